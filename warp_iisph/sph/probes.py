"""What a pressure sensor and a level gauge read, gathered on the device from the fluid particles
around a point: each probe (or each point of a gauge's column) is one thread walking the grid
cells the step's neighbour search sorted the particles into, in a fixed order, so a reading is
the same bits on every path.

The grid holds the particles where the step started; a reading comes after it, so the cells
searched reach ``H + dt max|v| + h`` (what the step moved them, and a spacing for the walls'
corrections) and the particles are tested where they are now.

Pressure (a flush-mounted sensor): a Shepard average over the fluid particles within the
support ``H`` of the point moved half a spacing into the liquid along the wall's normal (where
the first layer of particles sits), each particle's pressure continued to the point with the
hydrostatic gradient the walls' pressures use (:mod:`.wall_pressure`),

    p = max(sum_j V_j W_j (p_j + rho_j g . (x - x_j)) / sum_j V_j W_j, 0),  V_j = m / rho_j,

so that water at rest reads its hydrostatic pressure at the point itself, and no particle within
reach reads 0 (a dry sensor).

Level (a gauge): the kernel-smoothed occupancy ``phi(y) = sum_j (m / rho0) W(|x - x_j|)`` (about
1 in the liquid, 1/2 at a flat surface, 0 in air; each particle counts with its own volume h^3,
not the SPH volume m / rho_j, which the missing neighbours of a free surface inflate by a third
and more) at points every half spacing up the column; the
level is the height where ``phi`` falls through 1/2 at the top of the liquid standing on the
bottom: walking up from the bottom, gaps where ``phi < 1/2`` shorter than ``H`` (an air pocket,
a film torn for an instant) are bridged, a longer one ends the column, so spray above it does
not count; a column whose lowest ``H`` is dry reads 0.
"""

from __future__ import annotations

import warp as wp

from .grid import CellGrid, cell_first, cell_hash, cell_range
from .kernel import cubic_W

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.struct
class Reach:
    """How far from a point the grid is searched: the support ``H``, and what the step moved
    particles (its ``dt`` times the top speed, ``max_speed2`` squared) plus a spacing ``h``."""

    H: float
    h: float
    dt: wp.array(dtype=wp.float64)
    max_speed2: wp.array(dtype=float)


@wp.func
def reach(r: Reach) -> float:
    return r.H + float(r.dt[0]) * wp.sqrt(r.max_speed2[0]) + r.h


@wp.kernel
def pressure_probes(
    grid: CellGrid,
    x: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=float),
    rho: wp.array(dtype=float),
    points: wp.array(dtype=wp.vec3),
    gravity: wp.vec3,
    mass: float,
    around: Reach,
    slot: wp.array(dtype=wp.int32),
    column: int,
    log: wp.array2d(dtype=wp.float64),
):
    """Probe k's reading into column ``column + k`` of the log's row ``slot``."""
    k = wp.tid()
    q = points[k]
    r = reach(around)
    H = around.H
    cx = cell_range(grid, q, r, 0)
    cy = cell_range(grid, q, r, 1)
    cz = cell_range(grid, q, r, 2)
    weights = wp.float64(0.0)
    total = wp.float64(0.0)
    for z in range(cz[0], cz[1] + 1):
        for y in range(cy[0], cy[1] + 1):
            for xc in range(cx[0], cx[1] + 1):
                c = cell_hash(xc, y, z)
                s = cell_first(grid, c)
                while s < grid.n and grid.keys[s] == c:
                    j = grid.ids[s]
                    s += 1
                    d = q - x[j]
                    dist = wp.length(d)
                    if dist < H:
                        rho_j = rho[j]
                        w = wp.float64(mass / rho_j * cubic_W(dist, H))
                        weights += w
                        total += w * wp.float64(p[j] + rho_j * wp.dot(gravity, d))
    value = wp.float64(0.0)
    if weights > wp.float64(0.0):
        value = wp.max(total / weights, wp.float64(0.0))
    log[slot[0], column + k] = value


@wp.kernel
def occupancy(
    grid: CellGrid,
    x: wp.array(dtype=wp.vec3),
    gauges: wp.array(dtype=wp.vec3),
    samples: int,
    dy: float,
    volume: float,
    around: Reach,
    phi: wp.array(dtype=wp.float64),
):
    """``phi`` at point k of gauge g (``(x, bottom, z)`` in ``gauges``), ``(k + 1/2) dy`` above
    its bottom."""
    g, k = wp.tid()
    base = gauges[g]
    q = wp.vec3(base[0], base[1] + (float(k) + 0.5) * dy, base[2])
    r = reach(around)
    H = around.H
    cx = cell_range(grid, q, r, 0)
    cy = cell_range(grid, q, r, 1)
    cz = cell_range(grid, q, r, 2)
    acc = wp.float64(0.0)
    for z in range(cz[0], cz[1] + 1):
        for y in range(cy[0], cy[1] + 1):
            for xc in range(cx[0], cx[1] + 1):
                c = cell_hash(xc, y, z)
                s = cell_first(grid, c)
                while s < grid.n and grid.keys[s] == c:
                    j = grid.ids[s]
                    s += 1
                    dist = wp.length(q - x[j])
                    if dist < H:
                        acc += wp.float64(volume * cubic_W(dist, H))
    phi[g * samples + k] = acc


@wp.kernel
def gauge_levels(
    phi: wp.array(dtype=wp.float64),
    samples: int,
    dy: float,
    H: float,
    slot: wp.array(dtype=wp.int32),
    column: int,
    log: wp.array2d(dtype=wp.float64),
):
    """Gauge g's level above its bottom (see the module) into column ``column + g``."""
    g = wp.tid()
    half = wp.float64(0.5)
    top = int(-1)  # the last wet point of the column standing on the bottom
    dry = float(0.0)  # how long the column has been dry since
    for k in range(samples):
        if phi[g * samples + k] >= half:
            top = k
            dry = 0.0
        else:
            dry += dy
            if dry > H:
                break
    level = wp.float64(0.0)
    if top >= 0:
        level = wp.float64((float(top) + 0.5) * dy)
        if top + 1 < samples:
            a = phi[g * samples + top]
            b = phi[g * samples + top + 1]
            level += wp.float64(dy) * (a - half) / (a - b)
    log[slot[0], column + g] = level
