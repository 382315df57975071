"""A fast look at a run without the render extra: each frame's particles (coloured by speed) or
its mesh's vertices (shaded by their normals) are splatted as small spheres through an
orthographic camera with a z-buffer in NumPy, over the tank's edges, and the run's obstacles
(dense surface samples, drawn once unless they move) are laid over them see-through, so liquid
inside a glass or behind a post shows; the frames go into ``preview.mp4``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..run.folder import MAX_FPS, MESHES, PARTICLES, RunError, RunFolder, frame_index, select_frames, tank_bounds
from ..run.lock import writing_into
from ..run.progress import frame_bar
from ..scene.checks import in_range
from .out_file import view_file
from .video import MIN_FPS, parse_resolution, write_video

# Speed colour ramp (slow -> fast): deep blue, blue, cyan, pale yellow, orange.
RAMP = np.array([[0.05, 0.15, 0.45], [0.10, 0.40, 0.85], [0.30, 0.80, 0.95], [0.95, 0.95, 0.60], [0.95, 0.55, 0.15]])
WATER = np.array([0.25, 0.55, 0.90])
CLAY = np.array([0.72, 0.50, 0.32])  # obstacles: warm, so they stay apart from water and sky when see-through
LIGHT = np.array([0.35, 0.8, 0.5]) / np.linalg.norm([0.35, 0.8, 0.5])


def ramp(t: np.ndarray) -> np.ndarray:
    """Colour of values in [0, 1] along :data:`RAMP`."""
    t = np.clip(t, 0.0, 1.0) * (len(RAMP) - 1)
    k = np.minimum(t.astype(int), len(RAMP) - 2)
    f = (t - k)[:, None]
    return RAMP[k] * (1 - f) + RAMP[k + 1] * f


def camera_basis(yaw: float, pitch: float) -> np.ndarray:
    """Rows: screen right, screen up, towards the viewer (y is up in the scene; looking straight
    down or up, screen right is where the yaw turns it)."""
    a, b = math.radians(yaw), math.radians(pitch)
    toward = np.array([math.sin(a) * math.cos(b), math.sin(b), math.cos(a) * math.cos(b)])
    right = np.cross([0.0, 1.0, 0.0], toward)
    norm = np.linalg.norm(right)
    right = right / norm if norm > 1e-9 else np.array([math.cos(a), 0.0, -math.sin(a)])
    return np.stack([right, np.cross(toward, right), toward])


class OrthoView:
    """Maps scene points to pixels so that the box ``lower..upper`` fills the image."""

    def __init__(self, lower, upper, width: int, height: int, yaw: float = 30.0, pitch: float = 25.0):
        self.W, self.H = width, height
        self.R = camera_basis(yaw, pitch)
        self.center = 0.5 * (np.asarray(lower) + np.asarray(upper))
        corners = np.array(
            [[x, y, z] for x in (lower[0], upper[0]) for y in (lower[1], upper[1]) for z in (lower[2], upper[2])]
        )
        uv = (corners - self.center) @ self.R[:2].T
        span = np.maximum(uv.max(0) - uv.min(0), 1e-9)
        self.scale = 0.9 * min(width / span[0], height / span[1])  # pixels per metre
        self.mid = 0.5 * (uv.max(0) + uv.min(0))

    def project(self, x: np.ndarray):
        c = (np.asarray(x, float) - self.center) @ self.R.T
        px = (c[:, 0] - self.mid[0]) * self.scale + 0.5 * self.W
        py = 0.5 * self.H - (c[:, 1] - self.mid[1]) * self.scale
        return px, py, c[:, 2]


def splat(
    image: np.ndarray, depth_buffer: np.ndarray, view: OrthoView, x, colors, radius_m: float, shade_spheres: bool = True
) -> None:
    """Draw points as discs of ``radius_m`` metres (lit like spheres), nearest on top."""
    px, py, depth = view.project(x)
    seen = np.isfinite(px) & np.isfinite(py) & np.isfinite(depth)  # a particle file may hold anything
    colors = np.broadcast_to(colors, (len(px), 3))[seen]
    # far off the image is off it: clipped so that no pixel index overflows its integer
    px, py, depth = np.clip(px[seen], -1e6, 1e6), np.clip(py[seen], -1e6, 1e6), depth[seen]
    r = max(radius_m * view.scale, 0.7)
    ri = int(math.ceil(r))
    dy, dx = np.mgrid[-ri : ri + 1, -ri : ri + 1]
    keep = dx**2 + dy**2 <= r * r + 0.25
    dx, dy = dx[keep], dy[keep]
    nz = np.sqrt(np.maximum(1.0 - (dx**2 + dy**2) / (r * r + 0.25), 0.0))
    light = (
        0.55 + 0.45 * (dx * LIGHT[0] / (r + 0.5) - dy * LIGHT[1] / (r + 0.5) + nz * LIGHT[2])
        if shade_spheres
        else np.ones(len(dx))
    )
    X = (np.rint(px)[:, None] + dx[None, :]).astype(np.int64).ravel()
    Y = (np.rint(py)[:, None] + dy[None, :]).astype(np.int64).ravel()
    D = (depth[:, None] + nz[None, :] * radius_m).ravel()
    C = (colors[:, None, :] * np.clip(light, 0, 1)[None, :, None]).reshape(-1, 3)
    inside = (X >= 0) & (X < view.W) & (Y >= 0) & (Y < view.H)
    flat, D, C = (Y * view.W + X)[inside], D[inside], C[inside]
    order = np.lexsort((-D, flat))  # by pixel, nearest first
    flat, D, C = flat[order], D[order], C[order]
    first = np.ones(len(flat), bool)
    first[1:] = flat[1:] != flat[:-1]
    flat, D, C = flat[first], D[first], C[first]
    zb = depth_buffer.reshape(-1)
    nearer = D > zb[flat]
    zb[flat[nearer]] = D[nearer]
    image.reshape(-1, 3)[flat[nearer]] = C[nearer]


def box_edges(lower, upper, step: float) -> np.ndarray:
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    pts = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for u in (lo[others[0]], hi[others[0]]):
            for v in (lo[others[1]], hi[others[1]]):
                n = max(int((hi[axis] - lo[axis]) / step), 2)
                p = np.zeros((n, 3))
                p[:, axis] = np.linspace(lo[axis], hi[axis], n)
                p[:, others[0]], p[:, others[1]] = u, v
                pts.append(p)
    return np.concatenate(pts)


def splat_surface(
    image: np.ndarray, depth_buffer: np.ndarray, view: OrthoView, mesh, color=CLAY, max_points: int = 500_000
) -> None:
    """Draw a triangle mesh as random surface samples, about two per pixel of its area, each a
    3x3-pixel square (no gaps) lit by its triangle's normal; the z-buffer hides its far side."""
    import trimesh

    count = int(np.clip(2.0 * mesh.area * view.scale**2, 1000, max_points))
    points, face = trimesh.sample.sample_surface(mesh, count, seed=0)
    lam = np.clip(mesh.face_normals[face] @ LIGHT, 0.0, 1.0)[:, None]
    splat(image, depth_buffer, view, points, color * (0.35 + 0.65 * lam), 1.5 / view.scale, shade_spheres=False)


# how much of an obstacle's colour covers what lies behind it (liquid, edges, background)
OBSTACLE_OPACITY = 0.55


class ObstacleLayer:
    """An obstacle mesh drawn on its own (colour and depth per pixel), laid over a frame where
    it is nearer than what the frame drew there."""

    def __init__(self, view: OrthoView, mesh):
        self.image = np.zeros((view.H, view.W, 3))
        self.depth = np.full((view.H, view.W), -np.inf)
        splat_surface(self.image, self.depth, view, mesh)

    def over(self, image: np.ndarray, depth: np.ndarray) -> None:
        front = self.depth > depth
        image[front] = (1.0 - OBSTACLE_OPACITY) * image[front] + OBSTACLE_OPACITY * self.image[front]


def background(width: int, height: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, height)[:, None, None]
    top, bottom = np.array([0.93, 0.95, 0.98]), np.array([0.78, 0.80, 0.84])
    return np.broadcast_to(top * (1 - t) + bottom * t, (height, width, 3)).copy()


def preview_run(
    run_dir,
    out=None,
    source: str | None = None,
    resolution: str = "640x360",
    frames: str | None = None,
    fps: float | None = None,
    gif: bool = False,
    yaw: float = 30.0,
    pitch: float = 25.0,
    progress: bool = True,
) -> dict:
    """Write ``preview.mp4`` (or ``.gif``) of a run, or with ``out`` a ``.png`` file one frame's
    still; returns the path, frame count and seconds per frame."""
    run = RunFolder.existing(run_dir)
    record = run.record()
    width, height = parse_resolution(resolution)
    if source is None:
        source = PARTICLES if run.has_frames(PARTICLES) else MESHES
    if source not in (PARTICLES, MESHES):
        raise RunError(f"--source {source!r}: must be particles or mesh")
    files = select_frames(run.frames(source), frames)
    fps = run.fps(record) if fps is None else _option(fps, "--fps", MIN_FPS, MAX_FPS, "frames per second")
    yaw = _option(yaw, "--yaw", -1e6, 1e6, "degrees")
    pitch = _option(pitch, "--pitch", -90.0, 90.0, "degrees")
    out = view_file(
        run,
        out,
        "preview.gif" if gif else "preview.mp4",
        (".gif", ".png") if gif else (".mp4", ".gif", ".png"),
        "preview",
        "with --gif; .png: one frame's still" if gif else ".png: one frame's still",
    )
    gif = gif or out.suffix.lower() == ".gif"
    with writing_into(run.path, out):  # one writer in the run folder (a preview put elsewhere reads it as it is)
        return _preview(run, record, files, source, out, width, height, fps, gif, yaw, pitch, progress)


def _option(value, name: str, lo: float, hi: float, unit: str, lo_open: bool = False) -> float:
    try:
        return in_range(value, name, lo, hi, unit, lo_open=lo_open)
    except ValueError as e:
        raise RunError(str(e)) from None


def _preview(run, record, files, source, out, width, height, fps, gif, yaw, pitch, progress) -> dict:
    import time

    from PIL import Image, ImageDraw

    from ..run.formats import read_particles

    h = run.spacing(record) or 0.0
    load = read_particles if source == PARTICLES else _read_mesh_points
    first = load(files[0])
    if h <= 0:  # no record: estimate the spacing from the particle volume
        ext = np.ptp(first["x"], axis=0)
        h = float(np.cbrt(np.prod(np.maximum(ext, 1e-6)) / max(len(first["x"]), 1)))
    obstacles = run.obstacle_mesh()
    bounds = tank_bounds(record, run.record_path)
    if bounds is None:
        lo, hi = first["x"].min(0) - h, first["x"].max(0) + h
        last = load(files[-1])["x"]
        bounds = (np.minimum(lo, last.min(0) - h), np.maximum(hi, last.max(0) + h))
        if obstacles is not None:
            bounds = (np.minimum(bounds[0], obstacles.bounds[0]), np.maximum(bounds[1], obstacles.bounds[1]))
    view = OrthoView(*bounds, width, height, yaw, pitch)
    edges = box_edges(*bounds, step=0.5 / view.scale)
    # what does not move is drawn once: the tank's edges and still obstacles; moving ones every frame
    still, still_depth = background(width, height), np.full((height, width), -np.inf)
    splat(still, still_depth, view, edges, np.full((len(edges), 3), 0.45), 0.5 / view.scale, shade_spheres=False)
    moving = run.obstacles_move
    still_obstacles = ObstacleLayer(view, obstacles) if obstacles is not None and not moving else None
    # the colour scale's top: the speed of a fall over the tank's height along the run's gravity
    # (Earth's along -y where the record has none, or none that reads as a vector)
    try:
        gravity = np.asarray(record["scene"]["physics"]["gravity"], dtype=np.float64).reshape(3)
    except (KeyError, TypeError, ValueError):
        gravity = np.array([0.0, -9.81, 0.0])
    g = float(np.linalg.norm(gravity))
    if not (math.isfinite(g) and g > 0.0):
        gravity, g = np.array([0.0, -9.81, 0.0]), 9.81
    height = float(np.abs(gravity / g) @ (np.asarray(bounds[1], float) - np.asarray(bounds[0], float)))
    v_ref = math.sqrt(2 * g * max(height, h))
    timing = []

    def images():
        bar = frame_bar(len(files), progress, "preview")
        try:
            for k, path in enumerate(files):
                t0 = time.perf_counter()
                data = first if k == 0 else load(path)
                img, zb = still.copy(), still_depth.copy()
                layer = still_obstacles
                if moving:
                    solid = run.obstacle_mesh(frame_index(path))
                    layer = ObstacleLayer(view, solid) if solid is not None else None
                if source == PARTICLES:
                    speed = np.linalg.norm(data["v"], axis=1) if data["v"] is not None else np.zeros(len(data["x"]))
                    colors = ramp(speed / v_ref)
                    splat(img, zb, view, data["x"], colors, 0.5 * h)
                else:
                    lam = np.clip(data["n"] @ LIGHT, 0.0, 1.0)[:, None]
                    splat(img, zb, view, data["x"], WATER * (0.35 + 0.65 * lam), 0.3 * h, shade_spheres=False)
                if layer is not None:
                    layer.over(img, zb)
                pil = Image.fromarray((np.clip(img, 0, 1) * 255).astype(np.uint8))
                label = (
                    f"frame {frame_index(path)}   t = {frame_index(path) / fps:.3f} s   "
                    f"{len(data['x']):,} {'particles' if source == PARTICLES else 'vertices'}"
                )
                ImageDraw.Draw(pil).text((8, 6), label, fill=(30, 30, 30))
                timing.append(time.perf_counter() - t0)
                bar.update(1)
                yield np.asarray(pil)
        finally:
            bar.close()

    if out.suffix.lower() == ".png":
        if len(files) != 1:
            raise RunError(
                f"--out {out}: a still shows one frame; choose it with --frames, "
                f"e.g. --frames {frame_index(files[-1])}:"
            )
        from ..run.atomic import atomic_write

        image = Image.fromarray(next(images()))
        atomic_write(out, lambda tmp: image.save(tmp, format="PNG"))
    else:
        write_video(images(), out, fps, gif=gif)
    return {"path": out, "frames": len(files), "source": source, "seconds_per_frame": float(np.median(timing))}


def _read_mesh_points(path: Path) -> dict:
    from ..run.formats import read_mesh

    mesh = read_mesh(path)
    x = np.asarray(mesh.vertices, float).reshape(-1, 3)
    n = np.asarray(mesh.vertex_normals, float).reshape(-1, 3) if len(x) else np.zeros((0, 3))
    return {"x": x, "n": n}
