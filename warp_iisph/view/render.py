"""Physically based frames of a run's meshes with Mitsuba 3 (the ``render`` extra): the liquid is
a smooth dielectric (IOR 1.33) filled with an absorbing medium (its colour), under a procedural
sky, over a checkered floor, with the run's obstacles (diffuse) and optionally the tank's far
walls; a box-filtered path tracer at few samples, then OpenImageDenoise with albedo and normal
guides. Frames go to ``frames/frame_NNNNN.png`` and, together, into ``video.mp4``."""

from __future__ import annotations

import glob
import json
import math
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

from ..engine.devices import native_stderr
from ..engine.signals import deferred
from ..run.atomic import atomic_write
from ..run.folder import FRAMES, MESHES, RunError, RunFolder, frame_files, frame_index, select_frames, tank_bounds
from ..run.formats import read_mesh
from ..run.lock import FolderLock
from ..run.progress import frame_bar
from .camera import camera_up, framing_box, run_camera
from .materials import IOR, THICKNESS, material_color
from .video import parse_resolution, write_video

EXTRA = "pip install 'warp_iisph[render]'  (Mitsuba 3, pyoidn, imageio)"


class RenderUnavailable(RuntimeError):
    """The render extra (or a library it needs) is missing; the message says what to install."""


def llvm_libraries() -> list[tuple[int, str]]:
    """(major version, path) of the libLLVM shared libraries Dr.Jit could load."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        path = os.environ["DRJIT_LIBLLVM_PATH"]
        m = re.search(r"LLVM[-.]?(\d+)", os.path.basename(path))
        return [(int(m.group(1)) if m else 99, path)]
    found = {}
    for d in (
        "/usr/lib",
        "/usr/lib64",
        "/usr/local/lib",
        "/usr/lib/x86_64-linux-gnu",
        "/usr/lib/aarch64-linux-gnu",
        "/opt/homebrew/opt/llvm/lib",
    ):
        for path in (
            glob.glob(os.path.join(d, "libLLVM*.so*"))
            + glob.glob(os.path.join(d, "llvm-*", "lib", "libLLVM*.so*"))
            + glob.glob(os.path.join(d, "libLLVM*.dylib"))
        ):
            m = re.search(r"libLLVM[-.](?:so\.)?(\d+)", os.path.basename(path))
            if m:
                found.setdefault(int(m.group(1)), path)
    return sorted(found.items())


def choose_variant(device_hint: str | None = None, forced: str | None = None) -> tuple[str, str]:
    """The fastest Mitsuba variant that works here, and a line saying why."""
    try:
        with deferred():  # Ctrl-C while it loads: raised once it has
            import mitsuba as mi
    except ImportError:
        raise RenderUnavailable(f"the render extra is not installed: {EXTRA}") from None
    if forced:
        if forced not in mi.variants():
            raise RunError(f"--variant {forced!r}: must be one of {', '.join(mi.variants())}")
        why = _cannot_run(forced)
        if why is None:
            try:
                with deferred(), native_stderr():
                    mi.set_variant(forced)
            except Exception as e:  # noqa: BLE001 - Dr.Jit raises many kinds for a backend it cannot start
                why = (str(e).strip().splitlines() or [type(e).__name__])[0]
        if why is not None:
            raise RunError(f"--variant {forced}: cannot run on this machine: {why}")
        return forced, f"{forced} (asked for)"
    notes = []
    if device_hint != "cpu" and "cuda_ad_rgb" in mi.variants() and _cuda_present():
        try:
            with deferred(), native_stderr():
                mi.set_variant("cuda_ad_rgb")
            return "cuda_ad_rgb", "cuda_ad_rgb (GPU)"
        except Exception as e:  # noqa: BLE001 - any failure falls back to the CPU
            notes.append(f"cuda_ad_rgb failed ({str(e).splitlines()[0]})")
    libs = llvm_libraries()
    good = [(v, p) for v, p in libs if v >= 16]
    if "llvm_ad_rgb" in mi.variants() and good:
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", good[-1][1])
        try:
            with deferred(), native_stderr():
                mi.set_variant("llvm_ad_rgb")
            return "llvm_ad_rgb", f"llvm_ad_rgb (libLLVM {good[-1][0]}, vectorised on the CPU)"
        except Exception as e:  # noqa: BLE001
            notes.append(f"llvm_ad_rgb failed ({str(e).splitlines()[0]})")
    elif libs:
        notes.append(
            f"llvm_ad_rgb needs libLLVM >= 16 and this machine has only libLLVM {', '.join(str(v) for v, _ in libs)} "
            "(Debian's libllvm15 crashes it); install libllvm16 or newer (e.g. apt install libllvm17) or point "
            "DRJIT_LIBLLVM_PATH at one"
        )
    else:
        notes.append("llvm_ad_rgb needs libLLVM >= 16, none found (e.g. apt install libllvm17)")
    with deferred():
        mi.set_variant("scalar_rgb")
    return "scalar_rgb", "scalar_rgb (slowest)" + ("; " + "; ".join(notes) if notes else "")


def _cannot_run(variant: str) -> str | None:
    """Why a Mitsuba variant cannot run here (``None``: it may): its backend's driver or library
    is missing (a libLLVM older than 16 crashes the process, so it is not tried)."""
    if variant.startswith("cuda") and not _cuda_present():
        return "it needs an NVIDIA driver (libcuda), and none is installed"
    if variant.startswith("llvm"):
        libs = llvm_libraries()
        good = [(v, p) for v, p in libs if v >= 16]
        if not good:
            have = f"only libLLVM {', '.join(str(v) for v, _ in libs)}" if libs else "no libLLVM"
            return (
                f"it needs libLLVM >= 16 and this machine has {have} (Debian's libllvm15 crashes it); "
                "install libllvm16 or newer, or point DRJIT_LIBLLVM_PATH at one"
            )
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", good[-1][1])
    return None


def _cuda_present() -> bool:
    try:
        import ctypes

        ctypes.CDLL("libcuda.so.1")
        return True
    except OSError:
        return False


def sky_bitmap(height: int = 128) -> np.ndarray:
    """Equirectangular sky (y up): blue zenith, pale horizon, grey ground, and a small sun."""
    width = 2 * height
    theta = (np.arange(height) + 0.5) / height * math.pi  # 0 at the zenith
    phi = (np.arange(width) + 0.5) / width * 2 * math.pi
    elev = 0.5 * math.pi - theta[:, None]
    t = np.clip(np.sin(elev), 0.0, 1.0)[..., None]
    zenith, horizon, ground = np.array([0.25, 0.45, 0.85]), np.array([0.85, 0.9, 0.95]), np.array([0.35, 0.33, 0.3])
    img = np.where(elev[..., None] >= 0, horizon * (1 - t**0.5) + zenith * t**0.5, ground) * np.ones((height, width, 3))
    d = np.stack(
        np.broadcast_arrays(
            np.sin(theta)[:, None] * np.cos(phi)[None],
            np.cos(theta)[:, None] + 0 * phi[None],
            np.sin(theta)[:, None] * np.sin(phi)[None],
        ),
        -1,
    )
    sun = np.array([0.4, 0.75, 0.5]) / np.linalg.norm([0.4, 0.75, 0.5])
    img += 400.0 * (d @ sun > math.cos(math.radians(2.0)))[..., None]
    return img.astype(np.float32)


def scene_dict(
    mesh_path: Path | None,
    camera,
    floor_y: float,
    extent: float,
    color,
    spp: int,
    width: int,
    height: int,
    fov: float,
    walls: list | None = None,
    obstacles: Path | None = None,
    sky=None,
) -> dict:
    """Mitsuba's scene of one frame; ``sky``: the sky emitter, loaded once for many frames (made
    here otherwise)."""
    import mitsuba as mi

    T = mi.ScalarTransform4f
    origin, target = camera
    sigma = -np.log(np.asarray(color)) / THICKNESS  # 1/m
    scale = float(max(sigma.max(), 1e-6))
    d = {
        "type": "scene",
        "integrator": {
            "type": "aov",
            "aovs": "albedo:albedo,nn:sh_normal",
            "img": {"type": "volpath", "max_depth": 24, "rr_depth": 12},
        },
        "sensor": {
            "type": "perspective",
            "fov": float(fov),
            "fov_axis": "x",
            "to_world": T().look_at(
                origin=[float(c) for c in origin], target=[float(c) for c in target], up=camera_up(origin, target)
            ),
            "sampler": {"type": "independent", "sample_count": int(spp)},
            "film": {
                "type": "hdrfilm",
                "width": width,
                "height": height,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
        },
        "sky": sky if sky is not None else sky_emitter(),
        "floor": {
            "type": "rectangle",
            "to_world": T()
            .translate([float(target[0]), float(floor_y), float(target[2])])
            .rotate([1, 0, 0], -90)
            .scale(extent),
            "bsdf": {
                "type": "diffuse",
                "reflectance": {
                    "type": "checkerboard",
                    "color0": 0.25,
                    "color1": 0.55,
                    "to_uv": T().scale([extent * 4, extent * 4, 1]),
                },
            },
        },
    }
    if mesh_path is not None:
        d["liquid"] = {
            "type": Path(mesh_path).suffix.lstrip(".").lower(),
            "filename": str(mesh_path),
            "face_normals": False,
            "bsdf": {"type": "dielectric", "int_ior": IOR, "ext_ior": 1.0},
            "interior": {
                "type": "homogeneous",
                "albedo": 0.0,
                "scale": scale,
                "sigma_t": {"type": "rgb", "value": [float(s / scale) for s in sigma]},
            },
        }
    if obstacles is not None:  # flat-shaded: boxes keep their edges
        d["obstacles"] = {
            "type": "obj",
            "filename": str(obstacles),
            "face_normals": True,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.55, 0.5, 0.45]}},
        }
    for k, (center, normal, size) in enumerate(walls or []):
        d[f"wall_{k}"] = {
            "type": "rectangle",
            "to_world": _rectangle(T, center, normal, size),
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.7, 0.72, 0.75]}},
        }
    return d


def sky_emitter() -> dict:
    import mitsuba as mi

    return {"type": "envmap", "bitmap": mi.Bitmap(sky_bitmap())}


def _rectangle(T, center, normal, size):
    """Mitsuba's rectangle ([-1, 1]^2 in z = 0) moved to ``center`` facing ``normal``, ``size`` = half extents."""
    n = np.asarray(normal, float)
    up = np.array([0.0, 1.0, 0.0]) if abs(n[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    return (
        T()
        .look_at(origin=[float(c) for c in center], target=[float(c) for c in np.asarray(center) + n], up=up.tolist())
        .scale([float(size[0]), float(size[1]), 1.0])
    )


def far_walls(lower, upper, eye) -> list:
    """The vertical tank faces on the far side of the liquid from the camera, facing inward."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    c = 0.5 * (lower + upper)
    half = 0.5 * (upper - lower)
    walls = []
    for axis in (0, 2):
        for sign in (-1.0, 1.0):
            face = c.copy()
            face[axis] += sign * half[axis]
            if (np.asarray(eye)[axis] - c[axis]) * sign < 0:  # the camera is on the other side
                normal = np.zeros(3)
                normal[axis] = -sign
                other = 2 if axis == 0 else 0
                walls.append((face, normal, (half[other], half[1])))
    return walls


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


def use_variant(variant: str) -> None:
    """Set Mitsuba's ``variant`` (the one :func:`choose_variant` chose) in this process."""
    import mitsuba as mi

    if variant == "llvm_ad_rgb":
        good = [p for v, p in llvm_libraries() if v >= 16]
        if good:
            os.environ.setdefault("DRJIT_LIBLLVM_PATH", good[-1])
    mi.set_variant(variant)


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
    files = select_frames(run.frames(MESHES), frames)
    chosen_variant, why = choose_variant(str(record.get("device") or "cpu").split(":")[0], variant)
    tank = tank_bounds(record, run.record_path)
    solid = run.obstacle_mesh()
    box = framing_box(run, record, files, solid)  # the obstacles are framed with the liquid
    eye, target, fov = run_camera(record, box, width / height, run.record_path)
    floor_y = float(tank[0][1]) if tank is not None else float(box[0][1])
    extent = 4.0 * float(np.linalg.norm(box[1] - box[0])) + 1.0
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
                "meshes": run.provenance(MESHES),
                "spp": spp,
                "resolution": [width, height],
                "material": list(color),
                "walls": walls,
                "denoise": use_denoiser,
                "variant": chosen_variant,
                "camera": [eye.tolist(), np.asarray(target).tolist(), fov],
            },
        }
        if run.provenance(FRAMES) != made:
            for old in frame_files(out, "png"):
                old.unlink()
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
        write_video((imageio.imread(p) for p in pngs), video, fps, gif=gif)
        return {
            "variant": chosen_variant,
            "why": why,
            "rendered": len(seconds),
            "skipped": len(files) - len(calls),
            "frames": len(pngs),
            "video": video,
            "seconds_per_frame": float(np.median(seconds)) if seconds else 0.0,
        }
    finally:
        lock.release()
