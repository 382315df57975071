"""The demo command and its output folder; a diverging run keeps what it wrote."""

import json

import meshio
import numpy as np

from warp_iisph import scenes
from warp_iisph.cli import main
from warp_iisph.run.formats import read_particles, read_stats
from warp_iisph.run.runner import run_scene

STAT_KEYS = {"step", "t", "dt", "iterations", "density_error", "max_velocity", "ms"}


def test_run_dam_break_writes_frames_and_stats(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(
        [
            "run",
            "dam_break",
            "--duration",
            "0.1",
            "--fps",
            "20",
            "--spacing",
            "0.04",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert code == 0
    frames = sorted((out / "particles").glob("frame_*.ply"))
    assert [f.name for f in frames] == [f"frame_{k:05d}.ply" for k in range(3)]
    mesh = meshio.read(frames[-1])
    assert {"vx", "vy", "vz", "density", "pressure", "id"} <= set(mesh.point_data)
    p = read_particles(frames[-1])
    assert p["x"].shape[1] == 3 and len(p["x"]) == len(p["density"]) > 0
    assert np.all(p["v"][:, 1] <= 0.5)  # falling, not exploding
    stats = read_stats(out / "stats.jsonl")
    assert stats and all(STAT_KEYS <= set(s) for s in stats)
    assert {"neighbours", "advection", "pressure", "integration"} <= set(stats[0]["ms"])
    assert abs(stats[-1]["t"] - 0.1) < 1e-9
    run = json.loads((out / "run.json").read_text())
    assert run["ended"] == "completed" and run["totals"]["frames"] == 3
    # the choices the scene leaves unset, as the run took them (the scene's table keeps them unset)
    assert run["resolved"] == {"warm_start": "hydrostatic", "wall_gradient": "akinci"}
    assert run["scene"]["physics"].get("warm_start") is None
    # a second run into the same folder refuses without --overwrite
    assert (
        main(["run", "dam_break", "--duration", "0.05", "--spacing", "0.04", "--out", str(out), "--no-progress"]) == 2
    )
    assert "--overwrite" in capsys.readouterr().err


def test_a_box_of_liquid_filled_short_is_warned_of_before_the_run(tmp_path, capsys):
    """The dam break at 7 cm: its 0.4 x 0.6 x 0.6 m block holds 5 x 8 x 8 whole layers, 76 % of it;
    the warning comes once, before the run's summary, with the block named."""
    args = ["run", "dam_break", "--duration", "0.05", "--spacing", "0.07", "--out", str(tmp_path / "run")]
    assert main([*args, "--no-progress"]) == 0
    cap = capsys.readouterr()
    assert cap.err.count("warning: fluids[0]: whole layers of spacing = 0.07 m fill only 76 % of it") == 1, cap.err
    assert "completed" in cap.out
    # refused once its particles are built (the block lies inside a body): the refusal alone, one line
    body = "bodies=[{lower=[0.0,0.0,0.0],upper=[0.5,0.7,0.6],density=500.0}]"
    assert main([*args, "--overwrite", "--set", body, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fluids: no particle fits at spacing = 0.07 m" in err[0], err


def test_unknown_scene_is_a_clear_error(capsys):
    assert main(["run", "no_such_scene", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "not a bundled scene" in err and "dam_break" in err and "Traceback" not in err


def test_diverging_run_stops_and_keeps_frames(tmp_path):
    scene = scenes.martin_moyce(spacing=0.02, method="wcsph", dt=0.004, substeps=False)
    record = run_scene(scene, tmp_path / "w", duration=1.0, fps=50, progress=False)
    assert record["ended"] == "diverged"
    assert "step" in record["message"] and "t = " in record["message"]
    frames = sorted((tmp_path / "w" / "particles").glob("*.ply"))
    assert len(frames) == record["totals"]["frames"] >= 1
    for f in frames:
        read_particles(f)  # every frame on disk is complete
    assert json.loads((tmp_path / "w" / "run.json").read_text())["ended"] == "diverged"
    assert not list((tmp_path / "w" / "particles").glob(".*"))  # no temporary files left


def test_cuda_matches_cpu():
    import pytest
    import warp as wp

    if not wp.is_cuda_available():
        pytest.skip("no CUDA device on this machine")
    from warp_iisph import Simulation

    sims = {d: Simulation(scenes.martin_moyce(spacing=0.02, dt=0.002), d) for d in ("cpu", "cuda:0")}
    for s in sims.values():
        s.advance(0.1)
    a, b = sims["cpu"].positions, sims["cuda:0"].positions
    assert np.max(np.linalg.norm(a - b, axis=1)) < 0.02


def test_frame_writer_runs_in_order_overlaps_and_reports_errors():
    import threading
    import time

    import pytest

    from warp_iisph.run.frame_queue import FrameQueue

    done, main_thread = [], threading.get_ident()
    with FrameQueue() as w:
        t = time.perf_counter()
        for k in range(3):
            w.submit(lambda k=k: (time.sleep(0.05), done.append((k, threading.get_ident() != main_thread))))
        handed = time.perf_counter() - t
    assert done == [(0, True), (1, True), (2, True)]
    assert handed < 0.14  # the last job was handed over, not waited for
    assert w.busy >= 0.15 and w.blocked >= 0.09  # two waits for the job in flight

    w = FrameQueue()
    w.submit(lambda: (_ for _ in ()).throw(OSError(28, "No space left on device")))
    with pytest.raises(OSError, match="No space left"):
        w.submit(lambda: None)  # the failure surfaces at the next frame
    w.close()


def test_background_output_writes_the_same_files(tmp_path):
    scene = scenes.martin_moyce(spacing=0.04)
    scene.output.mesh = True
    a = run_scene(scene, tmp_path / "a", duration=0.1, fps=20, progress=False)
    b = run_scene(scene, tmp_path / "b", duration=0.1, fps=20, progress=False, background_output=False)
    assert a["output"]["background"] and not b["output"]["background"]
    assert a["output"]["writer_seconds"] > 0 and "export" in a["stage_seconds"]
    for sub in ("particles", "mesh"):
        names = sorted(p.name for p in (tmp_path / "a" / sub).glob("frame_*"))
        assert names == sorted(p.name for p in (tmp_path / "b" / sub).glob("frame_*")) and len(names) == 3
        for n in names:
            fa, fb = (tmp_path / r / sub / n for r in ("a", "b"))
            if sub == "mesh":
                assert fa.read_bytes() == fb.read_bytes()
            else:  # PLY headers carry meshio's timestamp
                pa, pb = read_particles(fa), read_particles(fb)
                assert all(np.array_equal(pa[k], pb[k]) for k in pa)


def test_a_failed_write_is_one_line_and_keeps_earlier_frames(tmp_path, monkeypatch, capsys):
    import warp_iisph.run.formats as formats

    real = formats.write_particles

    def fail_third(path, *args, **kw):
        if path.name == "frame_00002.ply":
            raise OSError(28, "No space left on device", str(path))
        real(path, *args, **kw)

    monkeypatch.setattr(formats, "write_particles", fail_third)
    out = tmp_path / "run"
    code = main(
        [
            "run",
            "dam_break",
            "--duration",
            "0.2",
            "--fps",
            "20",
            "--spacing",
            "0.05",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    err = capsys.readouterr().err
    assert (
        code == 1 and "No space left on device" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    )
    frames = sorted(p.name for p in (out / "particles").iterdir())
    assert frames == ["frame_00000.ply", "frame_00001.ply"]
    for f in frames:
        read_particles(out / "particles" / f)
    # the failed frame's checkpoint, written beside the particle file, was never put in place:
    # the last one is the last whole frame's, and nothing staged is left
    from warp_iisph.run.folder import RunFolder
    from warp_iisph.run.runner import load_checkpoint

    assert int(load_checkpoint(RunFolder(out, "ply"))["frame"]) == 1
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]
