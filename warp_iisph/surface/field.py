"""Zhu & Bridson's signed distance to the liquid, stored only on blocks of cells the surface can cross.

``phi(x) = |x - xbar(x)| - r0``, ``xbar`` the average of the particles within ``R`` weighted by
``k(s) = max(0, (1 - s^2)^3)``, ``s = |x - x_i| / R``, on a lattice of cell ``cell`` over the
particles' bounding box plus a margin. A node with no particle within ``R`` is outside
(``phi = R``). The lattice is cut into blocks of ``BLOCK``^3 cells; a coarse count of particles
marks blocks that are all air (EMPTY) or all deep liquid (FULL), and only the rest (SURFACE)
are stored and computed, so memory and work follow the surface's area, not the tank's volume.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ..engine.launch import launch_particles


@wp.func
def _coarse_index(p: wp.vec3, lower: wp.vec3, C: float, cdims: wp.vec3i) -> wp.vec3i:
    q = (p - lower) / C
    return wp.vec3i(
        wp.clamp(int(q[0]), 0, cdims[0] - 1), wp.clamp(int(q[1]), 0, cdims[1] - 1), wp.clamp(int(q[2]), 0, cdims[2] - 1)
    )


@wp.kernel
def count_coarse(x: wp.array(dtype=wp.vec3), lower: wp.vec3, C: float, cdims: wp.vec3i, counts: wp.array(dtype=wp.int32)):
    # atomics: one launch, never split
    c = _coarse_index(x[wp.tid()], lower, C, cdims)
    wp.atomic_add(counts, (c[0] * cdims[1] + c[1]) * cdims[2] + c[2], 1)


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
    kind: wp.array(dtype=wp.int32),
    slot: wp.array(dtype=wp.int32),
    block_map: wp.array(dtype=wp.int32),
    blocks: wp.array(dtype=wp.int32),
):
    # a scatter through an exclusive scan of the SURFACE flags; each thread writes its own slots
    b = wp.tid()
    if kind[b] == SURFACE:
        block_map[b] = slot[b]
        blocks[slot[b]] = b
    else:
        block_map[b] = -1


@wp.kernel
def surface_flags(kind: wp.array(dtype=wp.int32), flag: wp.array(dtype=wp.int32)):
    b = wp.tid()
    flag[b] = wp.where(kind[b] == SURFACE, 1, 0)


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
    return wp.vec3i(b // (f.block_dims[1] * f.block_dims[2]), (b // f.block_dims[2]) % f.block_dims[1], b % f.block_dims[2])


@wp.func
def block_coords(f: BlockField, kb: int) -> wp.vec3i:
    return unflatten_block(f, f.blocks[kb])


@wp.func
def local_node(m: int) -> wp.vec3i:
    return wp.vec3i(m // (BLOCK * BLOCK), (m // BLOCK) % BLOCK, m % BLOCK)


@wp.func
def local_slot(l: wp.vec3i) -> int:
    """Inverse of ``local_node``, for a node in [0, BLOCK]^3 taken into the block that owns it."""
    return ((l[0] % BLOCK) * BLOCK + l[1] % BLOCK) * BLOCK + l[2] % BLOCK


@wp.func
def owner_block(f: BlockField, bc: wp.vec3i, l: wp.vec3i) -> int:
    """Flat number of the block that owns node ``l`` in [0, BLOCK]^3 of the block at ``bc`` (the
    block itself, or one above it for a node on its upper faces); -1 beyond the lattice."""
    g = bc + wp.vec3i(l[0] // BLOCK, l[1] // BLOCK, l[2] // BLOCK)
    if g[0] >= f.block_dims[0] or g[1] >= f.block_dims[1] or g[2] >= f.block_dims[2]:
        return -1
    return (g[0] * f.block_dims[1] + g[1]) * f.block_dims[2] + g[2]


@wp.func
def node_position(f: BlockField, bc: wp.vec3i, l: wp.vec3i) -> wp.vec3:
    return f.lower + f.cell * wp.vec3(float(BLOCK * bc[0] + l[0]), float(BLOCK * bc[1] + l[1]), float(BLOCK * bc[2] + l[2]))


@wp.func
def node_phi(f: BlockField, kb: int, bc: wp.vec3i, l: wp.vec3i) -> float:
    """phi at node ``l`` in [0, BLOCK]^3 of stored block ``kb`` (at block coordinates ``bc``).
    A block stores its nodes in [0, BLOCK)^3; those on its upper faces belong to the blocks above
    it, which store them, or hold EMPTY/FULL, where every node has the value the narrow-band
    test of ``signed_distance`` gives."""
    if l[0] < BLOCK and l[1] < BLOCK and l[2] < BLOCK:
        return f.phi[kb * CELLS3 + local_slot(l)]
    b = owner_block(f, bc, l)
    if b < 0:
        return f.outside  # the lattice's top nodes lie in the margin, beyond R of every particle
    m = f.block_map[b]
    if m >= 0:
        return f.phi[m * CELLS3 + local_slot(l)]
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
):
    """Each block's kind: the narrow-band test over the coarse cells of all its nodes, from its
    lowest to its highest; only SURFACE blocks are stored and meshed."""
    b = wp.tid() + offset
    bc = unflatten_block(f, b)
    c0 = _coarse_index(node_position(f, bc, wp.vec3i(0, 0, 0)), f.lower, R, cdims)
    c1 = _coarse_index(node_position(f, bc, wp.vec3i(BLOCK, BLOCK, BLOCK)), f.lower, R, cdims)
    f.kind[b] = coarse_kind(counts, cdims, c0, c1, full)


SUB = wp.constant(2)  # signed_distance gives each thread a cube of SUB^3 nodes: one grid query for all
SUBS = wp.constant(BLOCK // SUB)
Float8 = wp.types.vector(length=8, dtype=float)  # one value per node of a 2x2x2 cube


@wp.func
def sub_corner(c: int) -> wp.vec3i:
    return wp.vec3i(c // 4, (c // 2) % 2, c % 2)


@wp.kernel
def signed_distance(
    offset: int,
    f: BlockField,
    grid: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    R: float,
    r0: float,
    counts: wp.array(dtype=wp.int32),
    cdims: wp.vec3i,
    full: int,
):
    """Zhu & Bridson's distance at the 8 nodes of one 2x2x2 cube of a stored block: one grid
    query (radius R plus the cube's half-diagonal) serves all 8, whose candidates it reads once;
    each node sums the particles within R in the order its own query would visit them."""
    n = wp.tid() + offset
    kb = n // (SUBS * SUBS * SUBS)
    m = n % (SUBS * SUBS * SUBS)
    bc = block_coords(f, kb)
    l0 = SUB * wp.vec3i(m // (SUBS * SUBS), (m // SUBS) % SUBS, m % SUBS)
    base = kb * CELLS3
    px = Float8()
    py = Float8()
    pz = Float8()
    for c in range(8):
        p = node_position(f, bc, l0 + sub_corner(c))
        px[c] = p[0]
        py[c] = p[1]
        pz[c] = p[2]
    # narrow band, per node: outside (EMPTY) and deep inside (FULL) need no sum; the 8 nodes
    # share one coarse cell (and so one test) unless the cube straddles a cell boundary
    ca = _coarse_index(wp.vec3(px[0], py[0], pz[0]), f.lower, R, cdims)
    cb = _coarse_index(wp.vec3(px[7], py[7], pz[7]), f.lower, R, cdims)
    shared = int(-1)
    if ca[0] == cb[0] and ca[1] == cb[1] and ca[2] == cb[2]:
        shared = coarse_kind(counts, cdims, ca, ca, full)
    active = int(0)
    for c in range(8):
        slot = base + local_slot(l0 + sub_corner(c))
        kind = shared
        if kind < 0:
            cc = _coarse_index(wp.vec3(px[c], py[c], pz[c]), f.lower, R, cdims)
            kind = coarse_kind(counts, cdims, cc, cc, full)
        if kind == EMPTY:
            f.phi[slot] = R
        elif kind == FULL:
            f.phi[slot] = -r0
        else:
            active = active | (1 << c)
    if active == 0:
        return
    half = 0.5 * f.cell
    center = wp.vec3(px[0] + half, py[0] + half, pz[0] + half)
    reach = R + wp.sqrt(3.0) * half
    reach2 = reach * reach
    inv_R2 = 1.0 / (R * R)
    wsum = Float8()
    sx = Float8()
    sy = Float8()
    sz = Float8()
    for q in wp.hash_grid_query(grid, center, reach):
        xq = x[q]
        dc = xq - center
        if wp.dot(dc, dc) < reach2:
            for c in range(8):
                d = xq - wp.vec3(px[c], py[c], pz[c])
                s2 = wp.dot(d, d) * inv_R2
                if s2 < 1.0:
                    t = 1.0 - s2
                    w = t * t * t
                    wsum[c] = wsum[c] + w
                    sx[c] = sx[c] + w * xq[0]
                    sy[c] = sy[c] + w * xq[1]
                    sz[c] = sz[c] + w * xq[2]
    for c in range(8):
        if (active >> c) & 1:
            phi = R
            if wsum[c] > 0.0:
                xbar = wp.vec3(sx[c], sy[c], sz[c]) / wsum[c]
                phi = wp.length(wp.vec3(px[c], py[c], pz[c]) - xbar) - r0
            f.phi[base + local_slot(l0 + sub_corner(c))] = phi


@dataclass
class SparseField:
    """A distance field stored only on the blocks of ``BLOCK``^3 cells that the surface can cross.

    Node ``(i, j, k)`` of the lattice sits at ``lower + cell * (i, j, k)``; the lattice has
    ``BLOCK * block_dims + 1`` nodes per axis. ``device.phi`` holds the ``BLOCK``^3 nodes at the
    lower corner of each stored block (flat block numbers in ``device.blocks``); ``device.kind``
    says for every block whether it is EMPTY (phi = R everywhere), FULL (phi = -r0) or SURFACE
    (stored)."""

    device: BlockField
    block_dims: tuple
    lower: np.ndarray
    cell: float

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
        inner = out[:-1, :-1, :-1].reshape(self.block_dims[0], BLOCK, self.block_dims[1], BLOCK, self.block_dims[2], BLOCK)
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
    sums[:1].zero_()
    if n:
        wp.utils.array_scan(flags, sums[1:], inclusive=True)
    return sums[:n], int(sums[n:].numpy()[0])


def sparse_distance_field(x: np.ndarray | wp.array, h: float, params, grid: wp.HashGrid, device) -> SparseField:
    """The signed distance on the blocks near the surface of particle positions ``x`` (spacing
    ``h``; ``params``: the scene's surface settings, in spacings; ``grid``: a hash grid to reuse)."""
    p = params
    cell, R, r0 = p.cell * h, p.radius * h, p.r0 * h
    if isinstance(x, wp.array):
        xd = x
    else:
        xd = wp.array(np.asarray(x, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    lo, hi, bad = particle_box(xd)
    if bad:
        raise ValueError(f"{bad} particles have non-finite positions")
    margin = R + 2.0 * cell
    lower = lo - margin
    block_dims = np.ceil((hi + margin - lower) / (cell * BLOCK)).astype(int)
    n_blocks = int(np.prod(block_dims))
    if float(np.prod(block_dims.astype(float))) > 2.0**31 / (3 * CELLS3):
        raise ValueError(f"mesh grid of {(BLOCK * block_dims + 1).tolist()} nodes is too large; increase the cell size")
    grid.build(xd, R)
    cdims = np.ceil(block_dims * BLOCK * cell / R).astype(int) + 1
    counts = wp.zeros(int(np.prod(cdims)), dtype=wp.int32, device=device)
    cd = wp.vec3i(*[int(c) for c in cdims])
    f = BlockField()
    f.block_dims = wp.vec3i(*[int(b) for b in block_dims])
    f.lower = wp.vec3(*lower.tolist())
    f.cell, f.outside, f.inside = float(cell), float(R), float(-r0)
    wp.launch(count_coarse, dim=xd.shape[0], inputs=[xd, f.lower, float(R), cd, counts], device=device)
    # a cube of side R = 2h holds about (R/h)^3 = 8 particles; "full" leaves room for jitter
    full = max(1, int(0.75 * (R / h) ** 3))
    f.kind = wp.empty(n_blocks, dtype=wp.int32, device=device)
    launch_particles(classify_blocks, n_blocks, [f, float(R), counts, cd, full], device)
    flag = wp.empty_like(f.kind)
    wp.launch(surface_flags, dim=n_blocks, inputs=[f.kind, flag], device=device)
    slot, n_surface = exclusive_scan(flag)
    f.block_map = wp.empty_like(f.kind)
    blocks = wp.empty(max(n_surface, 1), dtype=wp.int32, device=device)
    wp.launch(compact_blocks, dim=n_blocks, inputs=[f.kind, slot, f.block_map, blocks], device=device)
    f.blocks = blocks[:n_surface]
    f.phi = wp.empty(n_surface * CELLS3, dtype=float, device=device)
    launch_particles(signed_distance, n_surface * SUBS**3,
                     [f, grid.id, xd, float(R), float(r0), counts, cd, full], device)
    return SparseField(f, tuple(int(b) for b in block_dims), lower, cell)
