"""Neighbour search: hash-grid queries turned into per-step compact neighbour lists.

The grid is queried once per step; every later loop of the step walks the compact lists, which
is several times cheaper than querying the grid again. Fluid-fluid lists have a fixed number of
slots per particle and are filled in a single query pass; fluid-boundary lists, empty for most
particles, are compact (CSR: count, exclusive scan, fill), and a particle that a static mask of
cells near the walls clears skips the walls' grid altogether. Every grid is a :class:`.grid.CellGrid`
(the walls' still particles' built once), walked by :func:`walk_cells` in ``wp.hash_grid_query``'s
order. Each list
entry stores the neighbour index and ``grad W_ij`` (positions do not change until integration).
Fluid particles are periodically reordered by grid cell so that neighbours are close in memory.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch, launch_particles
from .grid import GRID_DIM, CellGrid, ParticleGrid, cell_first, cell_range, wrap_cell
from .kernel import cubic_grad_W, cubic_W
from .wall_mask import MovingMask, MovingNearMask, NearMask, may_have_moving_neighbors, may_have_neighbors, near_mask

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.struct
class NeighborList:
    """Neighbour lists: the m-th neighbour of particle i (m < ``count[i]``) is
    ``index[start[i] + m * step]``, with kernel gradient ``grad_W[...]`` and value ``W[...]``
    (:func:`entry`). Compact
    (CSR) lists and particle-major strided lists have ``step`` 1; slot-major strided lists keep
    slot m of every particle together (``start[i] = i``, ``step = n``), so neighbouring threads
    read neighbouring entries: the layout a GPU gathers fastest."""

    start: wp.array(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)
    index: wp.array(dtype=wp.int32)
    grad_W: wp.array(dtype=wp.vec3)
    W: wp.array(dtype=float)
    head: wp.array(dtype=float)  # fluid-to-wall lists: the step's hydrostatic head (wall_pressure.py)
    step: int


@wp.func
def entry(nbrs: NeighborList, i: int, m: int) -> int:
    """Where particle i's m-th neighbour is stored."""
    return nbrs.start[i] + m * nbrs.step


@wp.func
def scan_run(
    g: CellGrid,
    x_i: wp.vec3,
    radius: float,
    s: int,
    last: int,
    skip: int,
    first: int,
    nbrs: NeighborList,
    k0: int,
    step: int,
    slots: int,
    write: int,
    m: int,
) -> int:
    """The sorted points from position ``s`` while their cell is at most ``last`` (see
    :func:`walk_cells`): ``m`` plus how many are within reach."""
    r2 = radius * radius
    while s < g.n and g.keys[s] <= last:
        x_ij = x_i - g.points[s]
        s += 1
        if wp.dot(x_ij, x_ij) < r2:
            j = g.ids[s - 1]
            if j != skip:
                if write != 0 and m < slots:
                    e = k0 + m * step
                    nbrs.index[e] = first + j
                    nbrs.grad_W[e] = cubic_grad_W(x_ij, radius)
                    nbrs.W[e] = cubic_W(wp.length(x_ij), radius)
                m += 1
    return m


@wp.func
def walk_cells(
    g: CellGrid,
    x_i: wp.vec3,
    radius: float,
    skip: int,
    first: int,
    nbrs: NeighborList,
    k0: int,
    step: int,
    slots: int,
    write: int,
) -> int:
    """The points a :class:`CellGrid` holds within ``radius`` of ``x_i`` (but point ``skip``),
    visited cell by cell, x fastest, as ``wp.hash_grid_query`` visits them: how many there are.
    With ``write``, the m-th goes to list entry ``k0 + m step`` while ``m < slots`` (its index
    ``first`` plus its id, ``grad W`` and ``W``). A row of cells along x that does not wrap round
    the table has consecutive hashes, so its points lie in one run of the sorted points: it is
    scanned as one (the same points in the same order; a cell looked up only until the first
    occupied one), and each axis is wrapped once, not once a cell."""
    m = int(0)
    if g.n == 0:
        return m
    cx = cell_range(g, x_i, radius, 0)
    cy = cell_range(g, x_i, radius, 1)
    cz = cell_range(g, x_i, radius, 2)
    x0 = wrap_cell(cx[0])
    x1 = x0 + cx[1] - cx[0]
    for z in range(cz[0], cz[1] + 1):
        plane = wrap_cell(z) * (GRID_DIM * GRID_DIM)
        for y in range(cy[0], cy[1] + 1):
            row = plane + wrap_cell(y) * GRID_DIM
            if x1 < GRID_DIM:
                s = g.n
                c = row + x0
                while c <= row + x1 and s == g.n:
                    s = cell_first(g, c)
                    c += 1
                m = scan_run(g, x_i, radius, s, row + x1, skip, first, nbrs, k0, step, slots, write, m)
            else:
                for x in range(cx[0], cx[1] + 1):
                    c = row + wrap_cell(x)
                    m = scan_run(g, x_i, radius, cell_first(g, c), c, skip, first, nbrs, k0, step, slots, write, m)
    return m


@wp.kernel
def count_neighbors(
    offset: int,
    still: CellGrid,
    queries: wp.array(dtype=wp.vec3),
    radius: float,
    mask: NearMask,
    moving: CellGrid,
    moving_mask: MovingMask,
    moving_first: int,
    nbrs: NeighborList,
):
    """Neighbours among the still points (``still``, skipped where ``mask`` clears the cell) and
    the moving ones (``moving``, over the points from ``moving_first``, skipped where
    ``moving_mask`` clears the cell)."""
    i = wp.tid() + offset
    x_i = queries[i]
    n = int(0)
    if may_have_neighbors(mask, x_i):
        n += walk_cells(still, x_i, radius, -1, 0, nbrs, 0, 1, 0, 0)
    if may_have_moving_neighbors(moving_mask, x_i):
        n += walk_cells(moving, x_i, radius, -1, moving_first, nbrs, 0, 1, 0, 0)
    nbrs.count[i] = n


@wp.kernel
def fill_neighbors(
    offset: int,
    still: CellGrid,
    queries: wp.array(dtype=wp.vec3),
    radius: float,
    mask: NearMask,
    moving: CellGrid,
    moving_mask: MovingMask,
    moving_first: int,
    nbrs: NeighborList,
):
    """Write the lists (the still points', then the moving ones'); entries past the storage's end
    are dropped and the counts cut to match (``list_starts``'s total has flagged the overflow; the
    step is redone with more storage)."""
    i = wp.tid() + offset
    if nbrs.count[i] == 0:
        return
    x_i = queries[i]
    k = nbrs.start[i]
    capacity = nbrs.index.shape[0]
    if may_have_neighbors(mask, x_i):
        k += walk_cells(still, x_i, radius, -1, 0, nbrs, k, 1, capacity - k, 1)
    if may_have_moving_neighbors(moving_mask, x_i):
        k += walk_cells(moving, x_i, radius, -1, moving_first, nbrs, k, 1, capacity - k, 1)
    if k > capacity:  # keep every later loop inside the storage
        nbrs.count[i] = wp.max(capacity - nbrs.start[i], 0)


@wp.kernel
def fill_neighbors_strided(
    offset: int,
    grid: CellGrid,
    points: wp.array(dtype=wp.vec3),
    radius: float,
    stride: int,
    nbrs: NeighborList,
    wanted: wp.array(dtype=wp.int32),
):
    """One pass, no count: particle i's neighbours in its own ``stride`` slots (in the same order
    as ``fill_neighbors``): with ``B = nbrs.step`` particles interleaved slot by slot, slot m of
    particle i at ``(i // B) B stride + m B + i % B`` (B = 1: particle-major, ``i * stride + m``;
    B = n: slot-major, ``m n + i``); ``wanted`` says how many it found, the count is cut to the
    stride (``stride_needed`` flags it; the step is redone with a longer stride)."""
    i = wp.tid() + offset
    x_i = points[i]
    b = nbrs.step
    k0 = (i // b) * b * stride + i % b
    nbrs.start[i] = k0
    k = walk_cells(grid, x_i, radius, i, 0, nbrs, k0, b, stride, 1)
    nbrs.count[i] = wp.min(k, stride)
    wanted[i] = k


# entries a list storage may hold: its indices are 32-bit (beyond, a need is reported as this)
LIST_ENTRIES_LIMIT = 2**31 - 1


@wp.kernel
def stride_needed(n: int, wanted: wp.array(dtype=wp.int32), needed: wp.array(dtype=wp.int32)):
    # an atomic max: one launch, never split; the product in 64 bits, held at the limit
    total = wp.min(wp.int64(n) * wp.int64(wanted[wp.tid()]), wp.int64(2147483647))
    wp.atomic_max(needed, 0, wp.int32(total))


@wp.kernel
def list_starts(nbrs: NeighborList, total: wp.array(dtype=wp.int32)):
    """Each non-empty list's start, taken from a running total (zeroed before): no scan, so no
    allocation inside a graph's conditional body. A CPU launch is one loop in index order, so the
    starts are the exclusive scan's; on CUDA the lists come in any order, each still whole."""
    i = wp.tid()
    c = nbrs.count[i]
    if c > 0:
        nbrs.start[i] = wp.atomic_add(total, 0, c)


@wp.kernel
def cell_order(grid: wp.uint64, order: wp.array(dtype=wp.int32)):
    """Points in the order of a (built) ``wp.HashGrid``'s cells."""
    tid = wp.tid()
    order[tid] = wp.hash_grid_point_id(grid, tid)


@wp.kernel
def sorted_order(grid: CellGrid, order: wp.array(dtype=wp.int32)):
    """Points in the order of a (built) :class:`CellGrid`'s cells."""
    tid = wp.tid()
    order[tid] = grid.ids[tid]


class NeighborListBuffer:
    """Device storage of one :class:`NeighborList`, grown (never shrunk) as needed; built as
    compact (CSR) lists of one set's neighbours in another (fluid particles' walls)."""

    def __init__(self, n: int, device, capacity: int | None = None, heads: bool = False):
        """``heads``: keep a ``head`` per entry too (the walls' hydrostatic heads)."""
        self.device = device
        self.heads = heads
        self.lists = NeighborList()
        self.lists.start = wp.zeros(max(n, 1), dtype=wp.int32, device=device)
        self.lists.count = wp.zeros(max(n, 1), dtype=wp.int32, device=device)
        self.lists.step = 1
        self.needed = wp.zeros(1, dtype=wp.int32, device=device)  # entries the last build needed
        self.generation = -1  # bumped when the storage moves (captured graphs must be re-made)
        self._reserve(capacity or max(32 * n, 1))

    def _reserve(self, capacity: int) -> None:
        if capacity > LIST_ENTRIES_LIMIT:
            raise MemoryError(
                f"neighbour lists need {capacity:,} entries, more than 32-bit indices address "
                f"({LIST_ENTRIES_LIMIT:,}); use a coarser spacing or fewer particles"
            )
        self.generation += 1
        self.capacity = capacity
        self.lists.index = wp.zeros(capacity, dtype=wp.int32, device=self.device)
        self.lists.grad_W = wp.zeros(capacity, dtype=wp.vec3, device=self.device)
        self.lists.W = wp.zeros(capacity, dtype=float, device=self.device)
        self.lists.head = wp.zeros(capacity if self.heads else 1, dtype=float, device=self.device)

    def build(
        self,
        still: ParticleGrid,
        queries,
        n: int,
        radius: float,
        mask: NearMask,
        moving: ParticleGrid,
        moving_mask: MovingNearMask,
        moving_first: int,
        sync: bool = True,
    ):
        """Neighbours among another set of points (the walls) of each of the ``n`` ``queries``:
        count, starts, fill. The still points are in ``still`` (queries in cells that ``mask``,
        see :func:`near_mask`, clears skip it), the moving ones from ``moving_first`` in
        ``moving`` (skipped where ``moving_mask`` clears the cell).
        With ``sync`` the storage grows first when too small; without it (inside a captured
        graph) nothing is read back and ``needed`` tells afterwards."""
        if n == 0:
            return
        lists = self.lists
        common = [still.grid, queries, radius, mask, moving.grid, moving_mask.mask, moving_first]
        launch_particles(count_neighbors, n, [*common, lists], self.device)
        self.needed.zero_()
        launch(list_starts, dim=n, inputs=[lists, self.needed], device=self.device)
        if sync:
            total = int(self.needed.numpy()[0])
            if total > self.capacity:
                self.grow(total)
        launch_particles(fill_neighbors, n, [*common, self.lists], self.device)

    def grow(self, needed: int) -> None:
        self._reserve(int(needed * 1.25) + 16)

    def to_sets(self, n: int) -> list[set[int]]:
        """Host copy as one set of neighbour indices per particle (for tests and debugging)."""
        start = self.lists.start.numpy()[:n]
        count = self.lists.count.numpy()[:n]
        index = self.lists.index.numpy()
        step = self.lists.step
        return [set(index[s : s + c * step : step].tolist()) for s, c in zip(start, count)]


# the fluid lists' slots per particle before any list outgrows them (see StridedListBuffer)
FIRST_STRIDE = 48


class StridedListBuffer(NeighborListBuffer):
    """Fluid-fluid lists with a fixed number of slots per particle, filled in one grid query
    per particle (the CSR buffer queries twice: count, then fill). Every fluid particle has
    neighbours, so few slots go unused; ``needed`` is ``n`` times the longest list. The first
    stride, 48, is above the ~41 a dam break reaches (a lattice has 26 within 2h): a graph replay
    that outgrows it is redone whole, which would cost a frame."""

    def __init__(
        self, n: int, device, stride: int = FIRST_STRIDE, slot_major: bool | None = None, block: int | None = None
    ):
        """``block``: how many particles' lists interleave slot by slot (``NeighborList.step``):
        1 is particle-major, ``n`` slot-major, 32 a GPU warp's particles per block of slots;
        ``slot_major`` chooses between the first two; by default slot-major on CUDA."""
        self.n = max(n, 1)
        if block is not None and slot_major is not None:
            raise ValueError("StridedListBuffer: give block or slot_major, not both")
        if block is None:
            if slot_major is None:
                slot_major = wp.get_device(device).is_cuda
            block = self.n if slot_major else 1
        self.block = min(max(1, int(block)), self.n)
        self.padded = -(-self.n // self.block) * self.block  # particles the storage has slots for
        self.wanted = wp.zeros(self.n, dtype=wp.int32, device=device)
        super().__init__(n, device, capacity=stride * self.padded)
        self.lists.step = self.block

    def _reserve(self, capacity: int) -> None:
        self.stride = max(1, -(-capacity // self.padded))
        super()._reserve(self.stride * self.padded)

    def build(self, grid: ParticleGrid, points, n: int, radius: float, sync: bool = True):
        """Each of the ``n`` ``points``' neighbours among the others (``grid``: built over them);
        with ``sync`` a stride that proves too short grows and the lists are filled again."""
        if n == 0:
            return
        self.needed.zero_()
        launch_particles(
            fill_neighbors_strided, n, [grid.grid, points, radius, self.stride, self.lists, self.wanted], self.device
        )
        # slots for every particle the storage is laid out for (padded to whole blocks)
        launch(stride_needed, dim=n, inputs=[self.padded, self.wanted, self.needed], device=self.device)
        if sync:
            needed = int(self.needed.numpy()[0])
            if needed > self.capacity:
                self.grow(needed)
                self.build(grid, points, n, radius, sync)


def make_grid(device, dim: int = 128) -> wp.HashGrid:
    return wp.HashGrid(dim, dim, dim, device=device)


class NeighborSearch:
    """Fluid-fluid and fluid-boundary neighbour lists within the support radius ``H``. The first
    ``n_still`` boundary particles never move (one grid, built once, and a mask of the cells near
    them); the rest belong to moving obstacles, whose grid and mask are rebuilt every step."""

    def __init__(self, n_fluid: int, boundary_x: wp.array, radius: float, device, n_still: int | None = None):
        """``n_fluid``: the most fluid particles the lists serve (the state's capacity)."""
        self.device = device
        self.n = n_fluid
        self.radius = float(radius)
        self.grid = ParticleGrid(n_fluid, device)
        self.boundary_x = boundary_x
        n_boundary = 0 if boundary_x is None else int(boundary_x.shape[0])
        self.n_still = n_boundary if n_still is None else int(n_still)
        self.boundary_grid = None
        if n_boundary:
            still = boundary_x[: self.n_still]
            self.boundary_grid = ParticleGrid(self.n_still, device)
            self.boundary_grid.build(still, self.radius)
            self.boundary_mask = near_mask(still, self.radius, device)  # most particles are far from walls
        self.moving_grid = ParticleGrid(n_boundary - self.n_still, device)
        # the moving bodies' mask spans the walls and where the bodies start
        extent = boundary_x.numpy() if n_boundary > self.n_still else np.zeros((0, 3))
        self.moving_mask = MovingNearMask(extent, self.radius, device)
        self.fluid = StridedListBuffer(n_fluid, device)
        self.boundary = NeighborListBuffer(n_fluid, device, heads=True)
        self._order = wp.zeros(max(n_fluid, 1), dtype=wp.int32, device=device)

    def cell_order(self, x: wp.array, n: int | None = None) -> wp.array:
        """Permutation that sorts the first ``n`` particles (default: all it serves) by hash-grid
        cell (cache-friendly order)."""
        n = self.n if n is None else n
        self.grid.build(x, self.radius, n)
        if n:
            launch(sorted_order, dim=n, inputs=[self.grid.grid, self._order], device=self.device)
        return self._order

    def build(self, x: wp.array, n: int | None = None, sync: bool = True) -> None:
        """The lists of the first ``n`` particles of ``x`` (default: all it serves)."""
        n = self.n if n is None else n
        if n == 0:
            return
        self.grid.build(x, self.radius, n)
        self.fluid.build(self.grid, x, n, self.radius, sync=sync)
        if self.boundary_grid is not None:
            if self.moving_grid.n:  # moving obstacles: where they are this step
                self.moving_grid.build(self.boundary_x[self.n_still :], self.radius)
                self.moving_mask.mark(self.boundary_x[self.n_still :])
            self.boundary.build(
                self.boundary_grid,
                x,
                n,
                self.radius,
                self.boundary_mask,
                self.moving_grid,
                self.moving_mask,
                self.n_still,
                sync=sync,
            )
        else:
            self.boundary.lists.count.zero_()
            self.boundary.lists.start.zero_()
