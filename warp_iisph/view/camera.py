"""Where a view of a run looks from: the scene file's ``[camera]``, or a camera framed on the
liquid and the obstacles; shared by the render, the USD stage and the Blender script."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..run.folder import MESHES, RECORD, RunError, RunFolder, tank_bounds
from ..run.formats import read_mesh
from ..scene.settings import Camera

DEFAULT_FOV = 40.0  # degrees, horizontal; the scene's camera.fov default


def camera_up(eye, target) -> list[float]:
    """The up direction of a camera at ``eye`` looking at ``target``: y, or -z when it looks
    (almost) straight up or down, where y would leave its orientation undefined."""
    view = np.asarray(target, float) - np.asarray(eye, float)
    return [0.0, 1.0, 0.0] if abs(view[1]) < 0.999 * float(np.linalg.norm(view)) else [0.0, 0.0, -1.0]


def auto_camera(lower, upper, fov: float, aspect: float) -> tuple[np.ndarray, np.ndarray]:
    """Look at the box's centre from the front, right and above, far enough to see all of it."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    target = 0.5 * (lower + upper)
    radius = 0.5 * float(np.linalg.norm(upper - lower))
    direction = np.array([0.45, 0.5, 1.0]) / np.linalg.norm([0.45, 0.5, 1.0])
    half = math.radians(0.5 * fov)
    half = min(half, math.atan(math.tan(half) / aspect))  # the narrower of the two
    return target + direction * radius / math.sin(half) * 1.05, target


def mesh_bounds(paths: list[Path]) -> tuple[np.ndarray, np.ndarray] | None:
    """The corners of the box around the vertices of these meshes; ``None`` when all are empty."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for p in paths:
        v = np.asarray(read_mesh(p).vertices).reshape(-1, 3)
        if len(v):
            lo, hi = np.minimum(lo, v.min(0)), np.maximum(hi, v.max(0))
    return (lo, hi) if np.all(np.isfinite(lo)) else None


def framing_box(run: RunFolder, record: dict, files: list[Path], obstacles=None) -> tuple[np.ndarray, np.ndarray]:
    """What a camera frames: the liquid of the first, middle and last of ``files`` (the box tank
    when they are empty) and the ``obstacles`` mesh (``RunError`` when there is nothing to frame)."""
    box = mesh_bounds([files[0], files[len(files) // 2], files[-1]]) or tank_bounds(record, run.record_path)
    if box is None:
        raise RunError(f"{run.path / MESHES}: the meshes are empty and the run has no box tank to frame")
    if obstacles is not None:
        box = (np.minimum(box[0], obstacles.bounds[0]), np.maximum(box[1], obstacles.bounds[1]))
    return box


def run_camera(record: dict, box, aspect: float, source=RECORD) -> tuple[np.ndarray, np.ndarray, float]:
    """``(eye, target, fov)``: the run's scene camera (its target defaults to the box's centre),
    or :func:`auto_camera` on ``box``; ``fov`` is horizontal, in degrees (``source``: the
    record's file, for messages)."""
    table = (record.get("scene") or {}).get("camera") or {}
    try:
        cam = Camera(**table)
        cam.validate()
    except (TypeError, ValueError) as e:  # a record edited by hand
        raise RunError(f"{source}: {e}") from None
    fov = cam.fov
    if cam.position is not None:
        eye = np.asarray(cam.position, float)
        target = np.asarray(cam.target, float) if cam.target else 0.5 * (np.asarray(box[0]) + np.asarray(box[1]))
        return eye, target, fov
    eye, target = auto_camera(*box, fov, aspect)
    return eye, target, fov
