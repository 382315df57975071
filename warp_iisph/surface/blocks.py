"""The sparse lattice the surface lives on: blocks of ``BLOCK``^3 cells, each EMPTY (all air),
FULL (all deep liquid) or SURFACE (the surface can cross it; only these are stored), told apart by
a coarse count of particles (cells of the kernel radius R), and how a block's nodes are addressed
(:class:`BlockField`)."""

from __future__ import annotations

import warp as wp

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
