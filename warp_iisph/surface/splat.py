"""The distance field's values on the stored blocks: particles grouped by coarse cell (size R, a
counting sort), then Zhu & Bridson's weighted average position per node. On the CPU each stored
block splats the particles of the coarse cells within R of it onto its nodes (``splat_blocks``:
per particle only the rows of 8 nodes along z that its ball reaches, all 8 weights of a row at
once, into sums that stay in cache); on CUDA a thread per row gathers them (``gather_rows``, the
same terms in the same order). Nodes on a face shared with a FULL block take -r0, as that block's
nodes do, so the cells of unstored blocks never cross."""

from __future__ import annotations

import warp as wp

from .blocks import BLOCK, CELLS3, FULL, BlockField, _coarse_index, block_coords, node_position

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


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
