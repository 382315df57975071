"""The particles' hash grid, built from kernels and a radix sort into storage it keeps.

``wp.HashGrid.build`` cannot run inside a conditional body of a CUDA graph (the loop over steps
and the capture_if of the reorder), so the moving particles' grid is built here from operations
that can: a kernel writing each point's cell key, ``wp.utils.radix_sort_pairs`` into preallocated
buffers, and a kernel marking where each cell's run starts. The layout is Warp's own (the same
cell hash, a stable sort of the same keys), so a query visits the same candidates in the same
order as ``wp.hash_grid_query`` would: neighbour lists, and every result after them, are
bitwise those of a ``wp.HashGrid``.

A cell's run is found from ``starts`` and the sorted keys themselves: ``starts[c]`` is written for
every occupied cell and checked against the key it points at, so cells emptied since an earlier
build need no clearing (a HashGrid zeroes all of its 2M cells every build).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch_particles

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

GRID_DIM = wp.constant(128)  # cells per axis of the hash, as warp_iisph's wp.HashGrids use


@wp.struct
class CellGrid:
    """Points sorted by hashed cell: ``ids[k]`` is the point at sorted position k, ``keys[k]`` its
    cell, ``points[k]`` its position; ``starts[c]`` the first sorted position of cell c (valid
    where ``keys`` agrees). A query tests candidates' positions in a row and reads ``ids`` only
    for the ones within reach (about one in five): no load that waits on another for the rest."""

    inv_cell: float
    n: int
    keys: wp.array(dtype=wp.int32)
    ids: wp.array(dtype=wp.int32)
    starts: wp.array(dtype=wp.int32)
    points: wp.array(dtype=wp.vec3)


@wp.func
def cell_coord(v: float) -> int:
    return int(wp.floor(v))


@wp.func
def wrap_cell(c: int) -> int:
    """A cell coordinate wrapped (non-negative modulo) into the table's ``GRID_DIM``."""
    w = c % GRID_DIM
    if w < 0:
        w += GRID_DIM
    return w


@wp.func
def cell_hash(x: int, y: int, z: int) -> int:
    """Warp's hash of a cell: coordinates wrapped into the dim^3 table."""
    return wrap_cell(z) * (GRID_DIM * GRID_DIM) + wrap_cell(y) * GRID_DIM + wrap_cell(x)


@wp.func
def query_end(start: int, end: int) -> int:
    # a radius wider than the table visits each cell once
    if end - start >= GRID_DIM:
        return start + GRID_DIM - 1
    return end


@wp.func
def cell_range(g: CellGrid, p: wp.vec3, radius: float, axis: int) -> wp.vec2i:
    """First and last cell coordinate a query of ``radius`` around ``p`` visits along ``axis``."""
    lo = cell_coord((p[axis] - radius) * g.inv_cell)
    hi = cell_coord((p[axis] + radius) * g.inv_cell)
    return wp.vec2i(lo, query_end(lo, hi))


@wp.func
def cell_first(g: CellGrid, c: int) -> int:
    """Sorted position of cell c's first point, or ``g.n`` when the cell is empty."""
    k = g.starts[c]
    if k >= 0 and k < g.n:
        if g.keys[k] == c:
            return k
    return g.n


@wp.kernel
def cell_keys(
    offset: int,
    points: wp.array(dtype=wp.vec3),
    inv_cell: float,
    keys: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
):
    i = wp.tid() + offset
    p = points[i]
    keys[i] = cell_hash(cell_coord(p[0] * inv_cell), cell_coord(p[1] * inv_cell), cell_coord(p[2] * inv_cell))
    ids[i] = i


@wp.kernel
def cell_starts(offset: int, g: CellGrid, points: wp.array(dtype=wp.vec3)):
    # each occupied cell is written by the one thread at its run's start
    k = wp.tid() + offset
    g.points[k] = points[g.ids[k]]
    c = g.keys[k]
    if k == 0:
        g.starts[c] = 0
    elif g.keys[k - 1] != c:
        g.starts[c] = k


class ParticleGrid:
    """The hash grid of up to ``capacity`` points: the liquid's and the moving bodies', rebuilt
    every step into the same storage, and the walls' still particles, built once."""

    def __init__(self, capacity: int, device):
        self.device = device
        self.capacity = int(capacity)
        self.grid = CellGrid()
        self.grid.n = self.capacity
        self.grid.inv_cell = 1.0
        # radix_sort_pairs uses the second half of keys and ids as scratch
        self.grid.keys = wp.zeros(2 * max(self.capacity, 1), dtype=wp.int32, device=device)
        self.grid.ids = wp.zeros(2 * max(self.capacity, 1), dtype=wp.int32, device=device)
        self.grid.starts = wp.full(GRID_DIM * GRID_DIM * GRID_DIM, -1, dtype=wp.int32, device=device)
        self.grid.points = wp.zeros(max(self.capacity, 1), dtype=wp.vec3, device=device)

    @property
    def n(self) -> int:
        return self.grid.n

    def build(self, points: wp.array, cell: float, n: int | None = None) -> None:
        """Sort the first ``n`` points (default: all it holds) by cell (cells of size ``cell``);
        allocation-free."""
        g = self.grid
        g.n = self.capacity if n is None else int(n)
        g.inv_cell = float(np.float32(1.0) / np.float32(cell))  # in float32, as wp.HashGrid computes it
        if g.n == 0:
            return
        launch_particles(cell_keys, g.n, [points, g.inv_cell, g.keys, g.ids], self.device)
        wp.utils.radix_sort_pairs(g.keys, g.ids, g.n)
        launch_particles(cell_starts, g.n, [g, points], self.device)
