"""The Mitsuba 3 scene of one frame, as a dict: the liquid a smooth dielectric filled with an absorbing
medium, a procedural sky, a checkered floor, the run's obstacles and the tank's far walls."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .camera import camera_up
from .materials import IOR, THICKNESS


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
