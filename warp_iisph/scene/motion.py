"""Keyframed rigid motion of an obstacle: translations and rotations at key times, interpolated.

At key ``k`` the obstacle, as the scene places it, is rotated by ``rotate[k]`` (degrees about x,
then y, then z) about ``pivot`` and moved by ``translate[k]``. Between keys the translation and
the angles are interpolated linearly or smoothly (cubic Hermite through the keys with
Catmull-Rom slopes, zero at the ends: velocities are continuous and the body starts and stops
gently); before the first key and after the last the body holds still. The device evaluates the
same formulas (``warp_iisph.sph.bodies``); :meth:`Motion.at` is their NumPy twin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .checks import MAX_COORDINATE, Record, position, vec3

INTERPOLATIONS = ("linear", "smooth")
MAX_KEYS = 256
MAX_ANGLE = 1.0e6  # degrees: thousands of turns; beyond it the velocities the keys give leave float32


@dataclass
class Motion(Record):
    times: list
    translate: list = field(default_factory=list)
    rotate: list = field(default_factory=list)
    pivot: Optional[tuple] = None
    interpolation: str = "smooth"

    def validate(self, name: str) -> "Motion":
        t = self.times
        if not isinstance(t, (list, tuple)) or not 1 <= len(t) <= MAX_KEYS:
            raise ValueError(f"{name}.times = {t!r}: must be a list of 1 to {MAX_KEYS} key times (seconds)")
        try:
            if any(isinstance(v, (bool, str)) for v in t):
                raise TypeError
            times = np.asarray(t, dtype=np.float64)
            if times.ndim != 1:  # [[0, 1]]: a nested list is not a list of times
                raise TypeError
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{name}.times = {t!r}: must be a list of numbers (seconds)") from None
        if not np.all(np.isfinite(times)) or np.any(times < 0) or np.any(np.diff(times) <= 0):
            raise ValueError(f"{name}.times = {t!r}: must be finite, >= 0 and increasing")
        k = len(times)
        keys = {}
        for key in ("translate", "rotate"):
            v = getattr(self, key)
            if v is None or (isinstance(v, (list, tuple)) and len(v) == 0):
                keys[key] = np.zeros((k, 3))
                continue
            if not isinstance(v, (list, tuple)) or len(v) != k:
                raise ValueError(f"{name}.{key}: must give one [x, y, z] per key time ({k}), not {v!r}")
            keys[key] = np.array([vec3(row, f"{name}.{key}[{j}]") for j, row in enumerate(v)])
        if np.any(np.abs(keys["translate"]) > MAX_COORDINATE):
            raise ValueError(f"{name}.translate: must stay within {MAX_COORDINATE:g} m")
        if np.any(np.abs(keys["rotate"]) > MAX_ANGLE):
            raise ValueError(f"{name}.rotate: angles must stay within {MAX_ANGLE:g} degrees")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"{name}.interpolation = {self.interpolation!r}: must be one of {', '.join(INTERPOLATIONS)}"
            )
        self.times = times.tolist()
        self.translate = keys["translate"].tolist()
        self.rotate = keys["rotate"].tolist()
        if self.pivot is not None:
            self.pivot = tuple(float(c) for c in position(self.pivot, f"{name}.pivot"))
        return self

    @property
    def end(self) -> float:
        return float(self.times[-1])

    def _keys(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The key times, translations and angles as arrays, a key list left empty as zeros (what
        :meth:`validate` makes of it: a motion read before its scene is validated reads the same)."""
        t = np.asarray(self.times, dtype=np.float64)
        tr, rot = (np.asarray(v, float) if len(v) else np.zeros((len(t), 3)) for v in (self.translate, self.rotate))
        return t, tr, rot

    def slopes(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-key slopes of translation and angles (zero for linear, which needs none)."""
        t, tr, rot = self._keys()
        out = []
        for v in (tr, rot):
            m = np.zeros_like(v)
            if self.interpolation == "smooth" and len(t) > 2:
                m[1:-1] = (v[2:] - v[:-2]) / (t[2:] - t[:-2])[:, None]
            out.append(m)
        return out[0], out[1]

    def at(self, time: float) -> tuple[np.ndarray, np.ndarray]:
        """Translation (m) and angles (degrees) at ``time``."""
        t, tr, rot = self._keys()
        if time <= t[0] or len(t) == 1:
            return tr[0].copy(), rot[0].copy()
        if time >= t[-1]:
            return tr[-1].copy(), rot[-1].copy()
        k = int(np.searchsorted(t, time, side="right")) - 1
        dt = t[k + 1] - t[k]
        s = (time - t[k]) / dt
        mt, mr = self.slopes()
        if self.interpolation == "linear":
            return tr[k] + s * (tr[k + 1] - tr[k]), rot[k] + s * (rot[k + 1] - rot[k])
        h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
        return (
            h00 * tr[k] + h10 * dt * mt[k] + h01 * tr[k + 1] + h11 * dt * mt[k + 1],
            h00 * rot[k] + h10 * dt * mr[k] + h01 * rot[k + 1] + h11 * dt * mr[k + 1],
        )

    def matrix(self, time: float, pivot: np.ndarray) -> np.ndarray:
        """The 4x4 rigid transform at ``time`` of points placed by the scene (rotation about
        ``pivot`` about x, then y, then z, then the translation)."""
        tr, rot = self.at(time)
        R = rotation_xyz(rot)
        m = np.eye(4)
        m[:3, :3] = R
        m[:3, 3] = pivot + tr - R @ pivot
        return m


def rotation_xyz(degrees) -> np.ndarray:
    """Rotation by angles (degrees) about x, then y, then z (fixed axes): ``Rz Ry Rx``."""
    ax, ay, az = (math.radians(float(a)) for a in degrees)
    cx, sx, cy, sy, cz, sz = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx
