"""Looking at results: preview (no extra), Mitsuba render (the render extra), Blender script."""

import math
import sys

import imageio.v2 as imageio
import numpy as np
import pytest
import trimesh

from warp_iisph.cli import main
from warp_iisph.run.folder import RunError, RunFolder, select_frames
from warp_iisph.view.camera import auto_camera

from conftest import PILLAR  # the obstacle of the obstacle_run fixture


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
    assert main(["preview", str(tiny_run), "--source", "mesh", "--frames", "1:3", "--gif", "--out", str(out), "--no-progress"]) == 0
    assert len(video_frames(out)) == 2


def test_preview_bad_input_is_one_line(tiny_run, tmp_path, capsys):
    assert main(["preview", str(tmp_path / "nothing"), "--no-progress"]) == 2
    assert main(["preview", str(tiny_run), "--resolution", "640x361", "--no-progress"]) == 2
    assert main(["preview", str(tiny_run), "--frames", "9:12", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("warp-iisph: error:") for line in err)
    assert "no such run folder" in err[0] and "even" in err[1] and "0..3" in err[2]


def test_frame_selection():
    files = [type("P", (), {"stem": f"frame_{k:05d}"})() for k in range(10)]
    assert len(select_frames(files, "2:5")) == 3 and len(select_frames(files, "7:")) == 3 and len(select_frames(files, ":2")) == 2
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
    args = dict(camera=(eye, target), floor_y=0.0, extent=3.0, spp=4, width=64, height=36, fov=40.0)
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
    # frames rendered with other settings are stale: they are made again, not reused
    assert main(args) == 0
    assert "rendered 4 frames (0 already there)" in capsys.readouterr().out


def test_missing_extra_is_a_clear_message(tiny_run, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # import mitsuba now raises ImportError
    assert main(["render", str(tiny_run), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "render extra is not installed" in err and "pip install" in err


@needs_mitsuba
def test_old_libllvm_falls_back_to_scalar_and_says_what_to_install(monkeypatch):
    from warp_iisph.view import render

    monkeypatch.setattr(render, "_cuda_present", lambda: False)
    monkeypatch.setattr(render, "llvm_libraries", lambda: [(15, "/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1")])
    variant, why = render.choose_variant("cpu")
    assert variant == "scalar_rgb" and "libLLVM >= 16" in why and "libLLVM 15" in why and "install" in why
    monkeypatch.setattr(render, "llvm_libraries", lambda: [])
    assert "none found" in render.choose_variant("cpu")[1]


def test_camera_keys_in_scene_files(tmp_path):
    from warp_iisph.scene import SceneFileError, load_scene

    base = 'spacing = 0.05\ntank = { lower = [0, 0, 0], upper = [1, 1, 1] }\n[[fluids]]\nlower = [0, 0, 0]\nupper = [0.3, 0.3, 0.3]\n'
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


def test_blender_script_is_valid_python_listing_every_frame(tiny_run, capsys):
    assert main(["blender-script", str(tiny_run), "--material", "whisky"]) == 0
    script = tiny_run / "blender_scene.py"
    text = script.read_text()
    compile(text, str(script), "exec")
    assert text.count("frame_0000") >= 4 and "1.33" in text and "ShaderNodeVolumeAbsorption" in text


def test_blender_script_runs_in_blender(tiny_run, tmp_path):
    bpy = pytest.importorskip("bpy", reason="Blender's Python module (bpy) is not installed")
    from warp_iisph.view.blender import blender_script

    script = blender_script(tiny_run, tmp_path / "scene.py")
    exec(compile(script.read_text(), str(script), "exec"), {"__name__": "__main__"})
    liquids = [o for o in bpy.data.objects if o.name.startswith("liquid_")]
    assert len(liquids) == 4 and bpy.context.scene.frame_end == 3


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
    args = ["render", str(run), "--resolution", "64x36", "--spp", "4", "--variant", "scalar_rgb", "--frames", "0:1", "--no-progress"]
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
