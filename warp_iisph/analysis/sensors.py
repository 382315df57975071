"""The probes' readings in NumPy, from any code's particles: the same pressure sensor and level
gauge as the device's (:mod:`warp_iisph.sph.probes`, defined in docs/scenes.md), for measuring
another simulator's run (SPlisHSPlasH, which has no probes) the way ours is measured, and for
checking the device's readings."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..sph.kernel import cubic_W_np
from ..sph.probes import SOLID_SHARE, gauge_support


def pressure_readings(
    x: np.ndarray,
    p: np.ndarray,
    rho: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    spacing: float,
    rho0: float = 1000.0,
    gravity=(0.0, -9.81, 0.0),
    tree: cKDTree | None = None,
) -> np.ndarray:
    """Each sensor's reading (Pa): the Shepard average over the particles within 2h of the point
    moved h/2 along its normal, each pressure continued to it hydrostatically, at least 0."""
    H = 2.0 * spacing
    tree = tree if tree is not None else cKDTree(x)
    q = np.asarray(points, dtype=np.float64) + 0.5 * spacing * np.asarray(normals, dtype=np.float64)
    mass = rho0 * spacing**3
    out = np.zeros(len(q))
    for k, near in enumerate(tree.query_ball_point(q, H)):
        if not near:
            continue
        d = q[k] - x[near]
        w = mass / rho[near] * cubic_W_np(np.linalg.norm(d, axis=1), H)
        if w.sum() > 0.0:
            out[k] = max(float(np.sum(w * (p[near] + rho[near] * (d @ np.asarray(gravity))))) / float(w.sum()), 0.0)
    return out


def level_readings(
    x: np.ndarray,
    gauges: np.ndarray,
    bottom: float,
    top: float,
    spacing: float,
    tree: cKDTree | None = None,
    tank=None,
    obstacles=(),
) -> np.ndarray:
    """Each gauge's level above ``bottom`` (m) at its ``[x, z]``: where the occupancy
    ``sum_j h^3 W`` over the support's share on the liquid's side of the walls of the scene's
    ``tank`` and ``obstacles`` (:func:`warp_iisph.sph.probes.gauge_support`; with none given, 1)
    falls through 1/2 at the top of the liquid standing on the bottom (gaps shorter than 2h
    bridged, solid points stepped over)."""
    H, dy = 2.0 * spacing, 0.5 * spacing
    tree = tree if tree is not None else cKDTree(x)
    samples = max(1, int(np.ceil((top - bottom) / dy)))
    y = bottom + (np.arange(samples) + 0.5) * dy
    out = np.zeros(len(gauges))
    for g, (gx, gz) in enumerate(np.asarray(gauges, dtype=np.float64)):
        q = np.stack([np.full(samples, gx), y, np.full(samples, gz)], axis=1)
        share = gauge_support(tank, obstacles, gx, gz, y, H)
        phi = np.array(
            [
                spacing**3 * cubic_W_np(np.linalg.norm(x[n] - qk, axis=1), H).sum() if n else 0.0
                for qk, n in zip(q, tree.query_ball_point(q, H))
            ]
        )
        phi = np.where(share < SOLID_SHARE, -1.0, phi / np.maximum(share, SOLID_SHARE))  # as the device
        top_wet, dry = -1, 0.0
        for k in range(samples):
            if phi[k] >= 0.5:
                top_wet, dry = k, 0.0
            elif phi[k] >= 0.0:  # a solid point (-1) is neither
                dry += dy
                if dry > H:
                    break
        if top_wet >= 0:
            level = (top_wet + 0.5) * dy
            if top_wet + 1 < samples and phi[top_wet + 1] >= 0.0:
                a, b = phi[top_wet], phi[top_wet + 1]
                level += dy * (a - 0.5) / (a - b)
            out[g] = level
    return out
