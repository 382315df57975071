"""Water at rest: the pressure a column must carry, rho0 g per metre of depth."""

from __future__ import annotations

import numpy as np


def hydrostatic_slope(
    x: np.ndarray, p: np.ndarray, spacing: float, tank_lower, tank_upper, rho0: float, g: float
) -> float:
    """The slope of pressure against depth, fitted over the interior (two spacings from the side
    walls, above the two layers on the floor), divided by ``rho0 g``: 1 for hydrostatic pressure."""
    lo, hi = np.asarray(tank_lower, float)[[0, 2]], np.asarray(tank_upper, float)[[0, 2]]
    interior = np.all((x[:, [0, 2]] > lo + 2 * spacing) & (x[:, [0, 2]] < hi - 2 * spacing), axis=1)
    interior &= x[:, 1] > np.asarray(tank_lower, float)[1] + 2 * spacing
    return float(-np.polyfit(x[interior, 1], p[interior], 1)[0] / (rho0 * g))
