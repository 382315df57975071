"""Marching cubes on the stored blocks of a sparse distance field, welded across blocks.

The case tables are those of ``warp.geometry.IsoSurfaceMarchingCubes`` and the mesh is the one it
gives on the dense field: one vertex per crossed lattice edge (shared by the triangles around it),
so the mesh comes out welded across blocks.

Two passes over the blocks, each block one worker's job from first cell to last (so a block's
vertices and triangles are numbered in cell order without atomics, and splitting the workers
over threads changes no bit):

1. ``block_cases``: each cell's case (8 corner signs), the number of vertices before it in its
   block (one per crossed edge among the three leaving its lowest corner in +x, +y, +z), and the
   block's totals of vertices and triangles; a scan of the totals gives each block's first.
2. ``block_emit``: the vertices on the crossed edges and the triangles of each cell, whose
   corners are found on the edges' owner cells (in this block or one above) by their numbering.
"""

from __future__ import annotations

import numpy as np
import warp as wp
import warp.geometry

from ..engine.launch import launch_particles
from .blocks import (
    BLOCK,
    CELLS3,
    FULL,
    BlockField,
    block_coords,
    local_node,
    local_slot,
    node_phi,
    node_position,
    owner_block,
)
from .field import SparseField, Workspace, scan_with_total, splat_workers, substage

# Warp unrolls loops of constant trip count up to max_unroll (16): the nested loops over a block's
# rows and nodes here would unroll into thousands of copies and take minutes to compile
wp.set_module_options({"max_unroll": 1, "enable_backward": False})  # never differentiated either


@wp.func
def axis_step(axis: int) -> wp.vec3i:
    return wp.vec3i(wp.where(axis == 0, 1, 0), wp.where(axis == 1, 1, 0), wp.where(axis == 2, 1, 0))


@wp.func
def own_edges(code: int) -> int:
    """Which of the three edges leaving a cell's lowest corner (bit a: along axis a) its case
    crosses: corners 1, 3, 4 are the +x, +y, +z neighbours of corner 0."""
    c0 = code & 1
    return (
        wp.where(((code >> 1) & 1) != c0, 1, 0)
        | wp.where(((code >> 3) & 1) != c0, 2, 0)
        | wp.where(((code >> 4) & 1) != c0, 4, 0)
    )


@wp.func
def popcount3(bits: int) -> int:
    return (bits & 1) + ((bits >> 1) & 1) + ((bits >> 2) & 1)


NODES1 = wp.constant(BLOCK + 1)  # nodes per side of a block with its upper faces
FULL_ROW = wp.constant((1 << (BLOCK + 1)) - 1)


@wp.func
def upper_neighbours(f: BlockField, bc: wp.vec3i) -> wp.vec4i:
    """For the 7 blocks above block ``bc`` (bit e: the one at bc + (e >> 2, (e >> 1) & 1, e & 1)):
    in x which are stored, in y which are FULL (inside); the rest are EMPTY or beyond the
    lattice (outside). z and w are unused."""
    stored = int(0)
    full = int(0)
    for e in range(1, 8):
        g = bc + wp.vec3i((e >> 2) & 1, (e >> 1) & 1, e & 1)
        if g[0] < f.block_dims[0] and g[1] < f.block_dims[1] and g[2] < f.block_dims[2]:
            b = (g[0] * f.block_dims[1] + g[1]) * f.block_dims[2] + g[2]
            if f.block_map[b] >= 0:
                stored = stored | (1 << e)
            elif f.kind[b] == FULL:
                full = full | (1 << e)
    return wp.vec4i(stored, full, 0, 0)


@wp.func
def upper_phi(f: BlockField, bc: wp.vec3i, node: wp.vec3i, e: int, nb: wp.vec4i) -> float:
    """phi at ``node`` on the upper faces of block ``bc``, owned by its neighbour ``e``."""
    if (nb[0] >> e) & 1:
        b = owner_block(f, bc, node)
        return f.phi[f.block_map[b] * CELLS3 + local_slot(node)]
    if (nb[1] >> e) & 1:
        return f.inside
    return f.outside


@wp.kernel
def block_cases(
    offset: int,
    workers: int,
    f: BlockField,
    tri_range: wp.array(dtype=wp.int32),
    signs: wp.array(dtype=wp.int32),
    cases: wp.array(dtype=wp.uint8),
    cell_vertex: wp.array(dtype=wp.uint16),
    totals: wp.array(dtype=wp.vec2i),
):
    """Pass 1 (see the module): cases, vertices before each cell in its block, block totals.
    First the signs of the block's (BLOCK + 1)^3 nodes, its upper faces included, as one bit
    mask per row along z (in ``signs``, the worker's own 81 rows); then each cell's case is
    8 bits of 4 rows, and a row of cells whose 4 rows are all in or all out is skipped."""
    wk = wp.tid() + offset
    sb = wk * NODES1 * NODES1
    for kb in range(wk, f.blocks.shape[0], workers):
        bc = block_coords(f, kb)
        nb = upper_neighbours(f, bc)
        base = kb * CELLS3
        for i in range(NODES1):
            for j in range(NODES1):
                bits = int(0)
                if i < BLOCK and j < BLOCK:
                    p = base + (i * BLOCK + j) * BLOCK
                    for k in range(BLOCK):
                        bits = bits | wp.where(f.phi[p + k] >= 0.0, 1 << k, 0)
                    bits = bits | wp.where(upper_phi(f, bc, wp.vec3i(i, j, BLOCK), 1, nb) >= 0.0, 1 << BLOCK, 0)
                else:
                    e0 = wp.where(i == BLOCK, 4, 0) | wp.where(j == BLOCK, 2, 0)
                    for k in range(NODES1):
                        e = e0 | wp.where(k == BLOCK, 1, 0)
                        bits = bits | wp.where(upper_phi(f, bc, wp.vec3i(i, j, k), e, nb) >= 0.0, 1 << k, 0)
                signs[sb + i * NODES1 + j] = bits
        nv = int(0)
        nt = int(0)
        for i in range(BLOCK):
            for j in range(BLOCK):
                r00 = signs[sb + i * NODES1 + j]
                r10 = signs[sb + (i + 1) * NODES1 + j]
                r11 = signs[sb + (i + 1) * NODES1 + j + 1]
                r01 = signs[sb + i * NODES1 + j + 1]
                m0 = base + (i * BLOCK + j) * BLOCK
                if r00 == r10 and r00 == r11 and r00 == r01 and (r00 == 0 or r00 == FULL_ROW):
                    for k in range(BLOCK):  # no crossing in this row of cells
                        cases[m0 + k] = wp.uint8(wp.where(r00 == 0, 0, 255))
                        cell_vertex[m0 + k] = wp.uint16(nv)
                else:
                    for k in range(BLOCK):
                        # warp.geometry's corners 0-3 at z = k, 4-7 at z = k + 1
                        code = (
                            ((r00 >> k) & 1)
                            | (((r10 >> k) & 1) << 1)
                            | (((r11 >> k) & 1) << 2)
                            | (((r01 >> k) & 1) << 3)
                            | (((r00 >> (k + 1)) & 1) << 4)
                            | (((r10 >> (k + 1)) & 1) << 5)
                            | (((r11 >> (k + 1)) & 1) << 6)
                            | (((r01 >> (k + 1)) & 1) << 7)
                        )
                        cases[m0 + k] = wp.uint8(code)
                        cell_vertex[m0 + k] = wp.uint16(nv)
                        nv += popcount3(own_edges(code))
                        nt += (tri_range[code + 1] - tri_range[code]) // 3
        totals[kb] = wp.vec2i(nv, nt)


@wp.kernel
def block_emit(
    offset: int,
    workers: int,
    f: BlockField,
    tri_range: wp.array(dtype=wp.int32),
    tri_edges: wp.array(dtype=wp.int32),
    edge_origin: wp.array(dtype=wp.vec4i),
    cases: wp.array(dtype=wp.uint8),
    cell_vertex: wp.array(dtype=wp.uint16),
    first: wp.array(dtype=wp.vec2i),
    flip: int,
    verts: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
):
    """Pass 2 (see the module): vertices on the crossed edges, triangles (the second and third
    corner swapped when ``flip``, to wind them outward)."""
    wk = wp.tid() + offset
    for kb in range(wk, f.blocks.shape[0], workers):
        bc = block_coords(f, kb)
        tri = first[kb][1]
        for m in range(CELLS3):
            code = int(cases[kb * CELLS3 + m])
            if code == 0 or code == 255:
                continue
            node = local_node(m)
            edges = own_edges(code)
            v = first[kb][0] + int(cell_vertex[kb * CELLS3 + m])
            if edges != 0:
                a = f.phi[kb * CELLS3 + m]
                pa = node_position(f, bc, node)
                for axis in range(3):
                    if (edges >> axis) & 1:
                        lb = node + axis_step(axis)
                        b = node_phi(f, kb, bc, lb)
                        verts[v] = wp.lerp(pa, node_position(f, bc, lb), wp.clamp((0.0 - a) / (b - a), 0.0, 1.0))
                        v += 1
            for s in range(tri_range[code], tri_range[code + 1]):
                e = edge_origin[tri_edges[s]]
                le = node + wp.vec3i(e[0], e[1], e[2])
                # the edge's owner: this block, or for an edge leaving a node on its upper faces
                # the block above, stored whenever the edge crosses (see node_phi)
                owner = kb
                if le[0] == BLOCK or le[1] == BLOCK or le[2] == BLOCK:
                    owner = f.block_map[owner_block(f, bc, le)]
                cell = owner * CELLS3 + local_slot(le)
                below = own_edges(int(cases[cell])) & ((1 << e[3]) - 1)  # crossed edges numbered before it
                corner = s - tri_range[code]
                k = corner % 3
                slot = 3 * tri + corner - k + wp.where(flip != 0 and k > 0, 3 - k, k)
                indices[slot] = first[owner][0] + int(cell_vertex[cell]) + popcount3(below)
            tri += (tri_range[code + 1] - tri_range[code]) // 3


def case_tables(device) -> dict:
    """Warp's public marching-cubes tables, plus each cube edge as (lowest corner, axis)."""
    mc = warp.geometry.IsoSurfaceMarchingCubes
    corners = np.array(mc.CUBE_CORNER_OFFSETS, dtype=np.int32)
    assert [tuple(corners[c]) for c in (0, 1, 3, 4)] == [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    origin = []
    for a, b in mc.EDGE_TO_CORNERS:
        lo = np.minimum(corners[a], corners[b])
        origin.append((*lo.tolist(), int(np.argmax(corners[a] != corners[b]))))
    return {
        "corners": wp.array(corners, dtype=wp.vec3i, device=device),
        "tri_range": wp.array(np.array(mc.CASE_TO_TRI_RANGE, dtype=np.int32), device=device),
        "tri_edges": wp.array(np.array(mc.TRI_LOCAL_INDICES, dtype=np.int32), device=device),
        "edge_origin": wp.array(np.array(origin, dtype=np.int32), dtype=wp.vec4i, device=device),
    }


def marching_cubes(
    field: SparseField, tables: dict, device, work: Workspace | None = None, flip: bool = False, times=None
) -> tuple[wp.array, wp.array]:
    """Vertices and triangle indices of ``phi = 0`` over the stored blocks: one vertex per
    crossed lattice edge (shared by the triangles around it), so the mesh comes out welded.
    ``flip`` swaps each triangle's winding. The outputs are fresh arrays; scratch in ``work``."""
    work = work or Workspace(device)
    nb = field.n_stored
    if nb == 0:
        return wp.empty(0, dtype=wp.vec3, device=device), wp.empty(0, dtype=wp.int32, device=device)
    tb, f = tables, field.device
    workers = splat_workers(nb, device)
    with substage(times, "mc_cases"):
        cases = work.get("cases", nb * CELLS3, wp.uint8)
        cell_vertex = work.get("cell_vertex", nb * CELLS3, wp.uint16)
        totals = work.get("totals", nb, wp.vec2i)
        signs = work.get("signs", workers * (BLOCK + 1) ** 2, wp.int32)
        launch_particles(
            block_cases, workers, [workers, f, tb["tri_range"], signs, cases, cell_vertex, totals], device, min_chunk=1
        )
        first = scan_with_total(totals, work.get("first", nb + 1, wp.vec2i))
        nv, nt = (int(v) for v in first[nb:].numpy()[0])
    with substage(times, "mc_emit"):
        verts = wp.empty(nv, dtype=wp.vec3, device=device)
        indices = wp.empty(3 * nt, dtype=wp.int32, device=device)
        launch_particles(
            block_emit,
            workers,
            [
                workers,
                f,
                tb["tri_range"],
                tb["tri_edges"],
                tb["edge_origin"],
                cases,
                cell_vertex,
                first,
                int(flip),
                verts,
                indices,
            ],
            device,
            min_chunk=1,
        )
    return verts, indices
