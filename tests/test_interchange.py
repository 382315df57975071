"""Interchange: particle frames as VTU (ParaView), the whole run as one USD stage (pxr)."""

import json
import sys

import meshio
import numpy as np
import pytest

from warp_iisph.cli import main
from warp_iisph.run.folder import RunError, RunFolder
from warp_iisph.run.formats import read_particles
from warp_iisph.run.runner import run_scene
from warp_iisph.scene import SceneFileError, load_scene


def tiny_scene(fmt: str):
    """A collapsing block of 300 particles (the same as the tiny run of conftest)."""
    from conftest import collapsing_block

    scene = collapsing_block()
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
    base = (
        "spacing = 0.05\ntank = { lower = [0, 0, 0], upper = [1, 1, 1] }\n[[fluids]]\n"
        "lower = [0, 0, 0]\nupper = [0.3, 0.3, 0.3]\n"
    )
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


def test_meshing_particle_files_never_writes_over_an_input(runs, tmp_path, capsys):
    """A mesh is named after its particle file with the mesh format's suffix: meshed beside itself
    as PLY, a PLY frame would be replaced by its own mesh, and a folder holding a.ply and a.vtu
    would mesh both into a.obj. Both are refused before anything is written."""
    import shutil

    frame = tmp_path / "loose" / "frame_00001.ply"
    frame.parent.mkdir()
    shutil.copy(runs / "ply" / "particles" / "frame_00001.ply", frame)
    kept = frame.read_bytes()
    for extra in ([], ["--overwrite"]):
        args = ["mesh", str(frame), "--spacing", "0.04", "--format", "ply", "--no-progress", *extra]
        assert main(args) == 2
        assert "would be written over frame_00001.ply" in capsys.readouterr().err
        assert frame.read_bytes() == kept
    assert main(["mesh", str(frame), "--spacing", "0.04", "--no-progress"]) == 0
    assert main(["mesh", str(frame), "--spacing", "0.04", "--cell", "1", "--no-progress"]) == 0
    assert "(1 already there, kept as they are: --overwrite remakes them" in capsys.readouterr().out
    frame.with_suffix(".obj").unlink()
    shutil.copy(runs / "vtu" / "particles" / "frame_00001.vtu", frame.with_suffix(".vtu"))
    assert main(["mesh", str(frame.parent), "--spacing", "0.04", "--out", str(tmp_path / "m"), "--no-progress"]) == 2
    assert "would both be meshed into it" in capsys.readouterr().err and not list((tmp_path / "m").glob("*.obj"))


def test_cli_format_flag_writes_vtu(tmp_path, capsys):
    out = tmp_path / "run"
    assert (
        main(
            [
                "run",
                "martin_moyce",
                "--spacing",
                "0.05",
                "--duration",
                "0.05",
                "--fps",
                "20",
                "--format",
                "vtu",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    assert sorted(f.name for f in (out / "particles").iterdir()) == ["frame_00000.vtu", "frame_00001.vtu"]
    assert json.loads((out / "run.json").read_text())["output"]["format"] == "vtu"
    with pytest.raises(SystemExit) as exit_:  # argparse's one line
        main(["run", "martin_moyce", "--format", "obj", "--no-progress"])
    assert exit_.value.code == 2 and "--format" in capsys.readouterr().err


# --- the whole run as one USD stage ---------------------------------------------------------------

try:
    import pxr  # noqa: F401

    HAVE_USD = True
except ImportError:
    HAVE_USD = False
needs_usd = pytest.mark.skipif(not HAVE_USD, reason="the usd extra (usd-core) is not installed")


def obj_arrays(path):
    """Vertices, triangles (0-based) and normals of one of the run's OBJ files, from its lines."""
    lines = path.read_text().splitlines()

    def rows(tag):
        return np.array([line.split()[1:] for line in lines if line.startswith(tag + " ")], dtype=str).reshape(-1, 3)

    v, n = rows("v").astype(float), rows("vn").astype(float)
    f = np.array([[int(c.split("/")[0]) - 1 for c in row] for row in rows("f")], dtype=int).reshape(-1, 3)
    return v, f, n


def open_stage(path):
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    assert stage is not None
    return stage


@needs_usd
def test_usd_stage_holds_the_liquid_at_every_frame(tiny_run, capsys):
    from pxr import UsdGeom

    assert main(["usd", str(tiny_run), "--no-progress"]) == 0
    assert "wrote frames 0..3 at 30 frames/s" in capsys.readouterr().out
    stage = open_stage(tiny_run / "run.usdc")
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetTimeCodesPerSecond() == 30.0 and stage.GetFramesPerSecond() == 30.0
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0.0, 3.0)
    assert stage.GetDefaultPrim().GetPath() == "/World"
    liquid = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Liquid"))
    assert liquid and liquid.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert liquid.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    for attr in (
        liquid.GetPointsAttr(),
        liquid.GetFaceVertexCountsAttr(),
        liquid.GetFaceVertexIndicesAttr(),
        liquid.GetNormalsAttr(),
    ):
        assert attr.GetTimeSamples() == [0.0, 1.0, 2.0, 3.0], attr.GetName()  # the topology changes: sampled too
    counts = set()
    for k, obj in enumerate(RunFolder(tiny_run).frames("mesh")):
        v, f, n = obj_arrays(obj)
        points = np.array(liquid.GetPointsAttr().Get(k))
        assert points.shape == v.shape and np.allclose(points, v, atol=1e-5)
        assert list(liquid.GetFaceVertexCountsAttr().Get(k)) == [3] * len(f)
        assert np.array_equal(np.array(liquid.GetFaceVertexIndicesAttr().Get(k)).reshape(-1, 3), f)
        assert np.allclose(np.array(liquid.GetNormalsAttr().Get(k)), n, atol=1e-4)  # the file's normals
        lo, hi = np.array(liquid.GetExtentAttr().Get(k))
        assert np.allclose(lo, v.min(0), atol=1e-6) and np.allclose(hi, v.max(0), atol=1e-6)
        counts.add(len(v))
    assert len(counts) > 1  # the liquid moved: the frames differ
    # between two frames USD holds the earlier one (no interpolation between different topologies)
    assert len(liquid.GetPointsAttr().Get(1.5)) == len(liquid.GetPointsAttr().Get(1))
    assert not stage.GetPrimAtPath("/World/Obstacles") and not stage.GetPrimAtPath("/World/Particles")
    # the camera frames the liquid as the render's would
    from warp_iisph.view.camera import framing_box, run_camera

    run = RunFolder(tiny_run)
    eye, target, fov = run_camera(run.record(), framing_box(run, run.record(), run.frames("mesh")), 16 / 9)
    camera = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera")).GetCamera(0)
    assert abs(camera.GetFieldOfView(camera.FOVHorizontal) - fov) < 1e-4 and abs(camera.aspectRatio - 16 / 9) < 1e-5
    frustum = camera.frustum
    assert np.allclose(frustum.GetPosition(), eye, atol=1e-5)
    view = np.array(frustum.ComputeViewDirection())
    assert np.allclose(view, (target - eye) / np.linalg.norm(target - eye), atol=1e-5)
    near, far = camera.clippingRange.min, camera.clippingRange.max
    assert near < np.linalg.norm(target - eye) < far


@needs_usd
def test_usd_stage_holds_the_obstacles_and_the_scene_camera(obstacle_run, tmp_path):
    import shutil

    from conftest import PILLAR
    from pxr import UsdGeom

    run = tmp_path / "run"
    shutil.copytree(obstacle_run, run)
    record = json.loads((run / "run.json").read_text())
    record["scene"]["camera"] = {"position": [1.0, 0.8, 1.5], "target": [0.2, 0.1, 0.2], "fov": 30.0}
    (run / "run.json").write_text(json.dumps(record))
    out = run / "stage.usda"
    assert main(["usd", str(run), "--out", str(out), "--no-progress"]) == 0
    assert out.read_text().startswith("#usda")
    stage = open_stage(out)
    obstacles = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Obstacles"))
    points = np.array(obstacles.GetPointsAttr().Get())
    assert obstacles.GetPointsAttr().GetTimeSamples() == []  # static
    assert np.allclose(points.min(0), PILLAR[0], atol=1e-6) and np.allclose(points.max(0), PILLAR[1], atol=1e-6)
    v, f, _ = obj_arrays(run / "obstacles.obj")
    assert len(points) == len(v) and len(obstacles.GetFaceVertexCountsAttr().Get()) == len(f)
    # flat-shaded: one outward normal per face corner (the box's faces are axis-aligned)
    normals = np.array(obstacles.GetNormalsAttr().Get()).reshape(-1, 3, 3)
    centres = points[np.array(obstacles.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)].mean(1)
    assert np.all(np.einsum("ij,ij->i", normals[:, 0], centres - np.mean(PILLAR, axis=0)) > 0)
    camera = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera")).GetCamera(0)
    assert np.allclose(camera.frustum.GetPosition(), [1.0, 0.8, 1.5], atol=1e-6)
    assert abs(camera.GetFieldOfView(camera.FOVHorizontal) - 30.0) < 1e-4
    view = np.array(camera.frustum.ComputeViewDirection())
    assert np.allclose(view, np.subtract([0.2, 0.1, 0.2], [1.0, 0.8, 1.5]) / np.linalg.norm([0.8, 0.7, 1.3]), atol=1e-5)


@needs_usd
def test_usd_particles_and_a_frame_range(tiny_run, tmp_path):
    from pxr import UsdGeom

    out = tmp_path / "part.usdc"
    assert main(["usd", str(tiny_run), "--particles", "--frames", "1:3", "--out", str(out), "--no-progress"]) == 0
    stage = open_stage(out)
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1.0, 2.0)
    assert UsdGeom.Mesh(stage.GetPrimAtPath("/World/Liquid")).GetPointsAttr().GetTimeSamples() == [1.0, 2.0]
    points = UsdGeom.Points(stage.GetPrimAtPath("/World/Particles"))
    density = UsdGeom.PrimvarsAPI(points).GetPrimvar("density")
    for k in (1, 2):
        p = read_particles(RunFolder(tiny_run).particle_frame(k))
        assert np.allclose(np.array(points.GetPointsAttr().Get(k)), p["x"])
        assert np.allclose(np.array(points.GetVelocitiesAttr().Get(k)), p["v"])
        assert np.array_equal(np.array(points.GetIdsAttr().Get(k)), p["id"])
        assert np.allclose(np.array(density.Get(k)), p["density"])
        assert np.allclose(np.array(points.GetWidthsAttr().Get(k)), 0.04)  # the particle spacing
    # --particles on a run without particle frames says so
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    shutil.rmtree(run / "particles")
    with pytest.raises(RunError, match="particles"):
        from warp_iisph.view.usd import export_usd

        export_usd(run, particles=True, progress=False)


@needs_usd
def test_usd_moving_obstacles_are_sampled_per_frame():
    import trimesh
    from pxr import Usd, UsdGeom

    from warp_iisph.view.usd import add_obstacles

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.Xform.Define(stage, "/World")
    shift = np.eye(4)
    shift[:3, 3] = (2.0, 0.0, 0.0)  # column vectors: the translation is the last column
    prim = add_obstacles(stage, box, transforms={0: np.eye(4), 10: shift})
    xf = UsdGeom.Xformable(prim)
    corner = np.array([0.5, 0.5, 0.5, 1.0])
    for frame, expected in ((0, [0.5, 0.5, 0.5]), (10, [2.5, 0.5, 0.5]), (5, [1.5, 0.5, 0.5])):  # linear in between
        m = np.array(xf.ComputeLocalToWorldTransform(frame))
        assert np.allclose((corner @ m)[:3], expected), frame
    bigger = box.copy()
    bigger.apply_scale(2.0)
    prim = add_obstacles(stage, box, meshes={4: bigger}, path="/World/Deforming")
    assert prim.GetPointsAttr().GetTimeSamples() == [4.0]
    assert np.allclose(np.array(prim.GetPointsAttr().Get(4)), bigger.vertices)


@needs_usd
def test_usd_refuses_a_run_without_meshes_and_bad_outputs(runs, tiny_run, tmp_path, capsys):
    assert main(["usd", str(runs / "ply"), "--no-progress"]) == 2
    assert main(["usd", str(tiny_run), "--out", str(tmp_path / "x.abc"), "--no-progress"]) == 2
    assert main(["usd", str(tiny_run), "--out", str(tmp_path), "--no-progress"]) == 2
    assert main(["usd", str(tiny_run), "--frames", "7:9", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("warp-iisph: error:") for line in err)
    assert "no frame_*.obj or frame_*.ply files (run with --mesh, or `warp-iisph mesh RUN_DIR`)" in err[0]
    assert ".usdc, .usda, .usd" in err[1] and "is a folder" in err[2] and "0..3" in err[3]
    assert not list(tmp_path.iterdir())


def test_usd_without_usd_core_says_what_to_install(tiny_run, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pxr", None)  # import pxr now raises ImportError
    assert main(["usd", str(tiny_run), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usd-core is not installed" in err and "pip install 'warp_iisph[usd]'" in err


@needs_usd
def test_remeshing_a_run_removes_its_stale_usd_stage_and_blender_script(tiny_run, tmp_path, capsys):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    assert main(["usd", str(run), "--no-progress"]) == 0 and (run / "run.usdc").is_file()
    assert main(["mesh", str(run), "--no-progress"]) == 0  # nothing re-made: the stage stays
    assert (run / "run.usdc").is_file()
    assert main(["blender-script", str(run)]) == 0
    assert main(["mesh", str(run), "--smoothing", "taubin", "--overwrite", "--no-progress"]) == 0
    assert not (run / "run.usdc").exists()
    assert (run / "blender_scene.py").is_file()  # the same files, remade: the script still loads them
    assert main(["mesh", str(run), "--format", "ply", "--overwrite", "--no-progress"]) == 0
    assert not (run / "blender_scene.py").exists()  # it named the .obj files that went
    (run / "particles" / "frame_00002.ply").unlink()  # a mesh that cannot be made again: not deleted
    before = {p.name: p.read_bytes() for p in (run / "mesh").iterdir()}
    assert main(["mesh", str(run), "--smoothing", "none", "--overwrite", "--no-progress"]) == 2
    assert "frame_00002.ply: its particle frame is missing" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in (run / "mesh").iterdir()} == before


def test_frames_of_no_particles_and_meshes_of_no_triangles_are_written_and_read(tmp_path):
    """An emitter's scene has no particles before it starts: its VTU frames (which meshio writes
    but cannot read back) read as empty, and an empty surface writes as a PLY mesh (a memoryview
    cast failed on the empty tables, so such a run could not mesh as PLY)."""
    from warp_iisph.run.formats import FileFormatError, read_mesh, write_mesh, write_particles

    none, scalars = np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
    write_particles(tmp_path / "empty.vtu", none, none, scalars, scalars)
    assert read_particles(tmp_path / "empty.vtu")["x"].shape == (0, 3)
    (tmp_path / "cut.vtu").write_bytes((tmp_path / "empty.vtu").read_bytes()[:100])
    with pytest.raises(FileFormatError, match="not a readable point file"):  # cut short: still refused
        read_particles(tmp_path / "cut.vtu")
    path = write_mesh(tmp_path / "empty.ply", none, np.zeros((0, 3), np.int32), none, fmt="ply")
    mesh = read_mesh(path)
    assert len(mesh.vertices) == 0 and len(mesh.faces) == 0
