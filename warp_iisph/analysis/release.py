"""The pressure in a rectangular column of liquid at the instant it is released: an exact
potential-flow result, a test of the pressure solve with no start-up ambiguity.

A column of width ``a`` and height ``H`` stands on a floor (y = 0) against a back wall (x = 0),
held by a gate at x = a that vanishes at t = 0. At t = 0+ the liquid is at rest and
incompressible, so its acceleration ``A = g - grad p / rho`` is divergence-free and the pressure
is harmonic:

    laplace(p) = 0  in 0 < x < a, 0 < y < H,
    p = 0  on the free surfaces y = H and x = a,
    dp/dn = rho g . n  on the walls (the liquid does not accelerate through them):
        dp/dx = 0 at x = 0,  dp/dy = -rho g at y = 0.

Write ``p = rho g (H - y) + q``: the hydrostatic part meets the walls' conditions and the top's,
and ``q`` is harmonic with ``dq/dx = 0`` at x = 0, ``dq/dy = 0`` at y = 0, ``q = 0`` at y = H and
``q = -rho g (H - y)`` at x = a. Cosines ``cos(k_n y)`` with ``k_n = (2n + 1) pi / (2H)`` have a
zero slope at the floor and vanish at the top; ``cosh(k_n x)`` has a zero slope at the back
wall. So ``q = sum_n A_n cosh(k_n x) cos(k_n y)``, and matching the front face with
``(2/H) int_0^H (H - y) cos(k_n y) dy = 2 / (H k_n^2)`` (as ``cos(k_n H) = 0``):

    p(x, y) = rho g [ (H - y) - (2/H) sum_n cos(k_n y) cosh(k_n x) / (k_n^2 cosh(k_n a)) ].

At the foot of the back wall ``p(0, 0) = rho g [H - (2/H) sum_n 1 / (k_n^2 cosh(k_n a))]``:
0.3697 rho g H for the Martin & Moyce column (a = H/2), and the hydrostatic rho g H as the column
grows wide (a >> H). The series converges like ``exp(-k_n (a - x))``, and like ``1/n^2`` on the
front face itself.
"""

from __future__ import annotations

import numpy as np


def _modes(x, width: float, height: float, terms: int) -> tuple[np.ndarray, np.ndarray]:
    """The series' wavenumbers ``k_n`` and ``cosh(k_n x) / cosh(k_n a)`` at each ``x`` (a last
    axis over n), the ratio written without overflow."""
    x = np.asarray(x, dtype=np.float64)[..., None]
    k = (2.0 * np.arange(terms) + 1.0) * np.pi / (2.0 * height)
    return k, np.exp(k * (x - width)) * (1.0 + np.exp(-2.0 * k * x)) / (1.0 + np.exp(-2.0 * k * width))


def release_pressure(
    x, y, width: float, height: float, rho: float = 1000.0, g: float = 9.81, terms: int = 4000
) -> np.ndarray:
    """The pressure (Pa) at (x, y) in the column (``0 <= x <= width``, ``0 <= y <= height``) at the
    instant of release (see the module); ``terms`` of the series."""
    y = np.asarray(y, dtype=np.float64)[..., None]
    k, ratio = _modes(x, width, height, terms)
    series = np.sum(np.cos(k * y) * ratio / k**2, axis=-1)
    return rho * g * ((height - y[..., 0]) - 2.0 / height * series)


def release_surface_acceleration(x, width: float, height: float, g: float = 9.81, terms: int = 4000) -> np.ndarray:
    """The free top's downward acceleration (m/s^2) at ``x`` from the back wall at the instant of
    release: at y = H, where p = 0, ``A_y = -g - (1/rho) dp/dy``, and from the series above
    ``dp/dy = rho g [-1 + (2/H) sum_n (-1)^n cosh(k_n x) / (k_n cosh(k_n a))]`` (``sin(k_n H) =
    (-1)^n``), so the top falls at ``(2 g / H) sum_n (-1)^n cosh(k_n x) / (k_n cosh(k_n a))``: g at
    the front corner, nearly nothing far behind it. No gate lets the top fall faster: a gate still
    partly there holds a pressure of at least zero on part of the front face, so by the maximum
    principle the pressure inside is no lower than after the complete release, and where the top
    keeps p = 0 its pressure falls less steeply towards it."""
    k, ratio = _modes(x, width, height, terms)
    sign = np.where(np.arange(terms) % 2 == 0, 1.0, -1.0)
    return 2.0 * g / height * np.sum(sign * ratio / k, axis=-1)
