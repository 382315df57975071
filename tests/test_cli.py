"""The demo command and its output folder; a diverging run keeps what it wrote."""

import json

import meshio
import numpy as np

from warp_iisph import scenes
from warp_iisph.cli import main
from warp_iisph.io import read_particles, read_stats
from warp_iisph.runner import run_scene

STAT_KEYS = {"step", "t", "dt", "iterations", "density_error", "max_velocity", "ms"}


def test_run_dam_break_writes_frames_and_stats(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["run", "dam_break", "--duration", "0.1", "--fps", "20", "--spacing", "0.04", "--out", str(out), "--no-progress"])
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
    # a second run into the same folder refuses without --overwrite
    assert main(["run", "dam_break", "--duration", "0.05", "--spacing", "0.04", "--out", str(out), "--no-progress"]) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_unknown_scene_is_a_clear_error(capsys):
    assert main(["run", "no_such_scene", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "not a bundled scene" in err and "dam_break" in err and "Traceback" not in err


def test_diverging_run_stops_and_keeps_frames(tmp_path):
    scene = scenes.martin_moyce(spacing=0.02, method="wcsph", dt=0.004)
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
