"""Physically based frames of a run's meshes with Mitsuba 3 (the ``render`` extra): the liquid is
a smooth dielectric (IOR 1.33) filled with an absorbing medium (its colour), under a procedural
sky, over a checkered floor, with the run's obstacles (diffuse) and optionally the tank's far
walls; a box-filtered path tracer at few samples, then OpenImageDenoise with albedo and normal
guides. Frames go to ``frames/frame_NNNNN.png`` and, together, into ``video.mp4``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from ..engine.signals import deferred
from ..run.atomic import atomic_write
from ..run.folder import FRAMES, MESHES, RunError, RunFolder, frame_files, frame_index, select_frames, tank_bounds
from ..run.formats import read_mesh
from ..run.lock import FolderLock
from ..run.progress import frame_bar
from .camera import framing_box, run_camera
from .materials import material_color
from .mitsuba_scene import far_walls, scene_dict, sky_emitter
from .mitsuba_variant import EXTRA, RenderUnavailable, choose_variant, use_variant
from .video import parse_resolution, write_video


def denoise(color: np.ndarray, albedo: np.ndarray, normal: np.ndarray) -> np.ndarray:
    try:
        with deferred():
            import pyoidn
    except ImportError:
        raise RenderUnavailable(f"OpenImageDenoise (pyoidn) is not installed: {EXTRA}; or pass --no-denoise") from None
    return pyoidn.denoise(
        np.ascontiguousarray(color, np.float32),
        np.ascontiguousarray(np.clip(albedo, 0, 1), np.float32),
        np.ascontiguousarray(np.clip(normal, -1, 1), np.float32),
        hdr=True,
    )


def to_srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (s * 255.0 + 0.5).astype(np.uint8)


def render_image(scene: dict, use_denoiser: bool = True, seed: int = 0) -> np.ndarray:
    """Render a scene dict; returns the sRGB uint8 image."""
    import mitsuba as mi

    sc = mi.load_dict(scene)
    mi.render(sc, seed=seed)
    channels = dict(sc.sensors()[0].film().bitmap().split())
    color = np.array(channels["<root>"])[..., :3]
    if use_denoiser:
        color = denoise(color, np.array(channels["albedo"])[..., :3], np.array(channels["nn"])[..., :3])
    return to_srgb8(color)


class FrameRenderer:
    """A run's frames seen with one set of ``settings`` (plain data: the Mitsuba variant, camera,
    floor, material, samples, resolution, walls, denoising): the variant is set and the sky
    loaded once, and each frame brings its liquid and obstacles. A render farm's worker keeps one
    warm for all its frames."""

    def __init__(self, settings: dict):
        import mitsuba as mi

        from ..run.cluster import current_threads

        self.settings = settings
        use_variant(settings["variant"])
        if current_threads() is not None:  # in a worker: Mitsuba's threads are its share of the cores
            import drjit as dr

            dr.set_thread_count(current_threads())
        self.sky = mi.load_dict(sky_emitter())

    def render(self, mesh: Path | None, obstacles: Path | None, seed: int) -> np.ndarray:
        s = self.settings
        sd = scene_dict(
            mesh,
            (np.asarray(s["eye"]), np.asarray(s["target"])),
            s["floor_y"],
            s["extent"],
            s["color"],
            s["spp"],
            s["width"],
            s["height"],
            s["fov"],
            s["walls"],
            obstacles=obstacles,
            sky=self.sky,
        )
        return render_image(sd, s["denoise"], seed=seed)


def render_frame(settings: dict, mesh: str, obstacles: str | None, png: str) -> float:
    """Render one mesh frame into ``png`` (written beside it, then renamed in) with the process's
    :class:`FrameRenderer` for ``settings``; the seconds it took."""
    import imageio.v2 as imageio

    from ..run.cluster import warm

    t0 = time.perf_counter()
    renderer = warm(("render", json.dumps(settings, sort_keys=True)), lambda: FrameRenderer(settings))
    mesh, png = Path(mesh), Path(png)
    empty = len(read_mesh(mesh).faces) == 0  # also: a file cut off mid-write is refused here
    image = renderer.render(None if empty else mesh, None if obstacles is None else Path(obstacles), frame_index(mesh))
    atomic_write(png, lambda tmp: imageio.imwrite(tmp, image, format="png"))
    return time.perf_counter() - t0


# what the frames of a render were made with beyond ``framed`` (render_run): where it looked from
# and the floor it stood the liquid on; an earlier version's record may lack a key (then the
# frames' value is taken as today's: "obstacles", "floor")
VIEW_KEYS = ("camera", "floor")


def _comparable(settings: dict, made: dict) -> dict:
    """``settings`` of rendered frames, keys an earlier version did not record taken from ``made``."""
    return {**{k: made[k] for k in ("obstacles", "floor") if k in made}, **settings}


def kept_view(run: RunFolder, record: dict, framed: dict):
    """``(eye, target, fov, floor)`` of the frames already rendered with ``framed`` settings (the
    frames' own view), where the scene leaves the camera to the framing; ``None`` otherwise. A run
    extended by ``--resume`` frames other last frames, and a camera framed anew would throw away
    every frame rendered (hours on a farm): the render goes on with the view it began with.
    ``floor`` is ``[floor_y, extent]`` or ``None`` (not recorded by an earlier version)."""
    if ((record.get("scene") or {}).get("camera") or {}).get("position") is not None:
        return None  # the scene's own camera: nothing to keep
    prior = run.provenance(FRAMES)
    if not isinstance(prior, dict) or prior.get("run_id") != record.get("run_id"):
        return None
    settings = prior.get("settings")
    if not isinstance(settings, dict):
        return None
    rest = {k: v for k, v in _comparable(settings, framed).items() if k not in VIEW_KEYS}
    if rest != framed:
        return None
    try:
        old_eye, old_target, old_fov = settings["camera"]
        eye, target, fov = np.asarray(old_eye, float), np.asarray(old_target, float), float(old_fov)
        floor = settings.get("floor")
        floor = None if floor is None else [float(floor[0]), float(floor[1])]
    except (KeyError, TypeError, ValueError, IndexError):
        return None
    if eye.shape != (3,) or target.shape != (3,) or not np.all(np.isfinite(np.r_[eye, target])):
        return None  # a record edited by hand: framed anew
    if not 0.0 < fov < 180.0 or not np.linalg.norm(target - eye) > 1e-6:
        return None
    if floor is not None and not (np.all(np.isfinite(floor)) and floor[1] > 0.0):
        floor = None
    return eye, target, fov, floor


def render_run(
    run_dir,
    spp: int = 16,
    resolution: str = "640x360",
    material: str = "water",
    frames: str | None = None,
    walls: bool = False,
    use_denoiser: bool = True,
    gif: bool = False,
    overwrite: bool = False,
    variant: str | None = None,
    progress: bool = True,
    scheduler: str | None = None,
    workers: int | None = None,
) -> dict:
    """Render every (selected) mesh frame of a run into ``frames/`` and ``video.mp4``; frames
    already rendered are kept unless ``overwrite``. With ``workers`` (a LocalCluster of that
    many processes) or ``scheduler`` (a Dask cluster's address) the frames render in parallel,
    each worker keeping its renderer warm; the video is made here at the end."""
    from ..run.cluster import check_options, open_workers

    check_options(scheduler, workers)
    run = RunFolder.existing(run_dir)
    record = run.record()
    width, height = parse_resolution(resolution)
    if not 1 <= spp <= 65536:
        raise RunError(f"--spp {spp}: must be in [1, 65536]")
    color = material_color(material)
    every = run.frames(MESHES)
    files = select_frames(every, frames)
    chosen_variant, why = choose_variant(str(record.get("device") or "cpu").split(":")[0], variant)
    tank = tank_bounds(record, run.record_path)
    solid = run.obstacle_mesh()
    # the camera frames the whole run (and the obstacles with the liquid): a range of frames is seen
    # as the full video sees it, and keeps the frames rendered outside it
    box = framing_box(run, record, every, solid)
    eye, target, fov = run_camera(record, box, width / height, run.record_path)
    framed = {
        "meshes": run.provenance(MESHES),
        "spp": spp,
        "resolution": [width, height],
        "material": list(color),
        "walls": walls,
        "denoise": use_denoiser,
        "variant": chosen_variant,
        "obstacles": solid is not None,
    }
    floor_y = float(tank[0][1]) if tank is not None else float(box[0][1])
    extent = 4.0 * float(np.linalg.norm(box[1] - box[0])) + 1.0
    kept = kept_view(run, record, framed)
    if kept is not None:  # the view the frames already rendered were made with
        eye, target, fov, floor = kept
        floor_y, extent = floor if floor is not None else (floor_y, extent)
    wall_list = far_walls(*tank, eye) if walls and tank is not None else []
    settings = {
        "variant": chosen_variant,
        "eye": eye.tolist(),
        "target": np.asarray(target).tolist(),
        "fov": float(fov),
        "floor_y": floor_y,
        "extent": extent,
        "color": list(color),
        "spp": spp,
        "width": width,
        "height": height,
        "walls": [[np.asarray(c).tolist(), np.asarray(n).tolist(), [float(v) for v in z]] for c, n, z in wall_list],
        "denoise": use_denoiser,
    }
    lock = FolderLock(run.path).acquire()  # one writer: frames/ and video.mp4 are the run folder's
    try:
        with deferred():
            import imageio.v2 as imageio

        out = run.path / FRAMES
        out.mkdir(exist_ok=True)
        # rendered frames are a cache of this run's meshes seen with these settings: any made from
        # another run, other meshes or other settings go
        made = {
            "run_id": record.get("run_id"),
            "settings": {
                **framed,
                "camera": [np.asarray(eye).tolist(), np.asarray(target).tolist(), fov],
                "floor": [floor_y, extent],
            },
        }
        prior = run.provenance(FRAMES)
        rendered = prior.get("settings") if isinstance(prior, dict) else None
        if (
            not isinstance(rendered, dict)
            or prior.get("run_id") != made["run_id"]
            or _comparable(rendered, made["settings"]) != made["settings"]
        ):
            for old in frame_files(out, "png"):
                old.unlink()
            run.write_provenance(FRAMES, made["run_id"], made["settings"])
        elif rendered != made["settings"]:  # an earlier version's record: the keys it lacked added
            run.write_provenance(FRAMES, made["run_id"], made["settings"])
        if progress:
            print(f"rendering with Mitsuba {chosen_variant}: {why}", file=sys.stderr)
        pngs = [out / f"frame_{frame_index(path):05d}.png" for path in files]
        calls = []
        for path, png in zip(files, pngs):
            if overwrite or not png.exists():
                k = frame_index(path)
                obstacles = (
                    run.obstacle_frame(k)
                    if run.obstacle_frame(k).is_file()
                    else (run.obstacles if solid is not None else None)
                )
                obstacles = None if obstacles is None else str(obstacles)
                calls.append((render_frame, (settings, str(path), obstacles, str(png))))
        seconds = []

        def on_done(i, result, error):
            if error is not None:
                raise error
            seconds.append(result)
            bar.update(1)

        with open_workers(scheduler, workers) as pool:
            bar = frame_bar(len(files), progress, "render")
            bar.update(len(files) - len(calls))
            try:
                pool.run(calls, on_done, name="frame", warp=False)
            finally:
                bar.close()
        fps = run.fps(record)
        video = run.path / ("video.gif" if gif else "video.mp4")
        # every frame of the run rendered so far, in order (a range rendered adds to the video)
        shown = [png for png in (out / f"frame_{frame_index(p):05d}.png" for p in every) if png.exists()]
        write_video((imageio.imread(p) for p in shown), video, fps, gif=gif)
        return {
            "variant": chosen_variant,
            "why": why,
            "rendered": len(seconds),
            "skipped": len(files) - len(calls),
            "frames": len(pngs),
            "video": video,
            "video_frames": len(shown),
            "seconds_per_frame": float(np.median(seconds)) if seconds else 0.0,
        }
    finally:
        lock.release()
