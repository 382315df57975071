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

Beside a wall the kernel's support around a point of the column is cut: in still water against a
side wall ``phi`` is 1/2 at the wall's face and its surface reads low (7 % a quarter spacing from
it, 0 on the face). So ``phi`` is divided by the share of the support on the liquid's side of the
still walls (:func:`gauge_support`, from the scene's shapes: exact beside a plane, approximate
at a corner or an edge), and a point inside a still obstacle or outside a mesh tank is solid:
the walk steps over it, neither wet nor dry, so a gauge over a still obstacle reads the water
standing on the obstacle. The tank's floor is left out: it cuts only the column's lowest ``H``,
where the walk already reads a film one spacing thick at 0.96 of it.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import warp as wp

from ..scene.shapes import Box, MeshShape, Sphere, enclosed
from .grid import CellGrid, cell_first, cell_hash, cell_range
from .kernel import cubic_W, cubic_W_np

# Below this share of the kernel's support on the liquid's side a gauge's point is in a wall.
SOLID_SHARE = wp.constant(0.25)

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
    support: wp.array(dtype=wp.float64),
    phi: wp.array(dtype=wp.float64),
):
    """``phi`` at point k of gauge g (``(x, bottom, z)`` in ``gauges``), ``(k + 1/2) dy`` above
    its bottom, over the support's share on the liquid's side (``support``); -1 where that share
    is under :data:`SOLID_SHARE` (a solid point)."""
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
    share = support[g * samples + k]
    if share < wp.float64(SOLID_SHARE):
        phi[g * samples + k] = wp.float64(-1.0)
    else:
        phi[g * samples + k] = acc / share


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
        value = phi[g * samples + k]
        if value >= half:
            top = k
            dry = 0.0
        elif value >= wp.float64(0.0):  # a solid point (-1) is neither
            dry += dy
            if dry > H:
                break
    level = wp.float64(0.0)
    if top >= 0:
        level = wp.float64((float(top) + 0.5) * dy)
        if top + 1 < samples:
            a = phi[g * samples + top]
            b = phi[g * samples + top + 1]
            if b >= wp.float64(0.0):  # the surface between two points of liquid and air
                level += wp.float64(dy) * (a - half) / (a - b)
    log[slot[0], column + g] = level


@functools.lru_cache(maxsize=1)
def _plane_share_table(n: int = 4001) -> tuple[np.ndarray, np.ndarray]:
    """The share of the cubic kernel's support (H = 1) on the near side of a plane a signed
    distance ``d`` from its centre (``d > 0``: the centre on that side), on ``d`` in [-1, 1]: one
    minus the integral of the kernel's one-dimensional marginal ``m(x) = 2 pi int_|x|^1 W(r) r dr``
    beyond ``d``."""
    r = np.linspace(0.0, 1.0, 20 * n + 1)
    f = cubic_W_np(r, 1.0) * r
    inner = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(r))])  # int_0^r
    m = 2.0 * math.pi * (inner[-1] - inner)  # the marginal at x = r
    beyond = np.concatenate([[0.0], np.cumsum(0.5 * (m[1:] + m[:-1]) * np.diff(r))])
    beyond = beyond[-1] - beyond  # int_x^1 m
    half = beyond[0]  # int_0^1 m = 1/2
    d = np.linspace(-1.0, 1.0, n)
    share = np.where(d >= 0.0, 1.0 - np.interp(d, r, beyond) / (2 * half), np.interp(-d, r, beyond) / (2 * half))
    return d, share


def plane_share(d, H: float) -> np.ndarray:
    """The share of the kernel's support ``H`` around a point on the liquid's side of a plane wall
    ``d`` away (negative: the point inside the wall)."""
    table_d, table_share = _plane_share_table()
    return np.interp(np.asarray(d, dtype=np.float64) / H, table_d, table_share)


def column_inside(shape, x: float, z: float, ys) -> np.ndarray:
    """Which heights ``ys`` of the vertical line at ``(x, z)`` lie inside a closed mesh ``shape``:
    the parity of its triangles' crossings below each (one pass over the triangles a column, where
    a winding number per point costs the triangles once per point)."""
    tri = np.asarray(shape.load().triangles, dtype=np.float64)
    px, pz = x + 1.2345e-9, z + 2.3456e-9  # off the lattice a mesh's vertices sit on
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]

    def side(u, v):  # twice the signed area of (u, v, p) in the xz plane
        return (v[:, 0] - u[:, 0]) * (pz - u[:, 2]) - (v[:, 2] - u[:, 2]) * (px - u[:, 0])

    s_ab, s_bc, s_ca = side(a, b), side(b, c), side(c, a)
    hit = ((s_ab > 0) & (s_bc > 0) & (s_ca > 0)) | ((s_ab < 0) & (s_bc < 0) & (s_ca < 0))
    total = (s_ab + s_bc + s_ca)[hit]
    heights = np.sort((s_bc[hit] * a[hit, 1] + s_ca[hit] * b[hit, 1] + s_ab[hit] * c[hit, 1]) / total)
    return np.searchsorted(heights, np.asarray(ys, dtype=np.float64)) % 2 == 1


def gauge_support(tank, obstacles, x: float, z: float, ys, H: float) -> np.ndarray:
    """For the points of a level gauge's column at ``(x, z)``, heights ``ys``: 0 where the point is
    solid (inside a still obstacle, or outside a mesh tank), else the share of the kernel's support
    ``H`` on the liquid's side of the still walls near it, at least :data:`SOLID_SHARE`, the floor
    and the top left out (see the module): a box tank's sides (a mesh tank's are not measured),
    each pair of opposite sides exactly (their losses add), the two pairs and the nearest still
    box or sphere obstacle, by its distance, multiplied (the kernel is not a product of its
    directions: approximate at a corner or a box's edge). 1 where no wall is within ``H``."""
    ys = np.asarray(ys, dtype=np.float64)
    q = np.column_stack([np.full(len(ys), x), ys, np.full(len(ys), z)])
    share = np.ones(len(q))
    solid = np.zeros(len(q), dtype=bool)
    if isinstance(tank, Box):  # two parallel walls cut apart slabs: their shares' losses add
        lo, hi = tank.bounds
        for a in (0, 2):
            share *= np.clip(plane_share(q[:, a] - lo[a], H) + plane_share(hi[a] - q[:, a], H) - 1.0, 0.0, 1.0)
    elif isinstance(tank, MeshShape):
        solid |= ~column_inside(enclosed(tank), x, z, ys)
    clearance = np.full(len(q), np.inf)
    for o in obstacles:
        if o.motion is not None:  # where it is changes: not measured
            continue
        if isinstance(o, Box):
            lo, hi = o.bounds
            depth = np.minimum(q - lo, hi - q).min(axis=1)  # how deep inside the box (negative: outside)
            outside = np.linalg.norm(np.maximum(np.maximum(lo - q, q - hi), 0.0), axis=1)
            solid |= depth >= 0.0  # its faces too: boxes that touch make one solid
            clearance = np.minimum(clearance, outside)
        elif isinstance(o, Sphere):
            distance = np.linalg.norm(q - np.asarray(o.center), axis=1) - o.radius
            solid |= distance <= 0.0
            clearance = np.minimum(clearance, np.maximum(distance, 0.0))
        else:
            lo, hi = o.bounds
            if lo[0] - H < x < hi[0] + H and lo[2] - H < z < hi[2] + H:
                solid |= column_inside(o, x, z, ys)
    share *= np.where(clearance >= H, 1.0, plane_share(np.minimum(clearance, H), H))
    return np.where(solid, 0.0, np.maximum(share, SOLID_SHARE))
