"""Interchange: particle frames as VTU (ParaView), the whole run as one USD stage (pxr)."""

import json
import sys

import meshio
import numpy as np
import pytest

from warp_iisph import scenes
from warp_iisph.cli import main
from warp_iisph.run.folder import RunError, RunFolder
from warp_iisph.run.formats import read_particles
from warp_iisph.run.runner import run_scene
from warp_iisph.scene import SceneFileError, load_scene


def tiny_scene(fmt: str):
    """A falling block of about 500 particles (the same as test_view's tiny run)."""
    scene = scenes.hydrostatic_tank(spacing=0.04, width=0.4, depth=0.4, water_height=0.16)
    scene.tank.upper = (0.4, 0.5, 0.4)
    scene.output.format = fmt
    return scene


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same scene written as PLY and as VTU: 3 frames each."""
    root = tmp_path_factory.mktemp("formats")
    for fmt in ("ply", "vtu"):
        record = run_scene(tiny_scene(fmt).validate(), root / fmt, duration=2 / 30, fps=30, progress=False)
        assert record["ended"] == "completed" and record["output"]["format"] == fmt
    return root


# --- VTU particle frames --------------------------------------------------------------------------


def test_output_format_is_checked_in_scene_files(tmp_path):
    base = 'spacing = 0.05\ntank = { lower = [0, 0, 0], upper = [1, 1, 1] }\n[[fluids]]\nlower = [0, 0, 0]\nupper = [0.3, 0.3, 0.3]\n'
    path = tmp_path / "s.toml"
    path.write_text(base + '[output]\nformat = "vtu"\n')
    assert load_scene(path).output.format == "vtu"
    assert load_scene(path, ['output.format="ply"']).output.format == "ply"
    path.write_text(base + '[output]\nformat = "obj"\n')
    with pytest.raises(SceneFileError, match=r"s\.toml: output\.format = 'obj': must be one of ply, vtu"):
        load_scene(path)


def test_vtu_frames_hold_one_vector_field_and_the_same_particles_as_ply(runs):
    ply, vtu = RunFolder(runs / "ply"), RunFolder(runs / "vtu")
    assert [f.name for f in vtu.frames("particles")] == [f"frame_{k:05d}.vtu" for k in range(3)]
    assert not list((runs / "vtu" / "particles").glob("*.ply"))
    assert vtu.particle_format == "vtu" and ply.particle_format == "ply"
    for k in range(3):
        path = vtu.particle_frame(k)
        mesh = meshio.read(path)
        n = len(mesh.points)
        # one vertex cell per particle: ParaView draws the points as they are
        assert [(c.type, len(c.data)) for c in mesh.cells] == [("vertex", n)]
        assert np.array_equal(mesh.cells[0].data.ravel(), np.arange(n))
        assert set(mesh.point_data) == {"velocity", "density", "pressure", "id"}
        assert mesh.point_data["velocity"].shape == (n, 3)
        # ParaView sees a 3-component array named velocity (a vector, not three scalars)
        head = path.read_bytes()[:4000].decode("ascii", "replace")
        assert 'type="UnstructuredGrid"' in head
        # the same simulation written as PLY holds the same numbers
        a, b = read_particles(ply.particle_frame(k)), read_particles(path)
        assert np.array_equal(a["x"], b["x"]) and np.array_equal(a["v"], b["v"])
        for key in ("density", "pressure", "id"):
            assert np.array_equal(a[key], b[key]), key
    text = vtu.particle_frame(1).read_bytes()
    assert b'Name="velocity" NumberOfComponents="3"' in text
    # a later frame moved: the velocities are the simulation's, not zeros
    assert np.abs(read_particles(vtu.particle_frame(2))["v"]).max() > 0.1


def test_run_folder_finds_frames_of_either_format_without_a_record(runs, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(runs / "vtu", copy)
    (copy / "run.json").unlink()
    run = RunFolder(copy)
    assert run.particle_format == "vtu" and len(run.frames("particles")) == 3
    assert run.particle_frame(7).name == "frame_00007.vtu"
    shutil.rmtree(copy / "particles")
    (copy / "particles").mkdir()
    with pytest.raises(RunError, match=r"no frame_\*\.ply or frame_\*\.vtu files"):
        RunFolder(copy).frames("particles")
    with pytest.raises(RunError, match="particle format 'obj'"):
        RunFolder(copy, "obj")


def test_mesh_and_preview_work_on_a_vtu_run(runs, tmp_path, capsys):
    import shutil

    import imageio.v2 as imageio

    for fmt in ("ply", "vtu"):
        shutil.copytree(runs / fmt, tmp_path / fmt)
        assert main(["mesh", str(tmp_path / fmt), "--no-progress"]) == 0
        assert "meshed 3 frames" in capsys.readouterr().out
    meshes = {fmt: sorted((tmp_path / fmt / "mesh").glob("frame_*.obj")) for fmt in ("ply", "vtu")}
    assert len(meshes["vtu"]) == 3
    for a, b in zip(meshes["ply"], meshes["vtu"]):  # the same particles give the same surface
        assert a.read_bytes() == b.read_bytes()
    out = tmp_path / "p.gif"
    assert main(["preview", str(tmp_path / "vtu"), "--gif", "--out", str(out), "--no-progress"]) == 0
    assert "preview of 3 frames (particles" in capsys.readouterr().out
    with imageio.get_reader(out) as r:
        frames = [np.asarray(f) for f in r]
    assert len(frames) == 3
    # coloured by speed: the falling block of the last frame is drawn in the ramp's colours
    last = frames[-1].astype(int)
    assert ((last[..., 2] - last[..., 0]) > 60).mean() > 0.01


def test_cli_format_flag_writes_vtu(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "martin_moyce", "--spacing", "0.05", "--duration", "0.05", "--fps", "20", "--format", "vtu",
                 "--out", str(out), "--no-progress"]) == 0
    assert sorted(f.name for f in (out / "particles").iterdir()) == ["frame_00000.vtu", "frame_00001.vtu"]
    assert json.loads((out / "run.json").read_text())["output"]["format"] == "vtu"
    with pytest.raises(SystemExit) as exit_:  # argparse's one line
        main(["run", "martin_moyce", "--format", "obj", "--no-progress"])
    assert exit_.value.code == 2 and "--format" in capsys.readouterr().err
