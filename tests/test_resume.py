"""Resume: a run continued from its last checkpoint is bitwise the run that never stopped."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import finish, terminal_signals

from warp_iisph.cli import main
from warp_iisph.run.formats import read_particles, read_stats

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["--set", "spacing=0.04", "--no-progress"]


def frames(run: Path) -> list[Path]:
    return sorted((run / "particles").glob("frame_*.ply"))


def same_run(a: Path, b: Path) -> None:
    fa, fb = frames(a), frames(b)
    assert [f.name for f in fa] == [f.name for f in fb] and fa
    for x, y in zip(fa, fb):
        pa, pb = read_particles(x), read_particles(y)
        for k in ("x", "v", "density", "pressure", "id"):
            assert np.array_equal(pa[k], pb[k]), (x.name, k)
    strip = lambda r: {k: v for k, v in r.items() if k != "ms"}  # noqa: E731
    assert [strip(r) for r in read_stats(a / "stats.jsonl")] == [strip(r) for r in read_stats(b / "stats.jsonl")]


@pytest.fixture(scope="module")
def whole(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("resume") / "whole"
    assert main(["run", "martin_moyce", "--duration", "0.4", "--out", str(out), *SMALL]) == 0
    return out


def test_an_interrupted_run_resumes_bitwise(whole, tmp_path):
    out = tmp_path / "cut"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "warp_iisph.cli",
            "run",
            "martin_moyce",
            "--duration",
            "0.4",
            "--out",
            str(out),
            "--set",
            "spacing=0.04",
            "--set",
            "physics.dt=0.0005",
            "--no-progress",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=terminal_signals,
    )
    t0 = time.time()
    while not (out / "particles" / "frame_00003.ply").exists():
        assert proc.poll() is None and time.time() - t0 < 120, proc.communicate()
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    finish(proc)
    record = json.loads((out / "run.json").read_text())
    assert record["ended"] == "interrupted" and record["totals"]["frames"] < 12
    # the interrupted run used a fixed dt; so does the run it must equal
    reference = tmp_path / "reference"
    assert (
        main(
            ["run", "martin_moyce", "--duration", "0.4", "--out", str(reference), "--set", "physics.dt=0.0005", *SMALL]
        )
        == 0
    )
    assert main(["run", "--resume", str(out), "--no-progress"]) == 0
    same_run(out, reference)
    record = json.loads((out / "run.json").read_text())
    assert record["ended"] == "completed" and record["resumed"][0]["frame"] >= 3
    assert record["run_id"] == json.loads(json.dumps(record))["run_id"]


def test_a_finished_run_extends_bitwise(whole, tmp_path):
    out = tmp_path / "short"
    assert main(["run", "martin_moyce", "--duration", "0.1", "--out", str(out), *SMALL]) == 0
    # a checkpoint staged by a run killed mid-frame (written beside its place, never renamed in)
    stale = out / ".checkpoint.npz.k1ll3d.tmp.npz"
    stale.write_bytes(b"half a checkpoint")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p != stale}
    for extra in ([], ["--duration", "0.1"], ["--mesh"]):  # nothing left to run: refused, nothing changed
        assert main(["run", "--resume", str(out), *extra, "--no-progress"]) == 2
        assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p != stale} == before
    assert main(["run", "--resume", str(out), "--duration", "0.4", "--no-progress"]) == 0
    same_run(out, whole)
    assert not stale.exists()


def test_a_diverged_run_resumes_once_fixed(whole, tmp_path):
    """A run stopped as diverged by a speed limit set too low resumes, with the limit fixed, from
    its last checkpoint: the steps after it go, and the run equals one that had the right limit."""
    out = tmp_path / "strict"
    assert (
        main(
            ["run", "martin_moyce", "--duration", "0.4", "--out", str(out), "--set", "physics.max_velocity=1.0", *SMALL]
        )
        == 1
    )
    record = json.loads((out / "run.json").read_text())
    assert record["ended"] == "diverged" and "exceeds the limit 1 m/s" in record["message"]
    last = record["totals"]["frames"] - 1
    assert main(["run", "--resume", str(out), "--set", "physics.max_velocity=50", "--no-progress"]) == 0
    record = json.loads((out / "run.json").read_text())
    assert record["ended"] == "completed" and record["resumed"][0]["frame"] == last
    assert record["scene"]["physics"]["max_velocity"] == 50
    same_run(out, whole)


def test_resume_refuses_what_it_cannot_do(whole, tmp_path, capsys):
    assert main(["run", "--resume", str(whole), "--set", "spacing=0.02", "--no-progress"]) == 2
    assert "--set spacing: a resumed run keeps its particles" in capsys.readouterr().err
    assert main(["run", "--resume", str(whole), "--fps", "60", "--no-progress"]) == 2
    assert "keeps its 30 frames/s" in capsys.readouterr().err
    assert main(["run", "martin_moyce", "--resume", str(whole), "--no-progress"]) == 2
    capsys.readouterr()
    nock = tmp_path / "nock"
    assert (
        main(
            [
                "run",
                "martin_moyce",
                "--duration",
                "0.1",
                "--out",
                str(nock),
                "--set",
                "output.checkpoint_every=0",
                *SMALL,
            ]
        )
        == 0
    )
    assert main(["run", "--resume", str(nock), "--no-progress"]) == 2
    assert "no checkpoint to resume from" in capsys.readouterr().err


# --- what a resume keeps: the run folder must still hold what the run wrote up to its checkpoint ------

KEPT_SCENE = """
name = "kept"
spacing = 0.04
[tank]
lower = [0.0, 0.0, 0.0]
upper = [0.6, 0.4, 0.2]
[[fluids]]
lower = [0.0, 0.0, 0.0]
upper = [0.24, 0.32, 0.2]
[[bodies]]
name = "crate"
shape = "box"
lower = [0.36, 0.0, 0.04]
upper = [0.48, 0.08, 0.16]
density = 500.0
[output]
fps = 20
[[probes]]
name = "wall"
kind = "pressure"
position = [0.0, 0.05, 0.1]
normal = [1.0, 0.0, 0.0]
[[probes]]
name = "gauge"
kind = "level"
position = [0.1, 0.1]
"""


@pytest.fixture(scope="module")
def kept_scene(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("kept") / "kept.toml"
    path.write_text(KEPT_SCENE)
    return path


@pytest.fixture(scope="module")
def kept_run(kept_scene) -> Path:
    """A finished run (frames 0 .. 3, the checkpoint at 3) with meshes, a free body and probes:
    every kind of file a resume keeps."""
    out = kept_scene.parent / "run"
    assert main(["run", str(kept_scene), "--out", str(out), "--duration", "0.15", "--mesh", "--no-progress"]) == 0
    return out


@pytest.fixture
def kept_copy(kept_run, tmp_path) -> Path:
    import shutil

    out = tmp_path / "run"
    shutil.copytree(kept_run, out)
    return out


def _drop_lines(path: Path, which) -> None:
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(line for k, line in enumerate(lines) if not which(k, len(lines))))


def _cut(path: Path, by: int | None) -> None:
    """The file cut ``by`` bytes short (``None``: to its first 100, inside its header)."""
    data = path.read_bytes()
    path.write_bytes(data[:100] if by is None else data[:-by])


def _cut_at_a_line(path: Path) -> None:
    """The file's last line dropped whole: cut exactly at the end of the line before."""
    data = path.read_bytes()
    path.write_bytes(data[: data.rstrip(b"\n").rfind(b"\n") + 1])


def _swap_header(path: Path, a: int, b: int) -> None:
    """The header's cells a and b swapped: the same columns in another order."""
    head, rest = path.read_text().split("\n", 1)
    cells = head.split(",")
    cells[a], cells[b] = cells[b], cells[a]
    path.write_text(",".join(cells) + "\n" + rest)


@pytest.mark.parametrize(
    "damage, file, words",
    [
        (lambda r: (r / "particles" / "frame_00001.ply").unlink(), "particles/frame_00001.ply", "missing"),
        (lambda r: (r / "particles" / "frame_00003.ply").write_bytes(b""), "particles/frame_00003.ply", "empty"),
        (lambda r: _cut(r / "particles" / "frame_00002.ply", 5), "particles/frame_00002.ply", "cut short"),
        (lambda r: _cut(r / "particles" / "frame_00001.ply", None), "particles/frame_00001.ply", "no PLY header"),
        (lambda r: _cut(r / "mesh" / "frame_00002.obj", 3), "mesh/frame_00002.obj", "its last line is cut off"),
        (lambda r: _cut_at_a_line(r / "mesh" / "frame_00002.obj"), "mesh/frame_00002.obj", "where its counts make"),
        (lambda r: (r / "mesh" / "frame_00002.obj").unlink(), "mesh/frame_00002.obj", "warp-iisph mesh"),
        (lambda r: (r / "obstacles" / "frame_00000.obj").unlink(), "obstacles/frame_00000.obj", "a hole"),
        (lambda r: (r / "obstacles.obj").unlink(), "obstacles.obj", "missing"),
        (lambda r: (r / "stats.jsonl").unlink(), "stats.jsonl", "missing"),
        (lambda r: _drop_lines(r / "stats.jsonl", lambda k, n: k >= n - 5), "stats.jsonl", "up to step 25"),
        (lambda r: _drop_lines(r / "stats.jsonl", lambda k, n: k == 7), "stats.jsonl", "step 8 belongs"),
        (lambda r: (r / "probes.csv").unlink(), "probes.csv", "missing"),
        (lambda r: _drop_lines(r / "probes.csv", lambda k, n: k >= n - 3), "probes.csv", "the checkpoint counted 30"),
        (lambda r: _drop_lines(r / "probes.csv", lambda k, n: k == 4), "probes.csv", "holds 29 probe samples"),
        (lambda r: _drop_lines(r / "probes.csv", lambda k, n: k == 0), "probes.csv", "not the header"),
        (lambda r: _swap_header(r / "probes.csv", 1, 2), "probes.csv", "not the header"),
        (lambda r: _drop_lines(r / "bodies.csv", lambda k, n: k == n - 1), "bodies.csv", "one per frame makes 4"),
    ],
)
def test_a_resume_refuses_a_folder_that_lost_what_the_run_wrote(kept_copy, capsys, damage, file, words):
    """Frame files deleted, or step records or rows cut from the time series, since the run
    stopped: the resume is refused in one line naming the file, and nothing in the folder changes."""
    from test_reliability import one_line, snapshot

    damage(kept_copy)
    before = snapshot(kept_copy)
    capsys.readouterr()
    assert main(["run", "--resume", str(kept_copy), "--duration", "0.3", "--no-progress"]) == 2
    one_line(capsys.readouterr().err.strip().splitlines(), str(kept_copy / file), words, "--overwrite")
    assert snapshot(kept_copy) == before


def test_a_refusal_is_one_line_on_the_real_stderr(kept_copy):
    from test_reliability import one_line, snapshot

    _drop_lines(kept_copy / "stats.jsonl", lambda k, n: k == n - 1)
    before = snapshot(kept_copy)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "warp_iisph.cli",
            "run",
            "--resume",
            str(kept_copy),
            "--duration",
            "0.3",
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert p.returncode == 2
    one_line([line for line in p.stderr.splitlines() if line.strip()], str(kept_copy / "stats.jsonl"), "step 29")
    assert snapshot(kept_copy) == before


def test_an_intact_folder_resumes_again_and_again_and_a_mesh_made_again_lets_it(kept_scene, kept_copy, capsys):
    """What a killed run wrote after its checkpoint is no loss (it goes); a folder resumed twice,
    with meshes off for a stretch, still resumes and equals the run that never stopped (the frames
    of a stretch that wrote no meshes need none); a mesh deleted and made again by `warp-iisph
    mesh` lets the resume go on."""
    from test_reliability import one_line

    whole = kept_scene.parent / "whole"
    assert main(["run", str(kept_scene), "--out", str(whole), "--duration", "0.45", "--mesh", "--no-progress"]) == 0
    with open(kept_copy / "probes.csv", "a") as f:  # rows a run killed after its checkpoint had written
        f.write("0.2,1,2\n0.21,1")
    with open(kept_copy / "stats.jsonl", "a") as f:
        f.write('{"step": 31, "t": 0.155, "iterations": 1, "density_error": 0, "compression": 0}\n{"step": 3')
    resume = ["run", "--resume", str(kept_copy), "--no-progress"]
    assert main([*resume, "--duration", "0.3", "--set", "output.mesh=false"]) == 0
    record = json.loads((kept_copy / "run.json").read_text())
    assert record["resumed"][0]["output_before"] == {"particles": True, "mesh": True}
    assert main([*resume, "--duration", "0.45", "--set", "output.mesh=true"]) == 0
    meshes = sorted(p.name for p in (kept_copy / "mesh").glob("frame_*.obj"))
    assert meshes == [f"frame_{k:05d}.obj" for k in (0, 1, 2, 3, 7, 8, 9)]  # frames 4 .. 6 were written without
    same_run(kept_copy, whole)
    for name in ("probes.csv", "bodies.csv"):
        assert (kept_copy / name).read_text() == (whole / name).read_text(), name
    record = json.loads((kept_copy / "run.json").read_text())
    assert [(r["frame"], r["output_before"]["mesh"]) for r in record["resumed"]] == [(3, True), (6, False)]
    (kept_copy / "mesh" / "frame_00001.obj").unlink()
    capsys.readouterr()
    assert main([*resume, "--duration", "0.5"]) == 2
    one_line(capsys.readouterr().err.strip().splitlines(), str(kept_copy / "mesh" / "frame_00001.obj"), "mesh")
    assert main(["mesh", str(kept_copy), "--no-progress"]) == 0  # made again from its particle frame
    assert main([*resume, "--duration", "0.5"]) == 0


def test_meshes_remade_with_other_settings_are_not_mixed_with_the_resumed_runs(kept_copy, capsys):
    """`warp-iisph mesh RUN --overwrite --cell 1` remakes a run's meshes with other settings; a
    resume would write the next frames with the run's own beside them (and mesh/source.json
    claiming the first): refused, until the run is given those settings."""
    assert main(["mesh", str(kept_copy), "--overwrite", "--cell", "1", "--no-progress"]) == 0
    capsys.readouterr()
    resume = ["run", "--resume", str(kept_copy), "--duration", "0.25", "--no-progress"]
    assert main(resume) == 2
    assert "holds meshes made with other settings (cell)" in capsys.readouterr().err
    source = kept_copy / "mesh" / "source.json"
    made = json.loads(source.read_text())
    del made["settings"]["feature_weights"]  # as an older version wrote it: the key's default is meant
    source.write_text(json.dumps(made))
    assert main(["mesh", str(kept_copy), "--cell", "1", "--no-progress"]) == 0  # read alike by `mesh`
    assert main([*resume, "--set", "surface.cell=1"]) == 0
    made = json.loads(source.read_text())["settings"]
    assert made["cell"] == 1.0 and len(list((kept_copy / "mesh").glob("frame_*.obj"))) == 6
    resume[4] = "0.3"  # a resume that would change a surface setting of the meshes there: refused too
    assert main([*resume, "--set", "surface.cell=1", "--set", "surface.passes=5"]) == 2
    assert "other settings (passes)" in capsys.readouterr().err
