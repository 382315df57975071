"""Particle sampling of fluid blocks and of the tank walls (set-up, NumPy).

Particles sit on a lattice of spacing ``h`` with their centres ``h/2`` inside the faces of the
volume they fill, so that ``N * h^3`` is the sampled volume. Box tank walls are boundary
particles (Akinci et al. 2012) in two staggered layers, the inner one centred ``h/2`` outside the
tank's inner faces: a fluid particle resting against a wall is one spacing from the wall.
"""

from __future__ import annotations

import numpy as np

from ..scene import Box, Sphere
from ..scene.checks import floats
from ..scene.shapes import LAYER_TOLERANCE, whole_layers


def _axis(lo: float, hi: float, h: float) -> np.ndarray:
    n = whole_layers(hi - lo, h)
    return lo + h * (0.5 + np.arange(n))


def sample_box(box: Box, h: float) -> np.ndarray:
    lo, hi = box.bounds
    axes = [_axis(lo[a], hi[a], h) for a in range(3)]
    g = np.meshgrid(*axes, indexing="ij")
    return np.stack([c.reshape(-1) for c in g], axis=1)


def sample_sphere(sphere: Sphere, h: float) -> np.ndarray:
    c = np.asarray(sphere.center, dtype=np.float64)
    n = int(np.ceil(sphere.radius / h)) + 1
    k = np.arange(-n, n + 1) * h
    g = np.meshgrid(k, k, k, indexing="ij")
    p = np.stack([a.reshape(-1) for a in g], axis=1)
    p = p[np.linalg.norm(p, axis=1) < sphere.radius]
    return p + c


def sample_fluid(fluids, tank, h: float) -> np.ndarray:
    """All fluid particles, without those closer than h/2 to a box tank's face (``tank`` may be
    None: mesh containers are cleared against their boundary particles instead); a block that
    holds none is an error, not a silent loss."""
    parts = [sample_box(f, h) if isinstance(f, Box) else sample_sphere(f, h) for f in fluids]
    if tank is not None:
        lo, hi = tank.bounds
        tol = LAYER_TOLERANCE * h  # a block that fills the tank keeps the layer the tolerance above gave it
        parts = [x[np.all((x >= lo + 0.5 * h - tol) & (x <= hi - 0.5 * h + tol), axis=1)] for x in parts]
    for k, x in enumerate(parts):
        if len(x) == 0:
            raise ValueError(
                f"fluids[{k}]: no particle fits in it at spacing = {h:g} m; make it larger or the spacing smaller"
            )
    return np.concatenate(parts, axis=0) if parts else np.zeros((0, 3))


def _box_shell(lo: np.ndarray, hi: np.ndarray, h: float, offset: float) -> np.ndarray:
    """Lattice points on the surface of the box ``lo - offset .. hi + offset``; along each axis
    the spacing is the largest ``s <= h`` that divides the tank's length ``hi - lo``."""
    axes = []
    for a in range(3):
        n = int(np.ceil((hi[a] - lo[a]) / h - 1e-6))
        s = (hi[a] - lo[a]) / n
        k = int(round(2.0 * offset / h))  # offset = k s / 2 when s = h
        ax = lo[a] - 0.5 * k * s + s * np.arange(n + k + 1)
        # the layer itself sits exactly ``offset`` outside the faces, also when s < h: a wall
        # drawn in closer would start the fluid beside it compressed
        ax[0], ax[-1] = lo[a] - offset, hi[a] + offset
        axes.append(ax)
    idx = np.meshgrid(*[np.arange(len(ax)) for ax in axes], indexing="ij")
    shell = np.zeros(idx[0].shape, dtype=bool)
    for a in range(3):
        shell |= (idx[a] == 0) | (idx[a] == len(axes[a]) - 1)
    return np.stack([axes[a][idx[a][shell]] for a in range(3)], axis=1)


def sample_tank_walls(tank: Box, h: float) -> np.ndarray:
    """Boundary particles of a closed box: two layers on the six walls, edges and corners.

    The inner layer sits ``h/2`` outside the inner faces (a fluid particle resting against a wall
    is one spacing from it); the outer layer sits ``h/2`` behind it, shifted by half a spacing
    along the wall, so that it covers the holes of the inner layer: a fast particle aimed at the
    middle of four wall particles meets one straight behind them instead of a gap.
    """
    lo, hi = tank.bounds
    return np.concatenate([_box_shell(lo, hi, h, 0.5 * h), _box_shell(lo, hi, h, h)], axis=0)


def sample_box_faces(box: Box, h: float) -> np.ndarray:
    """Boundary particles of a box obstacle as :func:`sample_tank_walls` samples a tank, inside
    out: two staggered layers h/2 and h inside its faces, so that a fluid particle resting against
    a face is one spacing from the inner layer and its volume ends at the face, and the weights
    ``psi`` calibrated on the tank's walls hold for it. Needs every side at least 3 h long."""
    lo, hi = box.bounds
    if box.too_thin_for_faces(h):
        raise ValueError(
            f"sampling = 'faces': every side of the box must be at least 3 spacings ({3 * h:g} m) long; "
            f"it is {floats(hi - lo)}"
        )
    return np.concatenate([_box_shell(lo, hi, h, -0.5 * h), _box_shell(lo, hi, h, -h)], axis=0)


def flat_wall_patch(h: float, half_width: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A patch of the wall :func:`sample_tank_walls` builds (the floor y < 0, both layers) and the
    lattice of fluid above it, for calibrating boundary weights. Returns (wall, fluid)."""
    k = np.arange(-half_width, half_width + 1) * h
    gx, gz = np.meshgrid(k, k, indexing="ij")
    inner = np.stack([gx.ravel() + 0.5 * h, np.full(gx.size, -0.5 * h), gz.ravel() + 0.5 * h], axis=1)
    outer = np.stack([gx.ravel(), np.full(gx.size, -h), gz.ravel()], axis=1)
    fy = (np.arange(4) + 0.5) * h
    fx, fy, fz = np.meshgrid(k + 0.5 * h, fy, k + 0.5 * h, indexing="ij")
    fluid = np.stack([fx.ravel(), fy.ravel(), fz.ravel()], axis=1)
    return np.concatenate([inner, outer]), fluid
