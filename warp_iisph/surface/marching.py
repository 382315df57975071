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
from .field import (BLOCK, CELLS3, BlockField, SparseField, Workspace, block_coords, local_node, local_slot, node_phi,
                    node_position, owner_block, scan_with_total, splat_workers, substage)

# warp.geometry's corner numbering: corner c of a cell sits at its lowest node + CUBE_CORNER_OFFSETS[c]
# (0,0,0) (1,0,0) (1,1,0) (0,1,0) (0,0,1) (1,0,1) (1,1,1) (0,1,1); in a block's flat node slots
# ((i * BLOCK + j) * BLOCK + k) those are these steps:
S1 = wp.constant(BLOCK * BLOCK)
S2 = wp.constant(BLOCK * BLOCK + BLOCK)
S3 = wp.constant(BLOCK)
S5 = wp.constant(BLOCK * BLOCK + 1)
S6 = wp.constant(BLOCK * BLOCK + BLOCK + 1)
S7 = wp.constant(BLOCK + 1)


@wp.func
def axis_step(axis: int) -> wp.vec3i:
    return wp.vec3i(wp.where(axis == 0, 1, 0), wp.where(axis == 1, 1, 0), wp.where(axis == 2, 1, 0))


@wp.func
def inside_bit(phi: float, c: int) -> int:
    # the inside test of warp.geometry's marching cubes: phi >= 0 sets a corner's bit
    return wp.where(phi >= 0.0, 1 << c, 0)


@wp.func
def cell_case(f: BlockField, kb: int, bc: wp.vec3i, m: int, corners: wp.array(dtype=wp.vec3i)) -> int:
    """The case of the cell whose lowest corner is node ``m`` of stored block ``kb``."""
    l = local_node(m)
    code = int(0)
    if l[0] < BLOCK - 1 and l[1] < BLOCK - 1 and l[2] < BLOCK - 1:  # all 8 corners in this block
        p = kb * CELLS3 + m
        code = (inside_bit(f.phi[p], 0) | inside_bit(f.phi[p + S1], 1) | inside_bit(f.phi[p + S2], 2)
                | inside_bit(f.phi[p + S3], 3) | inside_bit(f.phi[p + 1], 4) | inside_bit(f.phi[p + S5], 5)
                | inside_bit(f.phi[p + S6], 6) | inside_bit(f.phi[p + S7], 7))
    else:
        for c in range(8):
            code = code | inside_bit(node_phi(f, kb, bc, l + corners[c]), c)
    return code


@wp.func
def own_edges(code: int) -> int:
    """Which of the three edges leaving a cell's lowest corner (bit a: along axis a) its case
    crosses: corners 1, 3, 4 are the +x, +y, +z neighbours of corner 0."""
    c0 = code & 1
    return (wp.where(((code >> 1) & 1) != c0, 1, 0) | wp.where(((code >> 3) & 1) != c0, 2, 0)
            | wp.where(((code >> 4) & 1) != c0, 4, 0))


@wp.func
def popcount3(bits: int) -> int:
    return (bits & 1) + ((bits >> 1) & 1) + ((bits >> 2) & 1)


@wp.kernel
def block_cases(
    offset: int,
    workers: int,
    f: BlockField,
    corners: wp.array(dtype=wp.vec3i),
    tri_range: wp.array(dtype=wp.int32),
    cases: wp.array(dtype=wp.uint8),
    cell_vertex: wp.array(dtype=wp.uint16),
    totals: wp.array(dtype=wp.vec2i),
):
    """Pass 1 (see the module): cases, vertices before each cell in its block, block totals."""
    wk = wp.tid() + offset
    for kb in range(wk, f.blocks.shape[0], workers):
        bc = block_coords(f, kb)
        nv = int(0)
        nt = int(0)
        for m in range(CELLS3):
            code = cell_case(f, kb, bc, m, corners)
            cases[kb * CELLS3 + m] = wp.uint8(code)
            cell_vertex[kb * CELLS3 + m] = wp.uint16(nv)
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
            l = local_node(m)
            edges = own_edges(code)
            v = first[kb][0] + int(cell_vertex[kb * CELLS3 + m])
            if edges != 0:
                a = f.phi[kb * CELLS3 + m]
                pa = node_position(f, bc, l)
                for axis in range(3):
                    if (edges >> axis) & 1:
                        lb = l + axis_step(axis)
                        b = node_phi(f, kb, bc, lb)
                        verts[v] = wp.lerp(pa, node_position(f, bc, lb), wp.clamp((0.0 - a) / (b - a), 0.0, 1.0))
                        v += 1
            for s in range(tri_range[code], tri_range[code + 1]):
                e = edge_origin[tri_edges[s]]
                le = l + wp.vec3i(e[0], e[1], e[2])
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


def marching_cubes(field: SparseField, tables: dict, device, work: Workspace | None = None, flip: bool = False,
                   times=None) -> tuple[wp.array, wp.array]:
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
        launch_particles(block_cases, workers, [workers, f, tb["corners"], tb["tri_range"], cases, cell_vertex, totals],
                         device, min_chunk=1)
        first = scan_with_total(totals, work.get("first", nb + 1, wp.vec2i))
        nv, nt = (int(v) for v in first[nb:].numpy()[0])
    with substage(times, "mc_emit"):
        verts = wp.empty(nv, dtype=wp.vec3, device=device)
        indices = wp.empty(3 * nt, dtype=wp.int32, device=device)
        launch_particles(
            block_emit, workers,
            [workers, f, tb["tri_range"], tb["tri_edges"], tb["edge_origin"], cases, cell_vertex, first, int(flip), verts,
             indices],
            device, min_chunk=1,
        )
    return verts, indices
