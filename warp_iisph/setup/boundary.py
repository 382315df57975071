"""Static boundaries as particles (Akinci et al. 2012).

Each boundary particle ``b`` contributes ``psi_b = gamma rho0 / sum_k W_bk`` to fluid densities
(sum over its boundary neighbours, itself included), so that a wall sampled unevenly still
pushes back like the fluid it replaces. ``gamma`` is calibrated once on a flat wall so that
fluid resting one spacing away from it is at rest density (:func:`flat_wall_gamma`). With
``gamma = 1`` (Akinci's original) the wall outweighs the fluid it replaces (by about 6 % of
rho0 for one layer), which kicks a tank at rest into motion.
"""

import functools

import numpy as np
import warp as wp

from ..engine.launch import launch_particles
from ..sph.kernel import cubic_W, cubic_W_np
from ..sph.neighbors import make_grid
from .sampling import flat_wall_patch

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


def flat_wall_gamma() -> float:
    """Scale ``gamma`` of the boundary weights such that a fluid particle resting one spacing
    from a flat wall, sampled as :func:`~warp_iisph.sampling.sample_tank_walls` does, with fluid
    filling the half-space above, has exactly the rest density. Independent of h."""
    return _flat_wall()[0]


def flat_wall_psi(h: float, rho0: float) -> float:
    """``psi`` of a particle in the middle of such a flat wall, at spacing ``h``."""
    gamma, delta = _flat_wall()
    return gamma * rho0 * h**3 / delta


@functools.lru_cache(maxsize=1)
def _flat_wall() -> tuple[float, float]:
    """``gamma`` and the boundary sum ``sum_k W_bk`` of the flat wall's middle particle, at h = 1
    (the calibration, done once)."""
    h, H = 1.0, 2.0
    wall, fluid = flat_wall_patch(h)
    centre = np.argmin(np.linalg.norm(wall[:, [0, 2]] - 0.5, axis=1) + np.abs(wall[:, 1] + 0.5))
    probe = np.array([0.5, 0.5, 0.5])
    rho_fluid = cubic_W_np(np.linalg.norm(fluid - probe, axis=1), H).sum() * h**3
    delta = np.array([cubic_W_np(np.linalg.norm(wall - w, axis=1), H).sum() for w in wall])
    near = np.linalg.norm(wall - probe, axis=1) < H
    # only wall particles far from the patch's edges have the sums of an infinite wall
    interior = np.all(np.abs(wall[:, [0, 2]] - 0.5) < 2.0, axis=1)
    assert np.all(interior[near]) and interior[centre]
    rho_wall = (cubic_W_np(np.linalg.norm(wall[near] - probe, axis=1), H) / delta[near]).sum()
    return float((1.0 - rho_fluid) / rho_wall), float(delta[centre])


@wp.kernel
def boundary_psi(
    offset: int,
    grid: wp.uint64,
    xb: wp.array(dtype=wp.vec3),
    H: float,
    rho0_gamma: float,
    psi: wp.array(dtype=float),
):
    b = wp.tid() + offset
    x_b = xb[b]
    delta = float(0.0)
    k = int(0)
    query = wp.hash_grid_query(grid, x_b, H)
    while wp.hash_grid_query_next(query, k):
        delta += cubic_W(wp.length(x_b - xb[k]), H)
    psi[b] = rho0_gamma / delta


def compute_boundary_psi(xb: wp.array, h: float, rho0: float, device) -> wp.array:
    """``psi_b`` for boundary particles ``xb`` sampled at about spacing ``h``."""
    H = 2.0 * h
    n = xb.shape[0]
    psi = wp.zeros(max(n, 1), dtype=float, device=device)
    if n == 0:
        return psi
    grid = make_grid(device)
    grid.build(xb, H)
    launch_particles(boundary_psi, n, [grid.id, xb, float(H), float(rho0 * flat_wall_gamma()), psi], device)
    return psi


@wp.kernel
def initial_density(
    offset: int,
    fluid_grid: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    boundary_grid: wp.uint64,
    xb: wp.array(dtype=wp.vec3),
    psi: wp.array(dtype=float),
    mass: float,
    H: float,
    rho: wp.array(dtype=float),
):
    i = wp.tid() + offset
    p = x[i]
    s = float(0.0)
    for j in wp.hash_grid_query(fluid_grid, p, H):
        s += mass * cubic_W(wp.length(p - x[j]), H)
    for b in wp.hash_grid_query(boundary_grid, p, H):
        s += psi[b] * cubic_W(wp.length(p - xb[b]), H)
    rho[i] = s


def overcompressed(
    xf: np.ndarray, xb: wp.array, psi: wp.array, h: float, rho0: float, tolerance: float, device
) -> np.ndarray:
    """Mask of the fluid particles ``xf`` whose density at rest, walls included, exceeds
    ``rho0 (1 + tolerance)``: sampled too close to a boundary, they would be kicked away."""
    H = 2.0 * h
    x = wp.array(xf.astype(np.float32), dtype=wp.vec3, device=device)
    fg, bg = make_grid(device), make_grid(device)
    fg.build(x, H)
    bg.build(xb, H)
    rho = wp.zeros(len(xf), dtype=float, device=device)
    launch_particles(initial_density, len(xf), [fg.id, x, bg.id, xb, psi, float(rho0 * h**3), float(H), rho], device)
    return rho.numpy() > rho0 * (1.0 + tolerance)
