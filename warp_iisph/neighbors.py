"""Neighbour search: ``wp.HashGrid`` queries turned into per-step compact neighbour lists.

The grid is queried once per step; every later loop of the step walks the compact lists, which
is several times cheaper than querying the grid again. Fluid-fluid lists have a fixed number of
slots per particle and are filled in a single query pass; fluid-boundary lists, empty for most
particles, are compact (CSR: count, exclusive scan, fill), and a particle that a static mask of
cells near the walls clears skips the walls' grid altogether. Each list
entry stores the neighbour index and ``grad W_ij`` (positions do not change until integration).
Fluid particles are periodically reordered by grid cell so that neighbours are close in memory.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .launch import launch_particles
from .sph import cubic_grad_W


@wp.struct
class NeighborList:
    """Compact (CSR) neighbour lists: the neighbours of particle i are
    ``index[start[i] : start[i] + count[i]]`` with kernel gradients ``grad_W[...]``."""

    start: wp.array(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)
    index: wp.array(dtype=wp.int32)
    grad_W: wp.array(dtype=wp.vec3)


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


@wp.kernel
def count_neighbors(
    offset: int,
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    queries: wp.array(dtype=wp.vec3),
    radius: float,
    mask: NearMask,
    count: wp.array(dtype=wp.int32),
):
    i = wp.tid() + offset
    x_i = queries[i]
    if not may_have_neighbors(mask, x_i):
        count[i] = 0
        return
    r2 = radius * radius
    n = int(0)
    j = int(0)
    query = wp.hash_grid_query(grid, x_i, radius)
    while wp.hash_grid_query_next(query, j):
        d = x_i - points[j]
        if wp.dot(d, d) < r2:
            n += 1
    count[i] = n


@wp.kernel
def fill_neighbors(
    offset: int,
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    queries: wp.array(dtype=wp.vec3),
    radius: float,
    nbrs: NeighborList,
):
    """Write the lists; entries past the storage's end are dropped and the counts cut to match
    (``list_total`` has flagged the overflow; the step is redone with more storage)."""
    i = wp.tid() + offset
    if nbrs.count[i] == 0:
        return
    x_i = queries[i]
    r2 = radius * radius
    k = nbrs.start[i]
    capacity = nbrs.index.shape[0]
    j = int(0)
    query = wp.hash_grid_query(grid, x_i, radius)
    while wp.hash_grid_query_next(query, j):
        x_ij = x_i - points[j]
        if wp.dot(x_ij, x_ij) < r2:
            if k < capacity:
                nbrs.index[k] = j
                nbrs.grad_W[k] = cubic_grad_W(x_ij, radius)
            k += 1
    if k > capacity:  # keep every later loop inside the storage
        nbrs.count[i] = wp.max(capacity - nbrs.start[i], 0)


@wp.kernel
def fill_neighbors_strided(
    offset: int,
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    radius: float,
    stride: int,
    nbrs: NeighborList,
    wanted: wp.array(dtype=wp.int32),
):
    """One pass, no count: particle i's neighbours in its own ``stride`` slots from ``i * stride``
    (in the same order as ``fill_neighbors``); ``wanted`` says how many it found, the count is cut
    to the stride (``stride_needed`` flags it; the step is redone with a longer stride)."""
    i = wp.tid() + offset
    x_i = points[i]
    r2 = radius * radius
    k0 = i * stride
    nbrs.start[i] = k0
    k = int(0)
    j = int(0)
    query = wp.hash_grid_query(grid, x_i, radius)
    while wp.hash_grid_query_next(query, j):
        if j != i:
            x_ij = x_i - points[j]
            if wp.dot(x_ij, x_ij) < r2:
                if k < stride:
                    nbrs.index[k0 + k] = j
                    nbrs.grad_W[k0 + k] = cubic_grad_W(x_ij, radius)
                k += 1
    nbrs.count[i] = wp.min(k, stride)
    wanted[i] = k


@wp.kernel
def stride_needed(n: int, wanted: wp.array(dtype=wp.int32), needed: wp.array(dtype=wp.int32)):
    # an atomic max: one launch, never split
    wp.atomic_max(needed, 0, n * wanted[wp.tid()])


@wp.kernel
def list_total(n: int, nbrs: NeighborList, total: wp.array(dtype=wp.int32)):
    """Entries the lists need (the scan's end), on the device: no host read inside a step."""
    total[0] = nbrs.start[n - 1] + nbrs.count[n - 1]


@wp.kernel
def cell_order(grid: wp.uint64, order: wp.array(dtype=wp.int32)):
    tid = wp.tid()
    order[tid] = wp.hash_grid_point_id(grid, tid)


class NeighborListBuffer:
    """Device storage of one :class:`NeighborList`, grown (never shrunk) as needed; built as
    compact (CSR) lists of one set's neighbours in another (fluid particles' walls)."""

    def __init__(self, n: int, device, capacity: int | None = None):
        self.device = device
        self.lists = NeighborList()
        self.lists.start = wp.zeros(max(n, 1), dtype=wp.int32, device=device)
        self.lists.count = wp.zeros(max(n, 1), dtype=wp.int32, device=device)
        self.needed = wp.zeros(1, dtype=wp.int32, device=device)  # entries the last build needed
        self.generation = -1  # bumped when the storage moves (captured graphs must be re-made)
        self._reserve(capacity or max(32 * n, 1))

    def _reserve(self, capacity: int) -> None:
        self.generation += 1
        self.capacity = capacity
        self.lists.index = wp.zeros(capacity, dtype=wp.int32, device=self.device)
        self.lists.grad_W = wp.zeros(capacity, dtype=wp.vec3, device=self.device)

    def build(self, grid: wp.HashGrid, points, queries, n: int, radius: float, mask: NearMask, sync: bool = True):
        """Neighbours among ``points`` (another set: the walls) of each of the ``n`` ``queries``:
        count, scan, fill; queries in cells that ``mask`` (see :func:`near_mask`) clears skip
        the grid. With ``sync`` the storage grows first when too small; without it (inside a
        captured graph) nothing is read back and ``needed`` tells afterwards."""
        if n == 0:
            return
        lists = self.lists
        launch_particles(count_neighbors, n, [grid.id, points, queries, radius, mask, lists.count], self.device)
        wp.utils.array_scan(lists.count[:n], lists.start[:n], inclusive=False)
        wp.launch(list_total, dim=1, inputs=[n, lists, self.needed], device=self.device)
        if sync:
            total = int(self.needed.numpy()[0])
            if total > self.capacity:
                self.grow(total)
        launch_particles(fill_neighbors, n, [grid.id, points, queries, radius, self.lists], self.device)

    def grow(self, needed: int) -> None:
        self._reserve(int(needed * 1.25) + 16)

    def to_sets(self, n: int) -> list[set[int]]:
        """Host copy as one set of neighbour indices per particle (for tests and debugging)."""
        start = self.lists.start.numpy()[:n]
        count = self.lists.count.numpy()[:n]
        index = self.lists.index.numpy()
        return [set(index[s : s + c].tolist()) for s, c in zip(start, count)]


class StridedListBuffer(NeighborListBuffer):
    """Fluid-fluid lists with a fixed number of slots per particle, filled in one grid query
    per particle (the CSR buffer queries twice: count, then fill). Every fluid particle has
    neighbours, so few slots go unused; ``needed`` is ``n`` times the longest list. The first
    stride, 48, is above the ~41 a dam break reaches (a lattice has 26 within 2h): a graph replay
    that outgrows it is redone whole, which would cost a frame."""

    def __init__(self, n: int, device, stride: int = 48):
        self.n = max(n, 1)
        self.wanted = wp.zeros(self.n, dtype=wp.int32, device=device)
        super().__init__(n, device, capacity=stride * self.n)

    def _reserve(self, capacity: int) -> None:
        self.stride = max(1, -(-capacity // self.n))
        super()._reserve(self.stride * self.n)

    def build(self, grid: wp.HashGrid, points, n: int, radius: float, sync: bool = True):
        """Each of the ``n`` ``points``' neighbours among the others; with ``sync`` a stride that
        proves too short grows and the lists are filled again."""
        if n == 0:
            return
        self.needed.zero_()
        launch_particles(fill_neighbors_strided, n, [grid.id, points, radius, self.stride, self.lists, self.wanted], self.device)
        wp.launch(stride_needed, dim=n, inputs=[n, self.wanted, self.needed], device=self.device)
        if sync:
            needed = int(self.needed.numpy()[0])
            if needed > self.capacity:
                self.grow(needed)
                self.build(grid, points, n, radius, sync)


# Above this many mask cells (bytes) the walls' bounding box is too fine to mask; every point queries.
MAX_MASK_CELLS = 1 << 27


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
    if len(xs) == 0:
        return _no_mask(device)
    cell = 1.001 * float(radius)
    lower = xs.min(axis=0) - cell
    dims = np.floor((xs.max(axis=0) + cell - lower) / cell).astype(np.int64) + 1
    if int(np.prod(dims)) > MAX_MASK_CELLS:
        return _no_mask(device)
    m = NearMask()
    m.lower, m.cell, m.dims = wp.vec3(*lower.tolist()), cell, wp.vec3i(*[int(d) for d in dims])
    cells = int(np.prod(dims))
    m.near = wp.zeros(cells, dtype=wp.uint8, device=device)
    occupied = wp.zeros(cells, dtype=wp.int32, device=device)
    wp.launch(occupy_cells, dim=len(xs), inputs=[m, points, occupied], device=device)
    launch_particles(dilate_cells, cells, [m, occupied], device)
    return m


def make_grid(device, dim: int = 128) -> wp.HashGrid:
    return wp.HashGrid(dim, dim, dim, device=device)


class NeighborSearch:
    """Fluid-fluid and fluid-boundary neighbour lists within the support radius ``H``."""

    def __init__(self, n_fluid: int, boundary_x: wp.array, radius: float, device):
        self.device = device
        self.n = n_fluid
        self.radius = float(radius)
        self.grid = make_grid(device)
        self.grid.reserve(max(n_fluid, 1))
        self.boundary_x = boundary_x
        self.boundary_grid = None
        if boundary_x is not None and boundary_x.shape[0] > 0:
            self.boundary_grid = make_grid(device)
            self.boundary_grid.build(boundary_x, self.radius)
            self.boundary_mask = near_mask(boundary_x, self.radius, device)  # most particles are far from walls
        self.fluid = StridedListBuffer(n_fluid, device)
        self.boundary = NeighborListBuffer(n_fluid, device)
        self._order = wp.zeros(max(n_fluid, 1), dtype=wp.int32, device=device)

    def cell_order(self, x: wp.array) -> wp.array:
        """Permutation that sorts particles by hash-grid cell (cache-friendly order)."""
        self.grid.build(x, self.radius)
        wp.launch(cell_order, dim=self.n, inputs=[self.grid.id, self._order], device=self.device)
        return self._order

    def build(self, x: wp.array, sync: bool = True) -> None:
        if self.n == 0:
            return
        self.grid.build(x, self.radius)
        self.fluid.build(self.grid, x, self.n, self.radius, sync=sync)
        if self.boundary_grid is not None:
            self.boundary.build(self.boundary_grid, self.boundary_x, x, self.n, self.radius, self.boundary_mask, sync=sync)
        else:
            self.boundary.lists.count.zero_()
            self.boundary.lists.start.zero_()
