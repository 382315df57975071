"""Where liquid enters and leaves a scene: emitters (a nozzle, a disc or a rectangle, that injects
particles at a speed) and sinks (boxes that remove the particles entering them)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .checks import MAX_COORDINATE, Record, box_corners, floats, in_range, position, unit
from .shapes import whole_layers

NOZZLES = ("disc", "rectangle")


@dataclass
class Emitter(Record):
    """A nozzle at ``center`` facing ``direction`` that injects liquid at ``speed`` (m/s) from
    ``start`` to ``end`` (s): a disc of ``radius``, or a rectangle of ``size`` [width, height]
    (width along ``direction x up``, ``up`` the world's y, or x for a vertical nozzle). It emits
    one layer of particles on a lattice of the scene's spacing each time the last layer has moved
    one spacing, so the stream keeps the spacing of the liquid it joins."""

    center: tuple
    direction: tuple
    speed: float
    shape: str = "disc"
    radius: Optional[float] = None
    size: Optional[tuple] = None
    start: float = 0.0
    end: Optional[float] = None  # seconds; None: it never stops

    def validate(self, name: str) -> None:
        self.center = floats(position(self.center, f"{name}.center"))
        self.direction = floats(unit(self.direction, f"{name}.direction", "the way the nozzle points"))
        self.speed = in_range(self.speed, f"{name}.speed", 0.0, 100.0, "m/s", lo_open=True)
        if self.shape not in NOZZLES:
            raise ValueError(f"{name}.shape = {self.shape!r}: must be one of {', '.join(NOZZLES)}")
        if self.shape == "disc":
            if self.radius is None:
                raise ValueError(f"{name}.radius: required for shape = 'disc' (metres)")
            self.radius = in_range(self.radius, f"{name}.radius", 0.0, MAX_COORDINATE, "metres", lo_open=True)
        else:
            if self.size is None:
                raise ValueError(f"{name}.size: required for shape = 'rectangle' ([width, height], metres)")
            try:
                w, h = (float(v) for v in self.size)
            except (TypeError, ValueError, OverflowError):
                raise ValueError(f"{name}.size = {self.size!r}: must be [width, height] in metres") from None
            for v in (w, h):
                in_range(v, f"{name}.size", 0.0, MAX_COORDINATE, "metres", lo_open=True)
            self.size = (w, h)
        # the other nozzle's key is left out (a --set that switches the shape cannot remove it)
        setattr(self, "size" if self.shape == "disc" else "radius", None)
        self.start = in_range(self.start, f"{name}.start", 0.0, 1.0e6, "seconds")
        if self.end is not None:
            self.end = in_range(self.end, f"{name}.end", self.start, 1.0e6, "seconds, > start", lo_open=True)

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Two unit vectors spanning the nozzle: along its width and its height."""
        d = np.asarray(self.direction)
        up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        u = np.cross(d, up)
        u /= np.linalg.norm(u)
        return u, np.cross(u, d)

    def layer(self, h: float) -> np.ndarray:
        """The points of one layer, relative to the centre: a square lattice of spacing ``h`` over
        the nozzle (centred, so a nozzle narrower than ``h`` still emits one particle)."""
        u, v = self.axes()
        if self.shape == "disc":
            n = int(np.ceil(self.radius / h)) + 1
            k = np.arange(-n, n + 1) * h
            a, b = (g.ravel() for g in np.meshgrid(k, k, indexing="ij"))
            keep = a**2 + b**2 <= max(self.radius, 0.5 * h) ** 2 + 1e-12
        else:
            w, ht = self.size
            na, nb = max(1, whole_layers(w, h)), max(1, whole_layers(ht, h))
            a, b = (
                g.ravel()
                for g in np.meshgrid(
                    (np.arange(na) - 0.5 * (na - 1)) * h, (np.arange(nb) - 0.5 * (nb - 1)) * h, indexing="ij"
                )
            )
            keep = np.ones(len(a), dtype=bool)
        return np.outer(a[keep], u) + np.outer(b[keep], v)

    def layer_size(self, h: float) -> int:
        """How many points :meth:`layer` has, counted row by row with its own comparisons, so
        that a nozzle far wider than the spacing costs no memory to count."""
        if self.shape != "disc":
            w, ht = self.size
            return max(1, whole_layers(w, h)) * max(1, whole_layers(ht, h))
        n = int(np.ceil(self.radius / h)) + 1
        a = np.arange(-n, n + 1) * h
        bound = max(self.radius, 0.5 * h) ** 2 + 1e-12
        # the largest j with a^2 + (j h)^2 <= bound, row by row: near the analytic one, then the
        # very comparison layer() makes decides (the rows' sets are symmetric and contiguous in j)
        guess = np.floor(np.sqrt(np.maximum(bound - a**2, 0.0)) / h).astype(np.int64)
        j_max = np.full(len(a), -1, dtype=np.int64)
        for shift in (-2, -1, 0, 1, 2):
            j = np.clip(guess + shift, 0, n)
            ok = a**2 + (j * h) ** 2 <= bound
            j_max = np.where(ok, np.maximum(j_max, j), j_max)
        return int(np.sum(np.where(j_max >= 0, 2 * j_max + 1, 0)))

    def half_extent(self) -> np.ndarray:
        """Half the nozzle's size along x, y and z (its layers reach this far from the centre)."""
        u, v = (np.abs(a) for a in self.axes())
        if self.shape == "disc":
            return self.radius * np.sqrt(u**2 + v**2)
        w, ht = self.size
        return 0.5 * (w * u + ht * v)

    def rim(self) -> np.ndarray:
        """The centre and points around the nozzle's edge (absolute, metres): what a check of
        where it stands looks at."""
        u, v = self.axes()
        if self.shape == "disc":
            angles = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
            edge = self.radius * (np.outer(np.cos(angles), u) + np.outer(np.sin(angles), v))
        else:
            w, ht = self.size
            edge = np.array([0.5 * (i * w * u + j * ht * v) for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j])
        return np.asarray(self.center) + np.vstack([np.zeros(3), edge])

    def particles(self, h: float, until: float) -> int:
        """How many particles it emits from ``start`` to ``until`` (s)."""
        t = max(0.0, min(math.inf if self.end is None else self.end, until) - self.start)
        return self.layer_size(h) * (int(np.floor(t * self.speed / h)) + 1) if until >= self.start else 0


@dataclass
class Sink(Record):
    """A box from ``lower`` to ``upper`` (metres): particles that enter it leave the scene."""

    lower: tuple
    upper: tuple

    def validate(self, name: str) -> None:
        self.lower, self.upper = box_corners(self.lower, self.upper, name)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.lower, dtype=np.float64), np.asarray(self.upper, dtype=np.float64)
