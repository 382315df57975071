"""Zhu & Bridson's signed distance to the liquid, stored only on blocks of cells the surface can cross.

``phi(x) = |x - xbar(x)| - r0``, ``xbar`` the average of the particles within ``R`` weighted by
``k(s) = max(0, (1 - s^2)^3)``, ``s = |x - x_i| / R``, on a lattice of cell ``cell`` over the
particles' bounding box plus a margin. A node with no particle within ``R`` is outside
(``phi = R``). The lattice is cut into blocks of ``BLOCK``^3 cells; a coarse count of particles
marks blocks that are all air (EMPTY) or all deep liquid (FULL), and only the rest (SURFACE)
are stored and computed, so memory and work follow the surface's area, not the tank's volume.

The particles are grouped by coarse cell (size R, a counting sort), and each stored block
splats the particles of the coarse cells within R of it onto its nodes (``splat_blocks``):
per particle only the rows of 8 nodes along z that its ball reaches, all 8 weights of a row at
once, into sums that stay in cache; then ``phi`` per node. Nodes on a face shared with a FULL
block take -r0, as that block's nodes do, so the cells of unstored blocks never cross.
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..engine.launch import get_threads, launch_particles

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.func
def _coarse_index(p: wp.vec3, lower: wp.vec3, C: float, cdims: wp.vec3i) -> wp.vec3i:
    q = (p - lower) / C
    return wp.vec3i(
        wp.clamp(int(q[0]), 0, cdims[0] - 1), wp.clamp(int(q[1]), 0, cdims[1] - 1), wp.clamp(int(q[2]), 0, cdims[2] - 1)
    )


BLOCK = wp.constant(8)  # cells per block side: the field and marching cubes live on blocks near the surface
CELLS3 = wp.constant(BLOCK * BLOCK * BLOCK)
EMPTY = wp.constant(0)
SURFACE = wp.constant(1)
FULL = wp.constant(2)


@wp.func
def coarse_count(counts: wp.array(dtype=wp.int32), c: wp.vec3i, cdims: wp.vec3i) -> int:
    if c[0] >= 0 and c[0] < cdims[0] and c[1] >= 0 and c[1] < cdims[1] and c[2] >= 0 and c[2] < cdims[2]:
        return counts[(c[0] * cdims[1] + c[1]) * cdims[2] + c[2]]
    return 0


@wp.func
def coarse_kind(counts: wp.array(dtype=wp.int32), cdims: wp.vec3i, c0: wp.vec3i, c1: wp.vec3i, full: int) -> int:
    """The narrow-band test over coarse cells ``c0 - 1 .. c1 + 1`` (cells of size R counting
    particles): EMPTY when all are empty (no particle within R of a point of cells c0..c1),
    FULL when all hold at least ``full`` (at least R deep in the liquid, where only the sign
    matters), else SURFACE. A node tests its own cell (c0 = c1), a block the span of its nodes,
    so a block's kind is what each of its nodes would find."""
    lo_count = int(2147483647)
    hi_count = int(0)
    for a in range(c0[0] - 1, c1[0] + 2):
        for b in range(c0[1] - 1, c1[1] + 2):
            for e in range(c0[2] - 1, c1[2] + 2):
                m = coarse_count(counts, wp.vec3i(a, b, e), cdims)
                lo_count = wp.min(lo_count, m)
                hi_count = wp.max(hi_count, m)
    if hi_count == 0:
        return EMPTY
    if lo_count >= full:
        return FULL
    return SURFACE


@wp.kernel
def compact_blocks(
    offset: int,
    kind: wp.array(dtype=wp.int32),
    slot: wp.array(dtype=wp.int32),
    block_map: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.int32),
):
    # a scatter through an exclusive scan of the SURFACE flags; each thread writes its own slots
    b = wp.tid() + offset
    if kind[b] == SURFACE:
        block_map[b] = slot[b]
        blocks[slot[b]] = b
    else:
        block_map[b] = -1


@wp.struct
class BlockField:
    """The device side of :class:`SparseField` (see there)."""

    phi: wp.array(dtype=float)
    blocks: wp.array(dtype=wp.int32)
    block_map: wp.array(dtype=wp.int32)
    kind: wp.array(dtype=wp.int32)
    block_dims: wp.vec3i
    lower: wp.vec3
    cell: float
    outside: float
    inside: float


@wp.func
def unflatten_block(f: BlockField, b: int) -> wp.vec3i:
    return wp.vec3i(
        b // (f.block_dims[1] * f.block_dims[2]), (b // f.block_dims[2]) % f.block_dims[1], b % f.block_dims[2]
    )


@wp.func
def block_coords(f: BlockField, kb: int) -> wp.vec3i:
    return unflatten_block(f, f.blocks[kb])


@wp.func
def local_node(m: int) -> wp.vec3i:
    return wp.vec3i(m // (BLOCK * BLOCK), (m // BLOCK) % BLOCK, m % BLOCK)


@wp.func
def local_slot(node: wp.vec3i) -> int:
    """Inverse of ``local_node``, for a node in [0, BLOCK]^3 taken into the block that owns it."""
    return ((node[0] % BLOCK) * BLOCK + node[1] % BLOCK) * BLOCK + node[2] % BLOCK


@wp.func
def owner_block(f: BlockField, bc: wp.vec3i, node: wp.vec3i) -> int:
    """Flat number of the block that owns ``node`` in [0, BLOCK]^3 of the block at ``bc`` (the
    block itself, or one above it for a node on its upper faces); -1 beyond the lattice."""
    g = bc + wp.vec3i(node[0] // BLOCK, node[1] // BLOCK, node[2] // BLOCK)
    if g[0] >= f.block_dims[0] or g[1] >= f.block_dims[1] or g[2] >= f.block_dims[2]:
        return -1
    return (g[0] * f.block_dims[1] + g[1]) * f.block_dims[2] + g[2]


@wp.func
def node_position(f: BlockField, bc: wp.vec3i, node: wp.vec3i) -> wp.vec3:
    return f.lower + f.cell * wp.vec3(
        float(BLOCK * bc[0] + node[0]), float(BLOCK * bc[1] + node[1]), float(BLOCK * bc[2] + node[2])
    )


@wp.func
def node_phi(f: BlockField, kb: int, bc: wp.vec3i, node: wp.vec3i) -> float:
    """phi at ``node`` in [0, BLOCK]^3 of stored block ``kb`` (at block coordinates ``bc``).
    A block stores its nodes in [0, BLOCK)^3; those on its upper faces belong to the blocks above
    it, which store them, or hold EMPTY/FULL, where every node has the value the narrow-band
    test of ``signed_distance`` gives."""
    if node[0] < BLOCK and node[1] < BLOCK and node[2] < BLOCK:
        return f.phi[kb * CELLS3 + local_slot(node)]
    b = owner_block(f, bc, node)
    if b < 0:
        return f.outside  # the lattice's top nodes lie in the margin, beyond R of every particle
    m = f.block_map[b]
    if m >= 0:
        return f.phi[m * CELLS3 + local_slot(node)]
    if f.kind[b] == FULL:
        return f.inside
    return f.outside


@wp.kernel
def classify_blocks(
    offset: int,
    f: BlockField,
    R: float,
    counts: wp.array(dtype=wp.int32),
    cdims: wp.vec3i,
    full: int,
    flag: wp.array(dtype=wp.int32),
):
    """Each block's kind: the narrow-band test over the coarse cells of all its nodes, from its
    lowest to its highest; only SURFACE blocks (``flag`` 1) are stored and meshed."""
    b = wp.tid() + offset
    bc = unflatten_block(f, b)
    c0 = _coarse_index(node_position(f, bc, wp.vec3i(0, 0, 0)), f.lower, R, cdims)
    c1 = _coarse_index(node_position(f, bc, wp.vec3i(BLOCK, BLOCK, BLOCK)), f.lower, R, cdims)
    kind = coarse_kind(counts, cdims, c0, c1, full)
    f.kind[b] = kind
    flag[b] = wp.where(kind == SURFACE, 1, 0)


ROWS = wp.constant(BLOCK * BLOCK)  # a block's nodes as rows of BLOCK along z
Float8 = wp.types.vector(length=8, dtype=float)  # one row of a block's nodes (BLOCK = 8)
assert BLOCK == 8, "the splat works on rows of 8 nodes"


@wp.kernel
def count_and_rank(
    x: wp.array(dtype=wp.vec3),
    lower: wp.vec3,
    C: float,
    cdims: wp.vec3i,
    counts: wp.array(dtype=wp.int32),
    rank: wp.array(dtype=wp.int32),
):
    # atomics: one launch, never split (on the CPU the ranks follow the particle order)
    c = _coarse_index(x[wp.tid()], lower, C, cdims)
    rank[wp.tid()] = wp.atomic_add(counts, (c[0] * cdims[1] + c[1]) * cdims[2] + c[2], 1)


@wp.kernel
def sort_by_coarse_cell(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    lower: wp.vec3,
    C: float,
    cdims: wp.vec3i,
    start: wp.array(dtype=wp.int32),
    rank: wp.array(dtype=wp.int32),
    xs: wp.array(dtype=wp.vec3),
):
    """The positions grouped by coarse cell (cells of size R, x-major): a block finds the
    particles near it as one contiguous range per (cx, cy) column of coarse cells."""
    i = wp.tid() + offset
    c = _coarse_index(x[i], lower, C, cdims)
    xs[start[(c[0] * cdims[1] + c[1]) * cdims[2] + c[2]] + rank[i]] = x[i]


@wp.func
def row_weights(e: float, dz2: Float8, inv_R2: float) -> Float8:
    """Zhu & Bridson's weights ``(1 - s^2)^3`` of one particle at a row's 8 nodes; ``e`` is R^2
    less its squared distance to the row's line, ``dz2`` the squared z offsets of the nodes."""
    t = wp.max(Float8(e, e, e, e, e, e, e, e) - dz2, Float8()) * inv_R2
    return wp.cw_mul(wp.cw_mul(t, t), t)


@wp.func
def full_below_mask(f: BlockField, bc: wp.vec3i) -> int:
    """Which blocks below block ``bc`` are FULL (bit e: the block at bc - (e >> 2, (e >> 1) & 1,
    e & 1)): the nodes on the faces it shares with them hold -r0, as every node of a FULL block
    does, so that the cells of those unstored blocks have no crossing (EMPTY neighbours need no
    such care: no particle is within R of their nodes, so the sums give exactly R)."""
    mask = int(0)
    for e in range(1, 8):
        nb = bc - wp.vec3i((e >> 2) & 1, (e >> 1) & 1, e & 1)
        if nb[0] >= 0 and nb[1] >= 0 and nb[2] >= 0:
            if f.kind[(nb[0] * f.block_dims[1] + nb[1]) * f.block_dims[2] + nb[2]] == FULL:
                mask = mask | (1 << e)
    return mask


@wp.func
def store_row(
    f: BlockField,
    kb: int,
    r: int,
    full_below: int,
    kz: Float8,
    sx: Float8,
    sy: Float8,
    sz: Float8,
    sw: Float8,
    R: float,
    r0: float,
):
    """phi = |x - xbar| - r0 at row ``r`` of stored block ``kb`` from its weighted sums (R where
    no particle is within R; -r0 on faces shared with a FULL block below)."""
    i = r // BLOCK
    j = r % BLOCK
    xi = float(i) * f.cell
    yj = float(j) * f.cell
    base = kb * CELLS3 + r * BLOCK
    for k in range(BLOCK):
        phi = R
        if sw[k] > 0.0:
            inv = 1.0 / sw[k]
            phi = wp.length(wp.vec3(xi - sx[k] * inv, yj - sy[k] * inv, kz[k] - sz[k] * inv)) - r0
        if full_below != 0:
            faces = wp.where(i == 0, 4, 0) | wp.where(j == 0, 2, 0) | wp.where(k == 0, 1, 0)
            for e in range(1, 8):
                if (e & faces) == e and ((full_below >> e) & 1) == 1:
                    phi = -r0
        f.phi[base + k] = phi


@wp.func
def node_heights(c: float) -> Float8:
    kz = Float8()
    for k in range(BLOCK):
        kz[k] = float(k) * c
    return kz


@wp.kernel
def splat_blocks(
    offset: int,
    workers: int,
    f: BlockField,
    xs: wp.array(dtype=wp.vec3),
    start: wp.array(dtype=wp.int32),
    cdims: wp.vec3i,
    R: float,
    r0: float,
    acc: wp.array(dtype=Float8),
):
    """Zhu & Bridson's distance at every node of the stored blocks ``w, w + workers, ...`` of
    worker ``w``: each block gathers the particles of the coarse cells within ``R`` of it and
    splats them onto its nodes' sums (in ``acc``, the worker's own 4 x 64 rows), then
    ``phi = |x - xbar| - r0`` (``R`` where no particle is within R). A block is one worker's
    whole job, so splitting the workers over threads changes no bit. The CPU's kernel: the sums
    stay in cache; on a GPU one thread per block is too little parallel work (``gather_rows``)."""
    wk = wp.tid() + offset
    ab = wk * ROWS * 4
    c = f.cell
    inv_c = 1.0 / c
    R2 = R * R
    inv_R2 = 1.0 / R2
    top = float(BLOCK - 1) * c
    kz = node_heights(c)
    zero = Float8()
    for kb in range(wk, f.blocks.shape[0], workers):
        bc = block_coords(f, kb)
        lo = node_position(f, bc, wp.vec3i(0, 0, 0))
        for m in range(ROWS * 4):
            acc[ab + m] = zero
        c0 = _coarse_index(lo - wp.vec3(R), f.lower, R, cdims)
        c1 = _coarse_index(lo + wp.vec3(top + R), f.lower, R, cdims)
        for cx in range(c0[0], c1[0] + 1):
            for cy in range(c0[1], c1[1] + 1):
                col = (cx * cdims[1] + cy) * cdims[2]
                for q in range(start[col + c0[2]], start[col + c1[2] + 1]):
                    # particle q relative to the block's first node, splatted onto the nodes within
                    # R, a row of 8 along z at a time (weights zero beyond R): only the rows its
                    # ball reaches are visited
                    p = xs[q] - lo
                    gz = wp.max(0.0, wp.max(-p[2], p[2] - top))  # to the nearest node of a row, along z
                    r2 = R2 - gz * gz  # what is left for the row's distance in x and y
                    if r2 > 0.0 and wp.max(p) < top + R and wp.min(p) > -R:
                        ri = wp.sqrt(r2)
                        i0 = wp.max(0, int(wp.ceil((p[0] - ri) * inv_c)))
                        i1 = wp.min(BLOCK - 1, int(wp.floor((p[0] + ri) * inv_c)))
                        dz = kz - Float8(p[2], p[2], p[2], p[2], p[2], p[2], p[2], p[2])
                        dz2 = wp.cw_mul(dz, dz)
                        i = i0
                        while i <= i1:
                            dx = float(i) * c - p[0]
                            rx = r2 - dx * dx
                            if rx > 0.0:
                                rj = wp.sqrt(rx)
                                j = wp.max(0, int(wp.ceil((p[1] - rj) * inv_c)))
                                j1 = wp.min(BLOCK - 1, int(wp.floor((p[1] + rj) * inv_c)))
                                row = ab + 4 * (i * BLOCK + j)
                                while j <= j1:
                                    dy = float(j) * c - p[1]
                                    w = row_weights(R2 - dx * dx - dy * dy, dz2, inv_R2)
                                    acc[row] = acc[row] + w * p[0]
                                    acc[row + 1] = acc[row + 1] + w * p[1]
                                    acc[row + 2] = acc[row + 2] + w * p[2]
                                    acc[row + 3] = acc[row + 3] + w
                                    row += 4
                                    j += 1
                            i += 1
        full_below = full_below_mask(f, bc)
        for r in range(ROWS):
            store_row(
                f,
                kb,
                r,
                full_below,
                kz,
                acc[ab + 4 * r],
                acc[ab + 4 * r + 1],
                acc[ab + 4 * r + 2],
                acc[ab + 4 * r + 3],
                R,
                r0,
            )


@wp.kernel
def gather_rows(
    offset: int,
    f: BlockField,
    xs: wp.array(dtype=wp.vec3),
    start: wp.array(dtype=wp.int32),
    cdims: wp.vec3i,
    R: float,
    r0: float,
):
    """``splat_blocks`` turned around for a GPU: one thread per row of 8 nodes of a stored block
    gathers, in the splat's order, the particles whose ball reaches its row (the splat's own
    reach tests, so the same terms in the same order: bitwise the same field), its sums in
    registers. Candidates come from the block's coarse columns within a cell of R of the row."""
    t = wp.tid() + offset
    kb = t // ROWS
    r = t % ROWS
    i = r // BLOCK
    j = r % BLOCK
    c = f.cell
    inv_c = 1.0 / c
    R2 = R * R
    inv_R2 = 1.0 / R2
    top = float(BLOCK - 1) * c
    kz = node_heights(c)
    bc = block_coords(f, kb)
    lo = node_position(f, bc, wp.vec3i(0, 0, 0))
    c0 = _coarse_index(lo - wp.vec3(R), f.lower, R, cdims)
    c1 = _coarse_index(lo + wp.vec3(top + R), f.lower, R, cdims)
    line = lo + wp.vec3(float(i) * c, float(j) * c, 0.0)
    a0 = _coarse_index(line - wp.vec3(R), f.lower, R, cdims)
    a1 = _coarse_index(line + wp.vec3(R), f.lower, R, cdims)
    sx = Float8()
    sy = Float8()
    sz = Float8()
    sw = Float8()
    dx_row = float(i) * c
    dy_row = float(j) * c
    for cx in range(wp.max(c0[0], a0[0] - 1), wp.min(c1[0], a1[0] + 1) + 1):
        for cy in range(wp.max(c0[1], a0[1] - 1), wp.min(c1[1], a1[1] + 1) + 1):
            col = (cx * cdims[1] + cy) * cdims[2]
            for q in range(start[col + c0[2]], start[col + c1[2] + 1]):
                p = xs[q] - lo
                gz = wp.max(0.0, wp.max(-p[2], p[2] - top))
                r2 = R2 - gz * gz
                if r2 > 0.0 and wp.max(p) < top + R and wp.min(p) > -R:
                    ri = wp.sqrt(r2)
                    if i >= wp.max(0, int(wp.ceil((p[0] - ri) * inv_c))) and i <= wp.min(
                        BLOCK - 1, int(wp.floor((p[0] + ri) * inv_c))
                    ):
                        dx = dx_row - p[0]
                        rx = r2 - dx * dx
                        if rx > 0.0:
                            rj = wp.sqrt(rx)
                            if j >= wp.max(0, int(wp.ceil((p[1] - rj) * inv_c))) and j <= wp.min(
                                BLOCK - 1, int(wp.floor((p[1] + rj) * inv_c))
                            ):
                                dy = dy_row - p[1]
                                dz = kz - Float8(p[2], p[2], p[2], p[2], p[2], p[2], p[2], p[2])
                                w = row_weights(R2 - dx * dx - dy * dy, wp.cw_mul(dz, dz), inv_R2)
                                sx = sx + w * p[0]
                                sy = sy + w * p[1]
                                sz = sz + w * p[2]
                                sw = sw + w
    store_row(f, kb, r, full_below_mask(f, bc), kz, sx, sy, sz, sw, R, r0)


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
    block_dims = np.ceil((hi + margin - lower) / (cell * BLOCK)).astype(int)
    n_blocks = int(np.prod(block_dims))
    if float(np.prod(block_dims.astype(float))) > 2.0**31 / (3 * CELLS3):
        raise ValueError(f"mesh grid of {(BLOCK * block_dims + 1).tolist()} nodes is too large; increase the cell size")
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
