"""SPH smoothing kernel: the cubic spline (Monaghan 1992) in 3D.

The support radius ``H`` is where the kernel reaches zero (twice the particle spacing by
default), written in the normalised form used by SPlisHSPlasH:
``W(q) = 8/(pi H^3) * {6(q^3 - q^2) + 1 for q <= 1/2; 2(1 - q)^3 for q <= 1}``, ``q = r/H``.
"""

import math

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.func
def cubic_W(r: float, H: float) -> float:
    q = r / H
    sigma = 8.0 / (wp.pi * H * H * H)
    if q <= 0.5:
        return sigma * (6.0 * (q * q * q - q * q) + 1.0)
    if q <= 1.0:
        t = 1.0 - q
        return sigma * 2.0 * t * t * t
    return 0.0


@wp.func
def cubic_grad_W(x_ij: wp.vec3, H: float) -> wp.vec3:
    r = wp.length(x_ij)
    q = r / H
    if r <= 1.0e-9 * H or q > 1.0:
        return wp.vec3(0.0, 0.0, 0.0)
    scale = 48.0 / (wp.pi * H * H * H)
    dW_dr = float(0.0)
    if q <= 0.5:
        dW_dr = scale * q * (3.0 * q - 2.0) / H
    else:
        t = 1.0 - q
        dW_dr = -scale * t * t / H
    return x_ij * (dW_dr / r)


def cubic_W_np(r, H):
    """NumPy twin of :func:`cubic_W` for set-up code and tests."""
    q = np.asarray(r, dtype=np.float64) / H
    sigma = 8.0 / (math.pi * H**3)
    inner = sigma * (6.0 * (q**3 - q**2) + 1.0)
    outer = sigma * 2.0 * np.clip(1.0 - q, 0.0, None) ** 3
    return np.where(q <= 0.5, inner, np.where(q <= 1.0, outer, 0.0))


def cubic_grad_W_np(x_ij, H):
    """NumPy twin of :func:`cubic_grad_W` for rows of offsets ``x_ij`` (n, 3)."""
    x_ij = np.asarray(x_ij, dtype=np.float64)
    r = np.linalg.norm(x_ij, axis=-1)
    q = r / H
    scale = 48.0 / (math.pi * H**3)
    dW_dr = np.where(q <= 0.5, scale * q * (3.0 * q - 2.0) / H, -scale * np.clip(1.0 - q, 0.0, None) ** 2 / H)
    dW_dr = np.where((r > 1.0e-9 * H) & (q <= 1.0), dW_dr, 0.0)
    return x_ij * (dW_dr / np.maximum(r, 1.0e-30))[..., None]


def lattice_grad_W_squared(h: float, H: float) -> float:
    """``sum_j |grad W_ij|^2`` over a particle's neighbours on a full cubic lattice of spacing
    ``h`` (the liquid at rest around it), support ``H``."""
    reach = int(np.ceil(H / h))
    k = np.arange(-reach, reach + 1) * h
    offsets = np.stack([a.ravel() for a in np.meshgrid(k, k, k, indexing="ij")], axis=1)
    return float((cubic_grad_W_np(offsets, H) ** 2).sum())
