"""Looking at results: preview (no extra), Mitsuba render (the render extra), Blender script."""

import math
import sys
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
import trimesh
from conftest import PILLAR  # the obstacle of the obstacle_run fixture

from warp_iisph.cli import main
from warp_iisph.run.folder import RunError, RunFolder, select_frames
from warp_iisph.view.camera import auto_camera


def video_frames(path):
    with imageio.get_reader(path) as r:
        return [np.asarray(f) for f in r]


def test_preview_writes_one_video_frame_per_run_frame(tiny_run, capsys):
    assert main(["preview", str(tiny_run), "--no-progress"]) == 0
    assert "preview of 4 frames" in capsys.readouterr().out
    frames = video_frames(tiny_run / "preview.mp4")
    assert len(frames) == 4 and frames[0].shape == (360, 640, 3)
    # the liquid is drawn: far more colours than the background gradient and the tank's edges
    blue = (frames[0][..., 2].astype(int) - frames[0][..., 0].astype(int)) > 60
    assert blue.mean() > 0.01
    # the mesh as the source, a frame range, a GIF
    out = tiny_run / "m.gif"
    assert (
        main(
            [
                "preview",
                str(tiny_run),
                "--source",
                "mesh",
                "--frames",
                "1:3",
                "--gif",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    assert len(video_frames(out)) == 2


def test_preview_bad_input_is_one_line(tiny_run, tmp_path, capsys):
    assert main(["preview", str(tmp_path / "nothing"), "--no-progress"]) == 2
    assert main(["preview", str(tiny_run), "--resolution", "640x361", "--no-progress"]) == 2
    assert main(["preview", str(tiny_run), "--frames", "9:12", "--no-progress"]) == 2
    assert main(["preview", str(tiny_run), "--fps", "0.001", "--gif", "--no-progress"]) == 2  # no video plays that slow
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("warp-iisph: error:") for line in err)
    assert "no such run folder" in err[0] and "even" in err[1] and "0..3" in err[2] and "[0.1, 10000]" in err[3]


# --- the viewers' --out: one rule (view/out_file.py) -------------------------------------------------

VIEWS = {  # command: the suffix its --out takes, and what else it needs here
    "preview": (".mp4", ["--resolution", "64x36", "--no-progress"]),
    "usd": (".usdc", ["--no-progress"]),
    "blender-script": (".py", []),
    "plot": (".png", []),
}


def files_in(*folders) -> dict:
    return {p: p.read_bytes() for folder in folders for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("command", list(VIEWS))
@pytest.mark.parametrize(
    "where, says",
    [
        (lambda run, tmp, suffix: tmp / "folder", "is a folder; give a file name ending in {suffix}"),
        (lambda run, tmp, suffix: tmp / "view.txt", "must end in {suffix}"),
        (lambda run, tmp, suffix: tmp / f"view{suffix}.bak", "must end in {suffix}"),
        (lambda run, tmp, suffix: run / "particles" / f"view{suffix}", "one of the run's own files"),
        (lambda run, tmp, suffix: run / "mesh" / f"frame_00001{suffix}", "one of the run's own files"),
        (lambda run, tmp, suffix: tmp / "a_file" / f"view{suffix}", "a_file is a file, not a folder"),
        (lambda run, tmp, suffix: tmp / "a_file" / "deeper" / f"view{suffix}", "a_file is a file, not a folder"),
        (lambda run, tmp, suffix: "", "--out '': empty; give a file name ending in {suffix}"),
        (lambda run, tmp, suffix: f"{tmp}/new{suffix}/", "is a folder; give a file name ending in {suffix}"),
    ],
    ids=["folder", "suffix", "double-suffix", "frame-folder", "frame-file", "under-a-file", "deeper", "empty", "slash"],
)
def test_every_view_refuses_the_same_bad_out_in_one_line(tiny_run, tmp_path, capsys, command, where, says):
    """preview, usd, blender-script and plot apply one rule to --out: no folder, their suffix, none
    of the run's own files or frame folders, no file in a folder's place, not empty; each refusal
    one line naming --out and what is allowed (exit 2), nothing written anywhere."""
    if command == "usd":
        pytest.importorskip("pxr", reason="the usd extra (usd-core) is not installed")
    suffix, extra = VIEWS[command]
    (tmp_path / "folder").mkdir()
    (tmp_path / "a_file").write_text("mine")
    out = where(tiny_run, tmp_path, suffix)
    before = files_in(tiny_run, tmp_path)
    capsys.readouterr()
    assert main([command, str(tiny_run), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("warp-iisph: error: --out ") and "Traceback" not in err, err
    assert says.format(suffix=suffix) in err, err
    assert files_in(tiny_run, tmp_path) == before


@pytest.mark.parametrize("command", list(VIEWS))
def test_every_view_refuses_an_out_folder_it_may_not_write_before_any_work(
    tiny_run, tmp_path, capsys, monkeypatch, command
):
    """A folder this process may not write to (here: os.access says so, as it does for a read-only
    folder of another user's; root may write anywhere) is refused up front, in one line, exit 2."""
    import os

    import warp_iisph.view.out_file as out_file

    if command == "usd":
        pytest.importorskip("pxr", reason="the usd extra (usd-core) is not installed")
    suffix, extra = VIEWS[command]
    locked = tmp_path / "read_only"
    locked.mkdir()
    real = os.access
    monkeypatch.setattr(out_file.os, "access", lambda p, mode: False if Path(p) == locked else real(p, mode))
    capsys.readouterr()
    assert main([command, str(tiny_run), "--out", str(locked / "deeper" / f"view{suffix}"), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not writable" in err and str(locked) in err, err
    assert list(locked.iterdir()) == []


@pytest.mark.parametrize("command", [c for c in VIEWS if c != "plot"])  # plot: the tiny run has no probes
def test_every_view_waits_for_the_run_folders_writer_and_takes_any_case_of_its_suffix(
    tiny_run, tmp_path, capsys, command
):
    """A view into the run folder another command writes, or into another run's folder that its
    writer holds, is refused naming the holder; put elsewhere it reads the run as it is; its
    suffix in capitals is its suffix."""
    from warp_iisph.run.lock import FolderLock

    if command == "usd":
        pytest.importorskip("pxr", reason="the usd extra (usd-core) is not installed")
    suffix, extra = VIEWS[command]
    with FolderLock(tiny_run):
        before = {p: b for p, b in files_in(tiny_run).items() if p.name != ".warp-iisph.lock"}
        capsys.readouterr()
        assert main([command, str(tiny_run), "--out", str(tiny_run / f"view{suffix}"), *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "in use by" in err and "with --out" in err, err
        assert {p: b for p, b in files_in(tiny_run).items() if p.name != ".warp-iisph.lock"} == before
        out = tmp_path / f"VIEW{suffix.upper()}"
        assert main([command, str(tiny_run), "--out", str(out), *extra]) == 0
        assert out.stat().st_size > 0
    # into another run's folder, which its own writer holds: refused the same way, naming that folder
    import shutil

    other = tmp_path / "other_run"
    shutil.copytree(tiny_run, other)
    with FolderLock(other):
        capsys.readouterr()
        assert main([command, str(tiny_run), "--out", str(other / "sub" / f"view{suffix}"), *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "in use by" in err and str(other) in err, err
        assert not (other / "sub").exists()


def test_frame_selection():
    files = [type("P", (), {"stem": f"frame_{k:05d}"})() for k in range(10)]
    assert (
        len(select_frames(files, "2:5")) == 3
        and len(select_frames(files, "7:")) == 3
        and len(select_frames(files, ":2")) == 2
    )
    for bad in ("2", "a:b", "1:2:3"):
        with pytest.raises(RunError):
            select_frames(files, bad)


def test_missing_mesh_frames_say_how_to_make_them(tmp_path):
    (tmp_path / "mesh").mkdir()
    with pytest.raises(RunError, match="--mesh"):
        RunFolder(tmp_path).frames("mesh")


# --- the render extra -----------------------------------------------------------------------------

try:
    import mitsuba  # noqa: F401

    HAVE_MITSUBA = True
except ImportError:
    HAVE_MITSUBA = False
needs_mitsuba = pytest.mark.skipif(not HAVE_MITSUBA, reason="the render extra (Mitsuba 3) is not installed")


@needs_mitsuba
def test_tiny_render_shows_the_liquid(tmp_path):
    from warp_iisph.view import render

    render.choose_variant("cpu", "scalar_rgb")
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
    ball.apply_translation([0.0, 0.2, 0.0])
    path = tmp_path / "ball.obj"
    ball.export(path)
    eye, target = auto_camera(ball.bounds[0], ball.bounds[1], 40.0, 64 / 36)
    args = {"camera": (eye, target), "floor_y": 0.0, "extent": 3.0, "spp": 4, "width": 64, "height": 36, "fov": 40.0}
    red = render.material_color("0.95,0.5,0.5")  # through the 0.4 m ball: red 66 %, green and blue 0.4 %
    with_liquid = render.render_image(render.scene_dict(path, color=red, **args), use_denoiser=True)
    background = render.render_image(render.scene_dict(None, color=red, **args), use_denoiser=True)
    assert with_liquid.shape == (36, 64, 3) and with_liquid.dtype == np.uint8
    changed = np.abs(with_liquid.astype(int) - background.astype(int)).max(axis=2) > 40
    assert 0.05 < changed.mean() < 0.9  # the ball covers part of the frame
    # the liquid absorbs green and blue: the changed pixels are redder than they were
    wc, bc = with_liquid[changed].astype(float), background[changed].astype(float)
    assert (wc[:, 0] - wc[:, 1]).mean() > (bc[:, 0] - bc[:, 1]).mean() + 20


@needs_mitsuba
def test_render_run_writes_frames_and_video_and_skips_done_frames(tiny_run, capsys):
    args = ["render", str(tiny_run), "--resolution", "64x36", "--spp", "4", "--variant", "scalar_rgb", "--no-progress"]
    assert main(args + ["--walls"]) == 0
    assert "rendered 4 frames (0 already there)" in capsys.readouterr().out
    pngs = sorted((tiny_run / "frames").glob("frame_*.png"))
    assert [p.name for p in pngs] == [f"frame_{k:05d}.png" for k in range(4)]
    assert imageio.imread(pngs[0]).shape == (36, 64, 3)
    assert len(video_frames(tiny_run / "video.mp4")) == 4
    assert main(args + ["--walls"]) == 0
    assert "rendered 0 frames (4 already there)" in capsys.readouterr().out
    # a range is seen by the whole run's camera: the frames outside it stay, and so does the video
    assert main(args + ["--walls", "--frames", "1:3", "--overwrite"]) == 0
    assert "rendered 2 frames (0 already there)" in capsys.readouterr().out
    assert sorted((tiny_run / "frames").glob("frame_*.png")) == pngs and len(video_frames(tiny_run / "video.mp4")) == 4
    # frames rendered with other settings are stale: they are made again, not reused
    assert main(args) == 0
    assert "rendered 4 frames (0 already there)" in capsys.readouterr().out


# a render small and quick enough for a test (the scalar variant runs everywhere Mitsuba does)
TINY_RENDER = ["--resolution", "64x36", "--spp", "2", "--variant", "scalar_rgb", "--no-progress"]


def _meshed_block_run(out: Path, duration: float, **output) -> dict:
    """conftest's collapsing block run with meshes into ``out`` (``output``: more output settings)."""
    from conftest import collapsing_block

    from warp_iisph.run.runner import run_scene

    scene = collapsing_block()
    scene.output.mesh = True
    for key, value in output.items():
        setattr(scene.output, key, value)
    return run_scene(scene, out, duration=duration, fps=30, progress=False)


@needs_mitsuba
def test_a_run_extended_by_resume_renders_only_its_new_frames_with_the_same_camera(tmp_path, capsys):
    """A resume that extends a run frames other last frames; the render goes on with the camera
    its frames were made with and keeps them (they took hours on a farm), rendering the new ones."""
    out = tmp_path / "run"
    assert _meshed_block_run(out, 0.1)["ended"] == "completed"
    args = ["render", str(out), *TINY_RENDER]
    assert main(args) == 0
    first_settings = RunFolder(out).provenance("frames")["settings"]
    camera = first_settings["camera"]
    first = {p.name: p.stat().st_mtime_ns for p in (out / "frames").glob("frame_*.png")}
    assert len(first) == 4
    assert main(["run", "--resume", str(out), "--duration", "0.4", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(args) == 0
    assert "rendered 9 frames (4 already there)" in capsys.readouterr().out
    assert RunFolder(out).provenance("frames")["settings"]["camera"] == camera
    assert {p.name: p.stat().st_mtime_ns for p in (out / "frames").glob("frame_*.png") if p.name in first} == first
    assert len(video_frames(out / "video.mp4")) == 13
    # the floor the liquid stands on stays with the camera (it is framed on the run too)
    assert RunFolder(out).provenance("frames")["settings"]["floor"] == first_settings["floor"]
    # other settings frame the run anew, and every frame is made again with them
    assert main(args[:3] + ["48x36"] + args[4:]) == 0
    assert "rendered 13 frames (0 already there)" in capsys.readouterr().out


@needs_mitsuba
def test_a_resume_takes_the_images_of_the_frames_it_makes_again(tmp_path, capsys, monkeypatch):
    """A run stopped after its checkpoint: its resume makes the frames after the checkpoint again,
    and their rendered images (and the videos showing them) go with their meshes, so a view never
    shows a frame the run no longer has."""
    from warp_iisph.run.frame_writer import FrameWriter

    real = FrameWriter.write

    def stop_at_8(self, k):
        if k == 8:
            raise KeyboardInterrupt
        return real(self, k)

    out = tmp_path / "run"
    monkeypatch.setattr(FrameWriter, "write", stop_at_8)
    assert _meshed_block_run(out, 0.4, checkpoint_every=3)["ended"] == "interrupted"
    monkeypatch.undo()
    args = ["render", str(out), *TINY_RENDER]
    assert main(args) == 0
    pngs = sorted((out / "frames").glob("frame_*.png"))
    assert main(["preview", str(out), "--no-progress"]) == 0
    assert len(pngs) == 8 and (out / "video.mp4").is_file() and (out / "preview.mp4").is_file()
    kept = {p.name: p.stat().st_mtime_ns for p in pngs[:7]}  # frames 0..6: the checkpoint's is 6
    resumed = ["run", "--resume", str(out), "--set", "physics.gravity=[0,-30,0]", "--no-progress"]
    assert main(resumed) == 0
    assert not (out / "frames" / "frame_00007.png").exists()
    assert not (out / "video.mp4").exists() and not (out / "preview.mp4").exists()
    capsys.readouterr()
    assert main(args) == 0
    assert "rendered 6 frames (7 already there)" in capsys.readouterr().out
    assert {n: (out / "frames" / n).stat().st_mtime_ns for n in kept} == kept


@needs_mitsuba
def test_frames_rendered_by_an_earlier_version_or_a_hand_edited_view_are_handled(tmp_path, capsys):
    """A record of rendered frames without the keys this version adds keeps its frames; a camera
    edited into nonsense (its eye on its target) is not used: the run is framed anew."""
    import json

    out = tmp_path / "run"
    assert _meshed_block_run(out, 0.1)["ended"] == "completed"
    args = ["render", str(out), *TINY_RENDER]
    assert main(args) == 0
    source = out / "frames" / "source.json"
    record = json.loads(source.read_text())
    for key in ("floor", "obstacles"):  # as the version before them wrote it
        del record["settings"][key]
    source.write_text(json.dumps(record))
    capsys.readouterr()
    assert main(args) == 0
    assert "rendered 0 frames (4 already there)" in capsys.readouterr().out
    assert "floor" in json.loads(source.read_text())["settings"]  # the keys it lacked, added
    record = json.loads(source.read_text())
    record["settings"]["camera"][1] = record["settings"]["camera"][0]
    source.write_text(json.dumps(record))
    assert main(args) == 0
    assert "rendered 4 frames (0 already there)" in capsys.readouterr().out
    camera = json.loads(source.read_text())["settings"]["camera"]
    assert camera[0] != camera[1]


def test_missing_extra_is_a_clear_message(tiny_run, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # import mitsuba now raises ImportError
    assert main(["render", str(tiny_run), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "render extra is not installed" in err and "pip install" in err


@needs_mitsuba
def test_old_libllvm_falls_back_to_scalar_and_says_what_to_install(monkeypatch):
    from warp_iisph.view import mitsuba_variant as variants

    monkeypatch.setattr(variants, "_cuda_present", lambda: False)
    monkeypatch.setattr(variants, "llvm_libraries", lambda: [(15, "/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1")])
    variant, why = variants.choose_variant("cpu")
    assert variant == "scalar_rgb" and "libLLVM >= 16" in why and "libLLVM 15" in why and "install" in why
    monkeypatch.setattr(variants, "llvm_libraries", lambda: [])
    assert "none found" in variants.choose_variant("cpu")[1]


def test_camera_keys_in_scene_files(tmp_path):
    from warp_iisph.scene import SceneFileError, load_scene

    base = (
        "spacing = 0.05\ntank = { lower = [0, 0, 0], upper = [1, 1, 1] }\n[[fluids]]\n"
        "lower = [0, 0, 0]\nupper = [0.3, 0.3, 0.3]\n"
    )
    path = tmp_path / "s.toml"
    path.write_text(base + "[camera]\nposition = [2, 1, 3]\ntarget = [0.5, 0.2, 0.5]\nfov = 30\n")
    cam = load_scene(path).camera
    assert cam.position == (2.0, 1.0, 3.0) and cam.fov == 30.0
    for bad, key in (("fov = 500", "camera.fov"), ("target = [0, 0, 0]", "camera.target"), ("zoom = 2", "camera.zoom")):
        path.write_text(base + "[camera]\n" + bad + "\n")
        with pytest.raises(SceneFileError, match=key.replace(".", r"\.")):
            load_scene(path)


def test_materials_and_camera_framing():
    from warp_iisph.view import render

    assert render.material_color("0.5,0.25,1") == (0.5, 0.25, 1.0)
    for bad in ("0,0.5,0.5", "1,2", "milk"):
        with pytest.raises(RunError):
            render.material_color(bad)
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.5, 0.3])
    eye, target = auto_camera(lo, hi, 40.0, 16 / 9)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 0.5) for z in (0, 0.3)])
    view = (target - eye) / np.linalg.norm(target - eye)
    angles = [math.degrees(math.acos(np.dot(view, (c - eye) / np.linalg.norm(c - eye)))) for c in corners]
    assert max(angles) < 0.5 * math.degrees(2 * math.atan(math.tan(math.radians(20)) / (16 / 9))) + 1e-6


# --- Blender --------------------------------------------------------------------------------------


def script_constants(text: str) -> dict:
    """The upper-case constants a generated script starts with, read as Python literals."""
    import ast

    return {
        node.targets[0].id: ast.literal_eval(node.value)
        for node in ast.parse(text).body
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name) and node.targets[0].id.isupper()
    }


def obj_counts(path) -> tuple[int, int]:
    """Vertices and triangles of an OBJ, counted from its lines."""
    lines = path.read_text().splitlines()
    return sum(line.startswith("v ") for line in lines), sum(line.startswith("f ") for line in lines)


def test_blender_script_makes_one_liquid_object_whose_mesh_changes_per_frame(tiny_run, capsys):
    from warp_iisph.view.camera import framing_box, run_camera

    assert main(["blender-script", str(tiny_run), "--material", "whisky"]) == 0
    script = tiny_run / "blender_scene.py"
    text = script.read_text()
    compile(text, str(script), "exec")
    assert "1.33" in text and "ShaderNodeVolumeAbsorption" in text
    c = script_constants(text)
    meshes = RunFolder(tiny_run).frames("mesh")
    assert (
        c["FRAMES"] == [[k, str(m.resolve())] for k, m in enumerate(meshes)] and c["USD"] is None and c["FPS"] == 30.0
    )
    # one object, made once; every frame's OBJ becomes a mesh datablock kept in the file; nothing
    # is made per frame or keyed visible any more
    assert (
        text.count("bpy.data.objects.new(") == 2
    )  # the frame sequence's object (liquid, moving obstacles) and the camera
    assert 'bpy.data.objects.new(name, bpy.data.meshes[name + "_%05d" % frames[0][0]])' in text
    assert 'liquid = sequence("liquid", FRAMES, mat)' in text and c["OBSTACLE_FRAMES"] == []
    assert "use_fake_user = True" in text and "keyframe_insert" not in text and "hide_render" not in text
    # the frame handler is saved in the .blend as a registered text and run now
    assert "text.use_module = True" in text and "exec(compile(HANDLER" in text and "frame_change_pre" in c["HANDLER"]
    # the camera is the run's, as the render and the USD stage frame it, in Blender's z-up axes
    record = RunFolder(tiny_run).record()
    eye, target, fov = run_camera(record, framing_box(RunFolder(tiny_run), record, meshes), 16 / 9)
    (bx, by, bz), (tx, ty, tz), bfov = c["CAMERA"]
    assert np.allclose([bx, bz, -by], eye, atol=1e-5) and np.allclose([tx, tz, -ty], target, atol=1e-5) and bfov == fov


def test_blender_frame_handler_swaps_the_mesh(monkeypatch, tiny_run):
    """The handler's logic, run against a stand-in for bpy (Blender itself: the test below)."""
    import types

    from warp_iisph.view.blender import HANDLER

    handlers = types.SimpleNamespace(frame_change_pre=[], persistent=lambda f: f)
    meshes = {f"liquid_{k:05d}": object() for k in (3, 4, 5)}
    fake = types.SimpleNamespace(
        app=types.SimpleNamespace(handlers=handlers), data=types.SimpleNamespace(meshes=meshes)
    )
    monkeypatch.setitem(sys.modules, "bpy", fake)
    for _ in range(2):  # run twice (the script again, or the .blend reopened): registered once
        exec(compile(HANDLER, "warp_iisph_liquid.py", "exec"), {"__name__": "warp_iisph_liquid.py"})
    assert len(handlers.frame_change_pre) == 1
    handler = handlers.frame_change_pre[0]

    class Liquid(dict):
        data = None

    liquid = Liquid(warp_iisph_first=3, warp_iisph_last=5)
    scene = types.SimpleNamespace(objects={"liquid": liquid}, frame_current=4)
    handler(scene)
    assert liquid.data is meshes["liquid_00004"]
    for frame, shown in ((0, 3), (3, 3), (5, 5), (99, 5)):  # held before the first and after the last
        scene.frame_current = frame
        handler(scene)
        assert liquid.data is meshes[f"liquid_{shown:05d}"]
    scene.objects = {"liquid": Liquid()}  # another file's object called liquid: left alone
    handler(scene)
    assert scene.objects["liquid"].data is None
    meshes.update({f"obstacles_{k:05d}": object() for k in (3, 4, 5)})  # moving obstacles: swapped the same way
    obstacles = Liquid(warp_iisph_first=3, warp_iisph_last=5)
    scene.objects, scene.frame_current = {"obstacles": obstacles}, 5
    handler(scene)
    assert obstacles.data is meshes["obstacles_00005"]


def test_blender_script_usd_needs_the_stage(tiny_run, tmp_path, capsys):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    for stale in RunFolder(run).usd_files():
        stale.unlink()
    assert main(["blender-script", str(run), "--usd"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "warp-iisph usd" in err
    (run / "run.usda").write_text("#usda 1.0\n")
    assert main(["blender-script", str(run), "--usd"]) == 0
    c = script_constants((run / "blender_scene.py").read_text())
    assert c["USD"] == str((run / "run.usda").resolve()) and len(c["FRAMES"]) == 4


def test_blender_script_runs_in_blender(tiny_run, tmp_path):
    bpy = pytest.importorskip("bpy", reason="Blender's Python module (bpy) is not installed")
    from warp_iisph.view.blender import blender_script

    script = blender_script(tiny_run, tmp_path / "scene.py")
    exec(compile(script.read_text(), str(script), "exec"), {"__name__": "__main__"})
    scene = bpy.context.scene
    liquids = [o for o in bpy.data.objects if o.name.startswith("liquid")]
    assert [o.name for o in liquids] == ["liquid"] and scene.frame_start == 0 and scene.frame_end == 3
    assert sorted(m.name for m in bpy.data.meshes if m.name.startswith("liquid_")) == [
        f"liquid_{k:05d}" for k in range(4)
    ]
    assert bpy.data.texts["warp_iisph_liquid.py"].use_module
    for k, obj in enumerate(RunFolder(tiny_run).frames("mesh")):
        scene.frame_set(k)
        mesh = liquids[0].data
        assert mesh.name == f"liquid_{k:05d}" and (len(mesh.vertices), len(mesh.polygons)) == obj_counts(obj)
        assert mesh.materials[0].name.startswith("warp_iisph_liquid")


def test_blender_imports_the_usd_stage(tiny_run, tmp_path):
    bpy = pytest.importorskip("bpy", reason="Blender's Python module (bpy) is not installed")
    pytest.importorskip("pxr", reason="usd-core is not installed")
    import shutil

    from warp_iisph.view.blender import blender_script

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    assert main(["usd", str(run), "--no-progress"]) == 0
    script = blender_script(run, tmp_path / "scene.py", usd=True)
    exec(compile(script.read_text(), str(script), "exec"), {"__name__": "__main__"})
    scene = bpy.context.scene
    liquid = bpy.data.objects["liquid"]
    assert [m.type for m in liquid.modifiers] == ["MESH_SEQUENCE_CACHE"] and scene.frame_end == 3
    for k, obj in enumerate(RunFolder(run).frames("mesh")):
        scene.frame_set(k)
        evaluated = liquid.evaluated_get(bpy.context.evaluated_depsgraph_get())
        mesh = evaluated.to_mesh()
        assert (len(mesh.vertices), len(mesh.polygons)) == obj_counts(obj)
        evaluated.to_mesh_clear()


# --- Obstacles ------------------------------------------------------------------------------------


def test_run_writes_its_obstacles_once(obstacle_run, tiny_run):
    mesh = trimesh.load(obstacle_run / "obstacles.obj", force="mesh")
    assert mesh.is_watertight and np.allclose(mesh.bounds, PILLAR, atol=1e-6)
    assert np.isclose(mesh.volume, 0.12 * 0.3 * 0.12)  # wound outward
    assert RunFolder(tiny_run).obstacle_mesh() is None and not (tiny_run / "obstacles.obj").exists()


def _warm_pixels(image) -> int:
    """Pixels redder than blue: the stone-coloured obstacle (background and still water are blue-grey)."""
    im = image.astype(int)
    return int(((im[..., 0] - im[..., 2]) > 8).sum())


def test_preview_draws_the_obstacles(obstacle_run, tmp_path):
    args = ["preview", str(obstacle_run), "--frames", "0:1", "--gif", "--no-progress"]
    assert main(args + ["--out", str(tmp_path / "with.gif")]) == 0
    hidden = obstacle_run / "obstacles.obj.hidden"
    (obstacle_run / "obstacles.obj").rename(hidden)
    try:
        assert main(args + ["--out", str(tmp_path / "without.gif")]) == 0
    finally:
        hidden.rename(obstacle_run / "obstacles.obj")
    with_, without = video_frames(tmp_path / "with.gif")[0], video_frames(tmp_path / "without.gif")[0]
    # the pillar's 0.12 m wide top and sides fill a few percent of the 640x360 frame
    assert _warm_pixels(with_) > 0.01 * 640 * 360 and _warm_pixels(without) < 0.001 * 640 * 360


@needs_mitsuba
def test_render_shows_the_obstacles(obstacle_run, tmp_path):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(obstacle_run, run)
    args = [
        "render",
        str(run),
        "--resolution",
        "64x36",
        "--spp",
        "4",
        "--variant",
        "scalar_rgb",
        "--frames",
        "0:1",
        "--no-progress",
    ]
    assert main(args) == 0
    with_ = imageio.imread(run / "frames" / "frame_00000.png")
    (run / "obstacles.obj").unlink()
    assert main(args + ["--overwrite"]) == 0
    without = imageio.imread(run / "frames" / "frame_00000.png")
    changed = np.abs(with_.astype(int) - without.astype(int)).max(axis=2) > 40
    assert changed.mean() > 0.02


def test_blender_script_imports_the_obstacles(obstacle_run, tiny_run):
    from warp_iisph.view.blender import blender_script

    text = blender_script(obstacle_run).read_text()
    compile(text, "scene.py", "exec")
    assert f"OBSTACLES = {str((obstacle_run / 'obstacles.obj').resolve())!r}" in text
    assert "OBSTACLES = None" in blender_script(tiny_run).read_text()


def test_preview_obstacles_are_see_through():
    """Liquid behind an obstacle (inside a glass, behind a post) shows through it, tinted;
    liquid in front of it is drawn as it is."""
    from warp_iisph.view.preview import OBSTACLE_OPACITY, ObstacleLayer, OrthoView, splat

    view = OrthoView((-1, -1, -1), (1, 1, 1), 64, 48, yaw=0.0, pitch=0.0)  # looking along -z
    layer = ObstacleLayer(view, trimesh.creation.box(extents=(1.0, 1.0, 0.1)))  # a slab at z = 0
    blue = np.array([0.1, 0.3, 0.9])
    for z, behind in ((-0.5, True), (0.5, False)):
        image, depth = np.ones((48, 64, 3)), np.full((48, 64), -np.inf)
        splat(image, depth, view, np.array([[0.0, 0.0, z]]), blue[None], 0.1, shade_spheres=False)
        drawn = image[24, 32].copy()
        layer.over(image, depth)
        if behind:
            assert np.allclose(image[24, 32], (1 - OBSTACLE_OPACITY) * drawn + OBSTACLE_OPACITY * layer.image[24, 32])
            assert image[24, 32][2] > layer.image[24, 32][2] + 0.2  # the liquid's blue shows through
        else:
            assert np.array_equal(image[24, 32], drawn)
