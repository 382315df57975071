"""Sweeps (`warp-iisph sweep`) and render farms on Dask: the same run folders as runs done one by
one, failures recorded, resumes that run only what is missing, Ctrl-C that stops cleanly."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import finish, terminal_signals

from warp_iisph.cli import main
from warp_iisph.run import sweep as sw
from warp_iisph.run import sweep_chart as charts
from warp_iisph.run.checkpoint import OWNER_KEYS

ROOT = Path(__file__).resolve().parent.parent
SMALL = ["--set", "spacing=0.04", "--duration", "0.1", "--no-progress"]
# the run.json fields a run's physics decides (its wall times, ids and command line differ)
PHYSICS = (
    "ended",
    "message",
    "scene",
    "resolved",
    "device",
    "particles",
    "duration",
    "requested_duration",
    "fps",
    "output",
)
TIMED = ("wall_seconds", "wall_seconds_per_simulated_second")

distributed = pytest.importorskip("distributed", reason="Dask distributed (the cluster extra) is not installed")


@pytest.fixture(scope="module")
def scheduler():
    """A LocalCluster of 2 worker processes, one thread each, shared by this module's tests."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as c:
        yield c.scheduler_address


def cli(*args) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "warp_iisph.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=terminal_signals,
        start_new_session=True,  # a process group of its own, as at a terminal
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


def exit_status(args) -> int:
    """``main``'s exit status, also for argparse's own errors (which exit)."""
    try:
        return main(args)
    except SystemExit as e:
        return e.code


def states(folder: Path) -> dict:
    return {e["name"]: e["ended"] for e in json.loads((folder / "sweep.json").read_text())["variants"]}


def wait_until(test, proc, seconds=240) -> None:
    t0 = time.time()
    while not test():
        assert proc.poll() is None, proc.communicate()
        assert time.time() - t0 < seconds
        time.sleep(0.1)


def run_json(folder: Path) -> dict:
    return json.loads((folder / "run.json").read_text())


def ply_data(path: Path) -> bytes:
    """A PLY file without the line meshio stamps with the time it wrote it."""
    return re.sub(rb"comment Created by meshio[^\n]*\n", b"", path.read_bytes())


def assert_same_run(a: Path, b: Path) -> None:
    """Two run folders hold the same run: particle frames, step records (but their timings),
    checkpoint and run.json's physics."""
    frames = sorted(p.name for p in (a / "particles").iterdir())
    assert frames and frames == sorted(p.name for p in (b / "particles").iterdir())
    for name in frames:
        assert ply_data(a / "particles" / name) == ply_data(b / "particles" / name), name

    def steps(run):
        return [{k: v for k, v in json.loads(line).items() if k != "ms"} for line in (run / "stats.jsonl").open()]

    assert steps(a) == steps(b)
    with np.load(a / "checkpoint.npz") as x, np.load(b / "checkpoint.npz") as y:  # the state, not whose run it is
        state = [k for k in x.files if k not in OWNER_KEYS]
        assert x.files == y.files and all(np.array_equal(x[k], y[k]) for k in state)
    ra, rb = run_json(a), run_json(b)
    for r in (ra, rb):  # how long the frame writer worked and was waited for
        del r["output"]["writer_seconds"], r["output"]["waited_seconds"]
    assert {k: ra[k] for k in PHYSICS} == {k: rb[k] for k in PHYSICS}
    drop = dict.fromkeys(TIMED)
    assert {**ra["totals"], **drop} == {**rb["totals"], **drop}


# --- variants, names, measures (no cluster) ----------------------------------------------------------


def test_values_split_at_top_level_commas_and_names_are_plain_folders():
    assert sw.split_values("0.01,0.001") == ["0.01", "0.001"]
    assert sw.split_values('[0, -9.81, 0],[0,-1,0], "a,b"') == ["[0, -9.81, 0]", "[0,-1,0]", '"a,b"']
    assert sw.variant_name({"spacing": "0.02", "physics.method": '"iisph"'}) == "spacing=0.02,physics.method=iisph"
    assert sw.variant_name({"spacing": "0.02"}, 3) == "spacing=0.02,repeat=3"
    odd = [{"k": v} for v in ("a/b", "a_b", "../x", "a\nb", "a b", "[0, -9.81, 0]", "x" * 300, "..")]
    names = [sw.variant_name(s) for s in odd]
    assert len(set(names)) == len(names)  # distinct settings, distinct folders
    for name in names:
        assert re.fullmatch(r"[A-Za-z0-9._=,+~-]+", name) and ".." not in name and len(name) <= sw.MAX_NAME
        assert not name.startswith((".", "-"))
    assert names == [sw.variant_name(s) for s in odd]  # stable: a resume finds them again
    vs = sw.variants(sw.parse_vary(["a=1,2", "b=x,y,z"]), repeat=2)
    assert len(vs) == 12 and [v["settings"] for v in vs[:3]] == [{"a": "1", "b": "x"}] * 2 + [{"a": "1", "b": "y"}]


def test_a_measure_is_a_path_or_a_name_in_the_summary():
    s = {"totals": {"mean_compression": 0.001, "steps": 21, "flag": True}, "particles": {"fluid": 250}}
    assert charts.measure_value(s, "totals.mean_compression") == 0.001
    assert charts.measure_value(s, "mean_compression") == 0.001 and charts.measure_value(s, "fluid") == 250
    assert charts.measure_value(s, "totals.flag") is None and charts.measure_value(s, "totals.nothing") is None
    assert "totals.steps" in charts.numbers_in(s) and "particles.fluid" in charts.numbers_in(s)


@pytest.mark.parametrize(
    "args, says",
    [
        (["martin_moyce", "--vary", "spacing"], "must be KEY=V1,V2"),
        (["martin_moyce", "--vary", "spacing=0.04,"], "an empty value"),
        (["martin_moyce", "--vary", "spacing=0.04,0.04"], "a value given twice"),
        (["martin_moyce", "--vary", "physics.eta=0.001,1e-3"], "a value given twice"),  # one number, two spellings
        (["martin_moyce", "--vary", "physics.rho0=1000,1000.0"], "a value given twice"),
        (["martin_moyce", "--vary", "name=2024-01-01,2024-01-02"], "variant name="),  # TOML dates: not names
        (["martin_moyce", "--vary", "spacing=0.04", "--set", "spacing=0.05"], "also given with --set"),
        (["martin_moyce", "--vary", "physics.eta=0.01,-1"], "variant physics.eta=-1: "),
        (["martin_moyce", "--vary", "physics.nothing=1,2"], "unknown key"),
        (["martin_moyce"], "at least one"),
        (["martin_moyce", "--vary", "spacing=0.04", "--measure", "a..b"], "--measure"),
        (["martin_moyce", "--vary", "spacing=0.04", "--workers", "0"], "--workers 0"),
        (["martin_moyce", "--vary", "spacing=0.04", "--workers", "2", "--scheduler", "tcp://x:1"], "not allowed"),
        (["martin_moyce", "--vary", "spacing=0.04", "--repeat", "0"], "--repeat 0"),
        (["martin_moyce", "--vary", "output.duration=0.05,0.1", "--duration", "0.2"], "also given with --duration"),
        (["martin_moyce", "--vary", "output.fps=10,20", "--fps", "30"], "also given with --fps"),
    ],
)
def test_bad_sweep_input_is_one_line_and_touches_nothing(tmp_path, capsys, args, says):
    out = tmp_path / "sweep"
    assert exit_status(["sweep", *args, "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("warp-iisph: error:") and says in err, err
    assert not out.exists()


@pytest.mark.parametrize("measure", ["totals.x", "totals.emitted", "particles", "device", "nothing"])
def test_a_measure_no_variant_will_have_is_refused_before_any_variant_runs(tmp_path, monkeypatch, capsys, measure):
    """A key that names no number of the variants' run.json summaries (``totals.emitted``: the
    scene has no emitter or sink; ``particles``, ``device``: not numbers) is refused in one line
    naming --measure, the key and the keys there are, before a variant runs: nothing written."""
    monkeypatch.chdir(tmp_path)  # the default sweeps/NAME would be here too
    monkeypatch.setattr(sw, "run_variant", lambda *a, **k: pytest.fail("a variant ran"))
    out = tmp_path / "sweep"
    args = ["sweep", "martin_moyce", "--vary", "physics.eta=0.01,0.001", "--measure", measure, "--out", str(out)]
    assert exit_status([*args, *SMALL]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"warp-iisph: error: --measure {measure}: no such number"), err
    assert "totals.mean_iterations, " in err and "particles.fluid" in err and "Traceback" not in err
    assert "totals.emitted" not in err.partition("give one of ")[2]  # not offered: no variant will have it
    assert not list(tmp_path.iterdir())  # no sweep folder, no run folder, no sweep.json, no chart


def test_the_measures_checked_before_a_sweep_are_the_ones_its_runs_write(tmp_path):
    """What --measure is checked against before a variant runs (:func:`sweep.blank_summary`) has
    the names of a real run's summary, with and without emitters and sinks; a sweep of a scene
    with an emitter takes totals.emitted."""
    from warp_iisph import Box, Scene
    from warp_iisph.run.runner import plan_frames, run_scene
    from warp_iisph.scene import Emitter, Sink, load_scene

    jet = Scene(spacing=0.04, tank=Box((0, 0, 0), (0.8, 0.5, 0.3)), name="jet")
    jet.add_emitter(Emitter(center=(0.1, 0.3, 0.15), direction=(1.0, 0.0, 0.0), speed=1.0, radius=0.06))
    jet.add_sink(Sink((0.6, 0.0, 0.0), (0.8, 0.1, 0.3)))
    for scene in (load_scene("martin_moyce", ["spacing=0.04"]), jet):
        real = sw.summary(run_scene(scene, tmp_path / scene.name, 0.05, progress=False))
        blank = sw.blank_summary(scene, plan_frames(scene, 0.05))
        assert charts.numbers_in(blank) == charts.numbers_in(real) and list(blank) == list(real)
        assert ("totals.emitted" in charts.numbers_in(blank)) == (scene is jet)
    record, _ = sw.plan_sweep("pour", ["physics.eta=0.01,0.001"], out=tmp_path / "pour", measure="totals.emitted")
    assert record["measure"] == "totals.emitted" and not (tmp_path / "pour").exists()


def test_a_sweep_folder_is_resumed_with_its_own_settings_or_not_at_all(tmp_path, capsys):
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "keep.txt").write_text("mine")
    assert main(["sweep", "--resume", str(tmp_path / "taken")]) == 2
    assert main(["sweep", "martin_moyce", "--resume", str(tmp_path / "taken")]) == 2
    assert main(["sweep", "martin_moyce", "--vary", "physics.eta=0.01", "--out", str(tmp_path / "taken")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert "no sweep.json" in err[0] and "give no SCENE" in err[1] and "not empty" in err[2]
    assert [p.name for p in (tmp_path / "taken").iterdir()] == ["keep.txt"]


@pytest.mark.parametrize("name", ["../victim", "ABS", "..", ".", "sub/dir", "", 7, "twice"])
def test_a_resumed_sweep_whose_variant_names_were_edited_is_refused_and_touches_nothing(tmp_path, capsys, name):
    """Each variant's folder is overwritten when it runs: a sweep.json whose variant name is not one
    plain folder inside the sweep's (a path out of it, absolute, hidden, not a string, twice) is
    refused in one line before anything runs, and the folder it names is left as it was."""
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "run.json").write_text("{}")
    (victim / "NOTES.txt").write_text("mine")
    out = tmp_path / "sweep"
    out.mkdir()
    name = str(victim) if name == "ABS" else name
    names = [name, name] if name == "twice" else [name]
    entries = [{"name": n, "settings": {"physics.eta": "0.01"}, "repeat": 1, "ended": "pending"} for n in names]
    record = {"scene": "martin_moyce", "set": [], "vary": {"physics.eta": ["0.01"]}, "repeat": 1, "duration": 0.1}
    record.update(fps=None, device="cpu", graph=False, measure="totals.mean_compression", variants=entries)
    (out / "sweep.json").write_text(json.dumps(record))
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "variants[" in err and "the file was edited" in err, err
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_without_dask_the_cluster_options_say_what_to_install(tmp_path, monkeypatch, capsys, tiny_run):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed now raises ImportError
    frames = (tiny_run / "frames").exists()
    out = tmp_path / "sweep"
    assert main(["sweep", "martin_moyce", "--vary", "physics.eta=0.01", "--workers", "2", "--out", str(out)]) == 2
    assert main(["render", str(tiny_run), "--workers", "2", "--no-progress"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and all("Dask is not installed" in line and "pip install" in line for line in err)
    assert not out.exists() and (tiny_run / "frames").exists() == frames


def test_a_serial_sweep_repeats_charts_and_resumes_nothing_when_complete(tmp_path, capsys):
    out = tmp_path / "sweep"
    args = ["sweep", "martin_moyce", "--vary", "physics.eta=0.01,0.001", "--repeat", "2", "--out", str(out), *SMALL]
    assert main([*args, "--measure", "mean_iterations"]) == 0
    assert "4 completed" in capsys.readouterr().out
    record = json.loads((out / "sweep.json").read_text())
    assert record["ended"] == "completed" and record["chart"] == "sweep.png" and (out / "sweep.png").stat().st_size
    assert [e["name"] for e in record["variants"]] == [
        f"physics.eta={eta},repeat={k}" for eta in ("0.01", "0.001") for k in (1, 2)
    ]
    for e in record["variants"]:  # the summary is the run's own totals
        assert e["worker"] == "this process" and e["wall_seconds"] > 0
        assert e["summary"]["totals"] == run_json(out / e["name"])["totals"]
    assert run_json(out / e["name"])["command"] == " ".join(sys.argv)  # the command that made it
    ids = {e["name"]: run_json(out / e["name"])["run_id"] for e in record["variants"]}
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    assert "0 run now, 4 complete before" in capsys.readouterr().out
    assert {e["name"]: run_json(out / e["name"])["run_id"] for e in record["variants"]} == ids
    # a measure no variant has: refused before anything runs, the sweep and its chart as they were
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert main(["sweep", "--resume", str(out), "--no-progress", "--measure", "totals.nothing"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--measure totals.nothing: no such number" in err
    assert "totals.mean_compression" in err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    # another measure they have: the chart redrawn with it, nothing run again
    assert main(["sweep", "--resume", str(out), "--no-progress", "--measure", "particles.fluid"]) == 0
    assert "(chart sweep.png: particles.fluid)" in capsys.readouterr().out
    assert json.loads((out / "sweep.json").read_text())["measure"] == "particles.fluid"


# --- on a LocalCluster of 2 workers ----------------------------------------------------------------


def test_a_sweep_on_two_workers_gives_the_runs_done_one_by_one(tmp_path, capsys):
    out = tmp_path / "sweep"
    vary = ["--vary", "physics.eta=0.01,0.001", "--vary", "physics.cfl=0.4,0.6"]
    assert main(["sweep", "martin_moyce", *vary, "--workers", "2", "--out", str(out), *SMALL]) == 0
    cap = capsys.readouterr()
    assert "Dask dashboard at http" in cap.err and "4 completed" in cap.out
    record = json.loads((out / "sweep.json").read_text())
    workers = {e["worker"] for e in record["variants"]}
    assert record["sessions"][0]["workers"]["workers"] == 2 and len(workers) == 2 and "this process" not in workers
    assert all(run_json(out / e["name"])["command"] == " ".join(sys.argv) for e in record["variants"])
    for eta in ("0.01", "0.001"):
        for cfl in ("0.4", "0.6"):
            alone = tmp_path / f"alone-{eta}-{cfl}"
            assert main(["run", "martin_moyce", "--set", f"physics.eta={eta}", "--set", f"physics.cfl={cfl}"] +
                        ["--out", str(alone), *SMALL]) == 0  # fmt: skip
            assert_same_run(out / f"physics.eta={eta},physics.cfl={cfl}", alone)


def _running_callbacks(dask_worker) -> list[str]:
    return sorted(name for name, callback in dask_worker.periodic_callbacks.items() if callback.is_running())


def test_workers_run_without_dasks_profiler_and_one_task_each(scheduler):
    from warp_iisph.run.cluster import PROFILER_CALLBACKS, SLOT, open_workers

    with open_workers(scheduler=scheduler) as pool:
        for running in pool.client.run(_running_callbacks).values():
            assert "heartbeat" in running and not set(PROFILER_CALLBACKS) & set(running)
        resources = pool.client.run(lambda dask_worker: dict(dask_worker.state.total_resources))
        assert all(r == {SLOT: 1} for r in resources.values())


def _intervals_ms(dask_worker=None, dask_scheduler=None) -> dict[str, float]:
    server = dask_worker or dask_scheduler
    return {name: float(callback.callback_time) for name, callback in server.periodic_callbacks.items()}


def test_a_local_cluster_runs_its_housekeeping_slowed():
    """A LocalCluster's scheduler and workers tick, and watch their systems and memory, at the
    package's intervals (Dask's 20 ms tick took 6 % of a core while idle)."""
    from dask.utils import parse_timedelta

    from warp_iisph.run.cluster import LOCAL_CLUSTER_CONFIG, open_workers

    ms = {key.split(".")[-2]: 1000 * parse_timedelta(value) for key, value in LOCAL_CLUSTER_CONFIG.items()}
    with open_workers(workers=2, threads=1) as pool:
        for worker in pool.client.run(_intervals_ms).values():
            assert (worker["tick"], worker["monitor"]) == (ms["tick"], ms["system-monitor"])
            assert worker["memory_monitor"] == ms["memory"]
        scheduler = pool.client.run_on_scheduler(_intervals_ms)
        assert (scheduler["tick"], scheduler["monitor"]) == (ms["tick"], ms["system-monitor"])
    assert ms["tick"] > 20  # Dask's own


def _log_dask_error(dask_worker=None, dask_scheduler=None) -> None:
    import logging

    logging.getLogger("distributed.worker" if dask_worker else "distributed.scheduler").error("DASK-ERROR-LOGGED")


def test_a_local_clusters_own_error_logs_stay_off_stderr(capfd):
    """Dask logs its errors as tracebacks (a worker's heartbeat meeting the scheduler closed, on
    a Ctrl-C): a LocalCluster's workers and scheduler keep them off stderr, which its processes
    share with this one."""
    from warp_iisph.run.cluster import open_workers

    with open_workers(workers=2, threads=1) as pool:
        pool.client.run(_log_dask_error)
        pool.client.run_on_scheduler(_log_dask_error)
        time.sleep(0.5)  # the workers' stderr is theirs to flush
    assert "DASK-ERROR-LOGGED" not in capfd.readouterr().err


def test_a_failing_variant_is_recorded_and_the_others_complete(tmp_path, scheduler, capsys):
    out = tmp_path / "sweep"
    code = main(
        ["sweep", "martin_moyce", "--vary", "spacing=0.04,0.0004", "--vary", "physics.dt=0.002,0.03"]
        + ["--set", 'physics.method="wcsph"', "--set", "physics.substeps=false", "--duration", "0.3"]
        + ["--scheduler", scheduler, "--out", str(out), "--no-progress"]
    )
    cap = capsys.readouterr()
    assert code == 1
    assert states(out) == {
        "spacing=0.04,physics.dt=0.002": "completed",
        "spacing=0.04,physics.dt=0.03": "diverged",  # a result, charted hollow
        "spacing=0.0004,physics.dt=0.002": "failed",  # 250 million particles: more memory than there is
        "spacing=0.0004,physics.dt=0.03": "failed",
    }
    record = json.loads((out / "sweep.json").read_text())
    failed = [e for e in record["variants"] if e["ended"] == "failed"]
    assert all("increase spacing" in e["message"] and "\n" not in e["message"] for e in failed)
    assert record["ended"] == "completed" and record["counts"] == {"completed": 1, "diverged": 1, "failed": 2}
    assert run_json(out / "spacing=0.04,physics.dt=0.03")["ended"] == "diverged"
    assert cap.err.count("warning: variant spacing=0.0004") == 2 and "1 completed, 1 diverged, 2 failed" in cap.out
    assert (out / "sweep.png").is_file()


def test_a_sweep_killed_and_resumed_runs_only_what_was_missing(tmp_path, scheduler, capsys):
    out = tmp_path / "sweep"
    # two quick variants (4 cm) and two slow ones (1.5 cm): the kill comes while the slow ones run
    proc = cli(
        *["sweep", "martin_moyce", "--vary", "spacing=0.04,0.015", "--vary", "physics.eta=0.01,0.001"],
        *["--duration", "0.5", "--scheduler", scheduler, "--out", str(out), "--no-progress"],
    )
    quick = ["spacing=0.04,physics.eta=0.01", "spacing=0.04,physics.eta=0.001"]
    slow = ["spacing=0.015,physics.eta=0.01", "spacing=0.015,physics.eta=0.001"]

    def quick_done_slow_running():
        if not (out / "sweep.json").is_file() or any(states(out)[q] != "completed" for q in quick):
            return False
        return all((out / n / "run.json").is_file() for n in slow)

    wait_until(quick_done_slow_running, proc)
    os.killpg(proc.pid, signal.SIGKILL)
    finish(proc)
    assert all(states(out)[n] == "pending" for n in slow)  # the sweep never heard of them again
    ids = {q: run_json(out / q)["run_id"] for q in quick}
    # the client gone, the cluster stops its variants: they say they were interrupted
    for n in slow:
        t0 = time.time()
        while run_json(out / n)["ended"] == "running":
            assert time.time() - t0 < 120
            time.sleep(0.2)
        assert run_json(out / n)["ended"] == "interrupted"
    assert main(["sweep", "--resume", str(out), "--scheduler", scheduler, "--no-progress"]) == 0
    assert "2 run now, 2 complete before" in capsys.readouterr().out
    assert set(states(out).values()) == {"completed"}
    assert {q: run_json(out / q)["run_id"] for q in quick} == ids  # not run again
    assert all(run_json(out / n)["ended"] == "completed" for n in slow)
    assert [s["variants_run"] for s in json.loads((out / "sweep.json").read_text())["sessions"]] == [4, 2]


@pytest.mark.parametrize("where, running", [([], 1), (["--workers", "2"], 2)])
def test_ctrl_c_stops_the_workers_and_leaves_a_truthful_record(tmp_path, where, running):
    out = tmp_path / "sweep"
    proc = cli(
        *["sweep", "martin_moyce", "--vary", "physics.eta=0.01,0.001,0.0005", "--set", "spacing=0.02"],
        *["--duration", "2", *where, "--out", str(out), "--no-progress"],
    )
    wait_until(lambda: len(list(out.glob("*/particles/frame_00002.ply"))) == running, proc)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole process group
    _, err = finish(proc)
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == "warp-iisph: interrupted", err
    assert "Traceback" not in err
    t0 = time.time()
    with pytest.raises(ProcessLookupError):  # the workers are gone with it
        while time.time() - t0 < 10:
            os.killpg(proc.pid, 0)
            time.sleep(0.2)
    record = json.loads((out / "sweep.json").read_text())
    assert record["ended"] == "interrupted"
    for e in record["variants"]:  # each says what its run folder says
        folder = out / e["name"]
        assert e["ended"] == (run_json(folder)["ended"] if folder.exists() else "pending")
    assert sorted(e["ended"] for e in record["variants"]) == ["interrupted"] * running + ["pending"] * (3 - running)


# --- render farm -----------------------------------------------------------------------------------


def test_render_on_two_workers_writes_and_skips_the_frames_render_does(tiny_run, tmp_path, scheduler, capsys):
    pytest.importorskip("mitsuba", reason="the render extra (Mitsuba 3) is not installed")
    import shutil

    farm = tmp_path / "farm"
    shutil.copytree(tiny_run, farm)
    args = ["--resolution", "64x36", "--spp", "4", "--variant", "scalar_rgb", "--no-progress"]
    assert main(["render", str(tiny_run), *args]) == 0
    assert main(["render", str(farm), "--scheduler", scheduler, *args]) == 0
    assert "rendered 4 frames (0 already there)" in capsys.readouterr().out
    for k in range(4):
        name = f"frame_{k:05d}.png"
        assert (farm / "frames" / name).read_bytes() == (tiny_run / "frames" / name).read_bytes()
    assert (farm / "video.mp4").stat().st_size > 0 and not list((farm / "frames").glob("*.part.png"))
    (farm / "frames" / "frame_00002.png").unlink()
    assert main(["render", str(farm), "--scheduler", scheduler, *args]) == 0
    assert "rendered 1 frame (3 already there)" in capsys.readouterr().out
    assert (farm / "frames" / "frame_00002.png").read_bytes() == (tiny_run / "frames" / "frame_00002.png").read_bytes()


def test_a_variant_whose_steps_are_too_long_for_the_solve_is_warned_about(tmp_path, capsys):
    """Each variant's run ends with the warnings a run would print (run_record.run_warnings),
    kept in sweep.json and printed again when the sweep is resumed complete."""
    path = tmp_path / "column.toml"
    path.write_text(
        'spacing = 0.02\nname = "column"\n[tank]\nlower = [0, 0, 0]\nupper = [0.6, 0.5, 0.2]\n'
        "[[fluids]]\nlower = [0, 0, 0]\nupper = [0.25, 0.4, 0.2]\n"
    )
    out = tmp_path / "sweep"
    args = ["sweep", str(path), "--vary", "physics.dt=0.01,0.002", "--set", "physics.substeps=false"]
    assert main([*args, "--duration", "0.4", "--out", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "variant physics.dt=0.01: mean compression" in err and "physics.dt=0.002:" not in err, err
    warnings = {e["name"]: e["summary"]["warnings"] for e in json.loads((out / "sweep.json").read_text())["variants"]}
    assert len(warnings["physics.dt=0.01"]) == 1 and warnings["physics.dt=0.002"] == []
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 0
    assert "variant physics.dt=0.01: mean compression" in capsys.readouterr().err


def test_a_sweep_resumed_after_its_scene_changed_is_refused_and_one_sweep_writes_a_folder(tmp_path, capsys):
    """A resume builds its variants from the scene file again: edited since the sweep began (a
    variant run before and one run now would be of two scenes) it is refused in one line, nothing
    run; restored, it resumes. A sweep folder another sweep is writing is refused, naming it."""
    from warp_iisph.run.lock import FolderLock

    path = tmp_path / "column.toml"
    text = (
        'spacing = 0.04\nname = "column"\n[tank]\nlower = [0, 0, 0]\nupper = [0.6, 0.5, 0.2]\n'
        "[[fluids]]\nlower = [0, 0, 0]\nupper = [0.25, 0.4, 0.2]\n"
    )
    path.write_text(text)
    out = tmp_path / "sweep"
    args = ["sweep", str(path), "--vary", "physics.viscosity=0.02,0.05", "--duration", "0.05", "--no-progress"]
    assert main([*args, "--out", str(out)]) == 0
    first = (out / "physics.viscosity=0.02" / "run.json").read_bytes()
    shutil.rmtree(out / "physics.viscosity=0.05")  # as if the sweep had stopped before it
    path.write_text(text.replace("0.25, 0.4", "0.25, 0.3"))  # a lower column
    capsys.readouterr()
    resume = ["sweep", "--resume", str(out), "--no-progress"]
    assert main(resume) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "changed since the sweep began" in err, err
    assert not (out / "physics.viscosity=0.05" / "run.json").exists()
    path.write_text(text)
    with FolderLock(tmp_path / "sweep", "sweep folder"):  # another sweep writing it
        assert main(resume) == 2
        assert "in use by PID" in capsys.readouterr().err
    assert main(resume) == 0 and (out / "physics.viscosity=0.02" / "run.json").read_bytes() == first
    assert json.loads((out / "physics.viscosity=0.05" / "run.json").read_text())["ended"] == "completed"
    assert not (out / ".warp-iisph.lock").exists()


@pytest.mark.parametrize(
    "edit, says",
    [
        (lambda r: r.update(measure=5), "measure = 5"),
        (lambda r: r.update(vary=["physics.eta"]), "vary = "),
        (lambda r: r.update(repeat="2"), "repeat = '2'"),
        (lambda r: r.update(duration=-1), "duration = -1"),
        (lambda r: r["variants"][0].update(settings={"physics.max_velocity": "9"}), "variants[0].settings"),
        (lambda r: r["variants"][0].update(settings={"physics.eta": "0.5"}), "variants[0].settings"),
        (lambda r: r["variants"][0].update(repeat="x"), "variants[0].settings"),
    ],
)
def test_a_hand_edited_sweep_record_is_refused_in_one_line_before_anything_runs(tmp_path, capsys, edit, says):
    """sweep.json's fields are checked when it is resumed (a measure that is not a name, settings
    that are not of the sweep's --vary, ...): exit 2 naming the field, nothing run (they were
    internal errors, one after the variants had run)."""
    out = tmp_path / "sweep"
    out.mkdir()
    entries = [{"name": "physics.eta=0.01", "settings": {"physics.eta": "0.01"}, "repeat": 1, "ended": "pending"}]
    record = {"scene": "martin_moyce", "set": [], "vary": {"physics.eta": ["0.01"]}, "repeat": 1, "duration": 0.1}
    record.update(fps=None, device="cpu", graph=False, measure="totals.mean_compression", variants=entries)
    edit(record)
    (out / "sweep.json").write_text(json.dumps(record))
    capsys.readouterr()
    assert main(["sweep", "--resume", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err and "the file was edited" in err, err
    assert [p.name for p in out.iterdir()] == ["sweep.json"]
