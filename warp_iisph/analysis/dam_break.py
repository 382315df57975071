"""The dam break against Martin & Moyce (1952): the surge front of a run and the experiment's data."""

from __future__ import annotations

import csv
from importlib import resources

import numpy as np

MARTIN_MOYCE = "martin_moyce_1952.csv"


def load_martin_moyce() -> dict[str, np.ndarray]:
    """Martin & Moyce (1952) surge-front data (column height 2a): series name -> (k, 2) array
    of (T, Z) with ``T = t sqrt(2 g / a)`` and ``Z = front / a``."""
    text = resources.files("warp_iisph.analysis.data").joinpath(MARTIN_MOYCE).read_text()
    rows = list(csv.reader(line for line in text.splitlines() if not line.startswith("#")))
    out: dict[str, list] = {}
    for series, T, Z in rows[1:]:
        out.setdefault(series, []).append((float(T), float(Z)))
    return {k: np.asarray(v) for k, v in out.items()}


def surge_front(positions: np.ndarray, spacing: float, wall_x: float = 0.0) -> float:
    """Distance from the wall at ``wall_x`` to the leading edge of the liquid body along +x.

    The body is what is connected to the wall along x: particles are sorted by x and the first
    gap wider than two spacings ends it, so droplets thrown ahead of the front do not count.
    The edge is the last particle's centre plus half a spacing (the face of its volume).
    """
    x = np.sort(positions[:, 0])
    gaps = np.nonzero(np.diff(x) > 2.0 * spacing)[0]
    last = x[gaps[0]] if len(gaps) else x[-1]
    return float(last - wall_x + 0.5 * spacing)


def front_errors(
    T: np.ndarray, Z: np.ndarray, reference: dict[str, np.ndarray] | None = None, t_max: float = 3.0
) -> np.ndarray:
    """Relative error ``Z_sim / Z_exp - 1`` of a simulated front curve ``Z(T)`` (interpolated)
    at every Martin & Moyce point with ``T <= t_max``."""
    pts = np.concatenate(list((reference or load_martin_moyce()).values()))
    pts = pts[pts[:, 0] <= t_max]
    return np.interp(pts[:, 0], T, Z) / pts[:, 1] - 1.0
