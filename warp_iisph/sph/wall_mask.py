"""Where a query may have a neighbour among the walls: a mask of cells, so that particles far from
every wall skip the walls' grids. The still walls' mask is built once; the moving bodies' is
marked again every step (a few thousand points, no allocation: graph-safe)."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch_particles

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.struct
class NearMask:
    """Cells of size a little over the radius, over the other set's bounding box grown by one
    cell: ``near`` is 1 where a cell or one of its 26 neighbours holds a point of the set, so a
    query point in a cell marked 0 (or outside the box) has no neighbour in it. ``dims`` 0:
    no mask, every point queries."""

    lower: wp.vec3
    cell: float
    dims: wp.vec3i
    near: wp.array(dtype=wp.uint8)


@wp.func
def mask_cell(m: NearMask, p: wp.vec3) -> wp.vec3i:
    q = (p - m.lower) / m.cell
    return wp.vec3i(int(wp.floor(q[0])), int(wp.floor(q[1])), int(wp.floor(q[2])))


@wp.func
def mask_flat(m: NearMask, c: wp.vec3i) -> int:
    if c[0] < 0 or c[1] < 0 or c[2] < 0 or c[0] >= m.dims[0] or c[1] >= m.dims[1] or c[2] >= m.dims[2]:
        return -1
    return (c[0] * m.dims[1] + c[1]) * m.dims[2] + c[2]


@wp.func
def may_have_neighbors(m: NearMask, p: wp.vec3) -> bool:
    if m.dims[0] == 0:
        return True
    k = mask_flat(m, mask_cell(m, p))
    if k < 0:
        return False
    return m.near[k] != wp.uint8(0)


@wp.kernel
def occupy_cells(m: NearMask, points: wp.array(dtype=wp.vec3), occupied: wp.array(dtype=wp.int32)):
    k = mask_flat(m, mask_cell(m, points[wp.tid()]))
    if k >= 0:
        occupied[k] = 1  # every writer writes the same value: no atomic needed


@wp.kernel
def dilate_cells(offset: int, m: NearMask, occupied: wp.array(dtype=wp.int32)):
    k = wp.tid() + offset
    c = wp.vec3i(k // (m.dims[1] * m.dims[2]), (k // m.dims[2]) % m.dims[1], k % m.dims[2])
    hit = wp.uint8(0)
    for a in range(-1, 2):
        for b in range(-1, 2):
            for e in range(-1, 2):
                j = mask_flat(m, c + wp.vec3i(a, b, e))
                if j >= 0:
                    if occupied[j] != 0:
                        hit = wp.uint8(1)
    m.near[k] = hit


# Above this many mask cells (bytes) the walls' bounding box is too fine to mask; every point queries.
MAX_MASK_CELLS = 1 << 27
# Nor beyond this many cells from the origin along an axis: float32 rounds a point's cell
# coordinate by up to a few ulps of it, and the cells' 0.1 % margin over the radius must cover that.
MAX_MASK_REACH = 2048


def mask_box(lo: np.ndarray, hi: np.ndarray, radius: float, grow: int):
    """Cells of 1.001 ``radius`` over [lo, hi] grown by ``grow`` cells: (lower, cell, dims), or
    None where the mask would be too large or too far from the origin to be exact."""
    cell = 1.001 * float(radius)
    lower = lo - grow * cell
    upper = hi + grow * cell
    dims = np.floor((upper - lower) / cell).astype(np.int64) + 1
    reach = np.maximum(np.abs(lower), np.abs(upper)).max() / cell
    if int(np.prod(dims)) > MAX_MASK_CELLS or reach > MAX_MASK_REACH:
        return None
    return lower, cell, dims


def _mask_over(box, device) -> NearMask:
    """An unmarked :class:`NearMask` over ``box`` (:func:`mask_box`'s lower, cell, dims)."""
    lower, cell, dims = box
    m = NearMask()
    m.lower, m.cell, m.dims = wp.vec3(*lower.tolist()), cell, wp.vec3i(*[int(d) for d in dims])
    m.near = wp.zeros(int(np.prod(dims)), dtype=wp.uint8, device=device)
    return m


def _no_mask(device) -> NearMask:
    m = NearMask()
    m.lower, m.cell, m.dims = wp.vec3(0.0), 1.0, wp.vec3i(0, 0, 0)
    m.near = wp.zeros(1, dtype=wp.uint8, device=device)
    return m


def near_mask(points: wp.array, radius: float, device) -> NearMask:
    """Where a point may have a neighbour among the static ``points`` (the walls): cells of
    1.001 ``radius`` (so two points within ``radius`` lie in neighbouring cells even after
    float rounding) over their bounding box grown by a cell, each marked when it or a neighbour
    holds one of them. Built once; a point elsewhere has no neighbour there."""
    xs = points.numpy()
    box = mask_box(xs.min(axis=0), xs.max(axis=0), radius, 1) if len(xs) else None
    if box is None:
        return _no_mask(device)
    m = _mask_over(box, device)
    cells = m.near.shape[0]
    occupied = wp.zeros(cells, dtype=wp.int32, device=device)
    wp.launch(occupy_cells, dim=len(xs), inputs=[m, points, occupied], device=device)
    launch_particles(dilate_cells, cells, [m, occupied], device)
    return m


@wp.struct
class MovingMask:
    """Cells near the moving points of this step (:class:`NearMask` layout, marked by
    :func:`mark_moving`); ``outside[0]`` is 1 when a moving point lay where the mask cannot
    vouch for all of its neighbours (outside the box or in its border cells): every point queries."""

    cells: NearMask
    outside: wp.array(dtype=wp.int32)


@wp.func
def may_have_moving_neighbors(m: MovingMask, p: wp.vec3) -> bool:
    if m.outside[0] != 0:
        return True
    return may_have_neighbors(m.cells, p)


@wp.kernel
def mark_moving(offset: int, m: MovingMask, points: wp.array(dtype=wp.vec3)):
    # every writer writes the same value: no atomic needed (from any CPU thread either); a point
    # in the box's border cells or beyond could have neighbours where the mask has no cell
    c = mask_cell(m.cells, points[wp.tid() + offset])
    d = m.cells.dims
    if c[0] < 1 or c[1] < 1 or c[2] < 1 or c[0] >= d[0] - 1 or c[1] >= d[1] - 1 or c[2] >= d[2] - 1:
        m.outside[0] = 1
        return
    for a in range(-1, 2):
        for b in range(-1, 2):
            for e in range(-1, 2):
                m.cells.near[mask_flat(m.cells, c + wp.vec3i(a, b, e))] = wp.uint8(1)


class MovingNearMask:
    """The moving points' :class:`MovingMask`, over the box of ``extent`` (points: where the walls
    and the bodies start) grown by two cells, so that bodies may drift a cell beyond it before every
    point has to query."""

    def __init__(self, extent: np.ndarray, radius: float, device):
        self.device = device
        self.mask = MovingMask()
        self.mask.outside = wp.ones(1, dtype=wp.int32, device=device)
        self.mask.cells = _no_mask(device)
        box = mask_box(extent.min(axis=0), extent.max(axis=0), radius, 2) if len(extent) else None
        if box is not None:  # else outside stays 1: every point queries
            self.mask.cells = _mask_over(box, device)

    def mark(self, points: wp.array) -> None:
        """Mark the cells near ``points`` (where the moving bodies are this step): the whole mask
        is cleared first (one byte a cell of the walls' box: 26k for the flood)."""
        if self.mask.cells.dims[0] == 0:
            return
        self.mask.cells.near.zero_()
        self.mask.outside.zero_()
        if points.shape[0]:
            launch_particles(mark_moving, points.shape[0], [self.mask, points], self.device)
