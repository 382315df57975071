"""Zhu & Bridson's signed distance to the liquid, stored only on blocks of cells the surface can cross.

``phi(x) = |x - xbar(x)| - r0``, ``xbar`` the average of the particles within ``R`` weighted by
``k(s) = max(0, (1 - s^2)^3)``, ``s = |x - x_i| / R``, on a lattice of cell ``cell`` over the
particles' bounding box plus a margin. A node with no particle within ``R`` is outside
(``phi = R``). The lattice is cut into blocks of ``BLOCK``^3 cells; a coarse count of particles
marks blocks that are all air (EMPTY) or all deep liquid (FULL), and only the rest (SURFACE)
are stored and computed, so memory and work follow the surface's area, not the tank's volume.

This module builds the field (:func:`sparse_distance_field`): the particles' box, the blocks and
their kinds (:mod:`.blocks`), the particles grouped by coarse cell and the values on the stored
blocks (:mod:`.splat`), in a :class:`Workspace` reused from frame to frame.
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..engine.launch import get_threads, launch_particles
from .blocks import (
    BLOCK,
    CELLS3,
    FULL,
    BlockField,
    classify_blocks,
    compact_blocks,
)
from .splat import ROWS, Float8, count_and_rank, gather_rows, sort_by_coarse_cell, splat_blocks

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@dataclass
class SparseField:
    """A distance field stored only on the blocks of ``BLOCK``^3 cells that the surface can cross.

    Node ``(i, j, k)`` of the lattice sits at ``lower + cell * (i, j, k)``; the lattice has
    ``BLOCK * block_dims + 1`` nodes per axis. ``device.phi`` holds the ``BLOCK``^3 nodes at the
    lower corner of each stored block (flat block numbers in ``device.blocks``); ``device.kind``
    says for every block whether it is EMPTY (phi = R everywhere), FULL (phi = -r0) or SURFACE
    (stored). ``coarse_start`` holds where each coarse cell's particles start in the grouped
    order (cells of size ``coarse_cell`` = R from ``lower``, ``coarse_dims`` of them, x-major,
    one more entry for the end): their differences are the particle counts per cell."""

    device: BlockField
    block_dims: tuple
    lower: np.ndarray
    cell: float
    coarse_start: wp.array | None = None
    coarse_dims: tuple = ()
    coarse_cell: float = 0.0

    @property
    def node_dims(self) -> tuple:
        return tuple(BLOCK * b + 1 for b in self.block_dims)

    @property
    def n_stored(self) -> int:
        return self.device.blocks.shape[0]

    def dense(self) -> np.ndarray:
        """The whole field as a dense (nx, ny, nz) NumPy array (for inspection and tests)."""
        f = self.device
        kind = f.kind.numpy().reshape(self.block_dims)
        out = np.full(self.node_dims, f.outside, dtype=np.float32)
        inner = out[:-1, :-1, :-1].reshape(
            self.block_dims[0], BLOCK, self.block_dims[1], BLOCK, self.block_dims[2], BLOCK
        )
        inner[...] = np.where(kind == FULL, f.inside, f.outside)[:, None, :, None, :, None]
        phi = f.phi.numpy().reshape(-1, BLOCK, BLOCK, BLOCK)
        for b, v in zip(f.blocks.numpy(), phi):
            i, j, k = np.unravel_index(b, self.block_dims)
            inner[i, :, j, :, k, :] = v
        out[:-1, :-1, :-1] = inner.reshape(out[:-1, :-1, :-1].shape)
        return out


@wp.kernel
def particle_bounds(x: wp.array(dtype=wp.vec3), bounds: wp.array(dtype=wp.vec3), bad: wp.array(dtype=wp.int32)):
    """The finite particles' bounding box (``bounds`` starts at +-inf) and the non-finite count:
    atomics, one launch, so a device frame needs no copy of its positions to the host."""
    p = x[wp.tid()]
    if wp.isfinite(p):
        wp.atomic_min(bounds, 0, p)
        wp.atomic_max(bounds, 1, p)
    else:
        wp.atomic_add(bad, 0, 1)


def particle_box(x: wp.array) -> tuple[np.ndarray, np.ndarray, int]:
    """Lower and upper corner of ``x`` and how many of its points are not finite."""
    bounds = wp.array(np.array([[np.inf] * 3, [-np.inf] * 3], dtype=np.float32), dtype=wp.vec3, device=x.device)
    bad = wp.zeros(1, dtype=wp.int32, device=x.device)
    wp.launch(particle_bounds, dim=x.shape[0], inputs=[x, bounds, bad], device=x.device)
    b = bounds.numpy()  # float32, as the positions
    return b[0], b[1], int(bad.numpy()[0])


def exclusive_scan(flags: wp.array) -> tuple[wp.array, int]:
    """Exclusive prefix sum of ``flags`` and its total, in one read back to the host: the
    inclusive sum is written one element on, after a leading zero."""
    n = flags.shape[0]
    sums = wp.empty(n + 1, dtype=flags.dtype, device=flags.device)
    starts = scan_with_total(flags, sums)
    return starts[:n], int(starts[n:].numpy()[0])


def scan_with_total(flags: wp.array, out: wp.array) -> wp.array:
    """``out[: n + 1]`` = 0 followed by the inclusive prefix sums of ``flags`` (n of them): the
    start of each element's range, and their end. No read back to the host."""
    n = flags.shape[0]
    out = out[: n + 1]
    out[:1].zero_()
    if n:
        wp.utils.array_scan(flags, out[1:], inclusive=True)
    return out


class Workspace:
    """Scratch arrays kept from frame to frame, grown by a quarter when too small: on the CPU a
    fresh array costs a page fault per 4 KiB on first touch (about 0.7 ms per MB here), more
    than some of the kernels that fill it."""

    def __init__(self, device):
        self.device = wp.get_device(device)
        self._arrays: dict = {}

    def get(self, name: str, n: int, dtype) -> wp.array:
        """An uninitialised array of ``n`` elements of ``dtype`` (valid until the next ``get``
        of the same name)."""
        a = self._arrays.get(name)
        if a is None or a.shape[0] < n or a.dtype is not dtype:
            a = wp.empty(max(n + n // 4, 1), dtype=dtype, device=self.device)
            self._arrays[name] = a
        return a[:n]

    def zeros(self, name: str, n: int, dtype) -> wp.array:
        a = self.get(name, n, dtype)
        a.zero_()
        return a


def splat_workers(n_blocks: int, device) -> int:
    """How many workers share the stored blocks: on the CPU a few per thread (each reuses one
    8 KiB set of sums, hot in cache, and takes every workers-th block, so the threads get
    alike shares of the surface); on CUDA one per block."""
    if wp.get_device(device).is_cpu:
        return max(1, min(n_blocks, 16 * get_threads()))
    return max(1, n_blocks)


def substage(times, name: str):
    """``times(name)`` when fine-grained stage times are asked for (a ``StageTimes``), else nothing."""
    return nullcontext() if times is None else times(name)


def sparse_distance_field(
    x: np.ndarray | wp.array, h: float, params, device, work: Workspace | None = None, times=None
) -> SparseField:
    """The signed distance on the blocks near the surface of particle positions ``x`` (spacing
    ``h``; ``params``: the scene's surface settings, in spacings). The field's arrays live in
    ``work`` (a fresh workspace if none): valid until its next use. ``times``: a ``StageTimes``
    that gets the seconds of each step (upload, bounds, sort, classify, splat), or None."""
    p = params
    work = work or Workspace(device)
    cell, R, r0 = p.cell * h, p.radius * h, p.r0 * h
    with substage(times, "upload"):
        if isinstance(x, wp.array):
            xd = x
        else:
            xd = wp.array(np.asarray(x, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    n = xd.shape[0]
    with substage(times, "bounds"):
        lo, hi, bad = particle_box(xd)
    if bad:
        raise ValueError(f"{bad} particles have non-finite positions")
    margin = R + 2.0 * cell
    lower = lo - margin
    blocks = np.ceil((np.asarray(hi, np.float64) + margin - lower) / (cell * BLOCK))  # float64: no cast yet
    if not np.all(np.isfinite(blocks)) or float(np.prod(blocks)) > 2.0**31 / (3 * CELLS3):
        span = (np.asarray(hi, np.float64) - np.asarray(lo, np.float64)).tolist()
        raise ValueError(
            f"mesh grid over the particles' extent {[float(f'{v:.3g}') for v in span]} m is too large for "
            f"cells of {cell:g} m; increase the cell size (a particle far from the others?)"
        )
    block_dims = blocks.astype(int)
    n_blocks = int(np.prod(block_dims))
    cdims = np.ceil(block_dims * BLOCK * cell / R).astype(int) + 1
    n_coarse = int(np.prod(cdims))
    cd = wp.vec3i(*[int(c) for c in cdims])
    f = BlockField()
    f.block_dims = wp.vec3i(*[int(b) for b in block_dims])
    f.lower = wp.vec3(*lower.tolist())
    f.cell, f.outside, f.inside = float(cell), float(R), float(-r0)
    with substage(times, "sort"):  # particles counted and grouped by coarse cell (size R)
        counts = work.zeros("counts", n_coarse, wp.int32)
        rank = work.get("rank", n, wp.int32)
        wp.launch(count_and_rank, dim=n, inputs=[xd, f.lower, float(R), cd, counts, rank], device=device)
        start = scan_with_total(counts, work.get("start", n_coarse + 1, wp.int32))
        xs = work.get("sorted", n, wp.vec3)
        launch_particles(sort_by_coarse_cell, n, [xd, f.lower, float(R), cd, start, rank, xs], device)
    with substage(times, "classify"):
        # a cube of side R = 2h holds about (R/h)^3 = 8 particles; "full" leaves room for jitter
        full = max(1, int(0.75 * (R / h) ** 3))
        f.kind = work.get("kind", n_blocks, wp.int32)
        flag = work.get("flag", n_blocks, wp.int32)
        launch_particles(classify_blocks, n_blocks, [f, float(R), counts, cd, full, flag], device)
        slot = scan_with_total(flag, work.get("slot", n_blocks + 1, wp.int32))
        n_surface = int(slot[n_blocks:].numpy()[0])
        f.block_map = work.get("block_map", n_blocks, wp.int32)
        blocks = work.get("blocks", max(n_surface, 1), wp.int32)
        launch_particles(compact_blocks, n_blocks, [f.kind, slot, f.block_map, blocks], device)
        f.blocks = blocks[:n_surface]
    with substage(times, "splat"):
        f.phi = work.get("phi", n_surface * CELLS3, float)
        if wp.get_device(device).is_cpu:
            workers = splat_workers(n_surface, device)
            acc = work.get("sums", workers * ROWS * 4, Float8)
            launch_particles(
                splat_blocks, workers, [workers, f, xs, start, cd, float(R), float(r0), acc], device, min_chunk=1
            )
        else:
            wp.launch(
                gather_rows, dim=n_surface * ROWS, inputs=[0, f, xs, start, cd, float(R), float(r0)], device=device
            )
    return SparseField(f, tuple(int(b) for b in block_dims), lower, cell, start, tuple(int(c) for c in cdims), float(R))
