"""Marching cubes on the stored blocks of a sparse distance field, welded across blocks.

The case tables are those of ``warp.geometry.IsoSurfaceMarchingCubes`` and the mesh is the one it
gives on the dense field: one vertex per crossed lattice edge (shared by the triangles around it),
so the mesh comes out welded across blocks.
"""

from __future__ import annotations

import numpy as np
import warp as wp
import warp.geometry

from ..engine.launch import launch_particles
from .field import BLOCK, CELLS3, BlockField, SparseField, block_coords, exclusive_scan, local_node, local_slot, node_phi, node_position, owner_block


@wp.func
def axis_step(axis: int) -> wp.vec3i:
    return wp.vec3i(wp.where(axis == 0, 1, 0), wp.where(axis == 1, 1, 0), wp.where(axis == 2, 1, 0))


@wp.func
def edge_crosses(a: float, b: float) -> bool:
    # the inside test of warp.geometry's marching cubes: phi >= 0 sets a corner's bit
    return (a >= 0.0) != (b >= 0.0)


# Each stored block owns the three lattice edges leaving each of its nodes in +x, +y, +z:
# edge t of the flat numbering is block t // (3 CELLS3), node (t // 3) % CELLS3, axis t % 3.


@wp.kernel
def count_edge_vertices(offset: int, f: BlockField, crossing: wp.array(dtype=wp.int32)):
    t = wp.tid() + offset
    kb = t // (CELLS3 * 3)
    bc = block_coords(f, kb)
    l = local_node((t // 3) % CELLS3)
    a = node_phi(f, kb, bc, l)
    b = node_phi(f, kb, bc, l + axis_step(t % 3))
    crossing[t] = wp.where(edge_crosses(a, b), 1, 0)


@wp.kernel
def emit_edge_vertices(
    offset: int,
    f: BlockField,
    crossing: wp.array(dtype=wp.int32),
    vertex: wp.array(dtype=wp.int32),
    verts: wp.array(dtype=wp.vec3),
):
    t = wp.tid() + offset
    if crossing[t] == 0:
        return
    kb = t // (CELLS3 * 3)
    bc = block_coords(f, kb)
    la = local_node((t // 3) % CELLS3)
    lb = la + axis_step(t % 3)
    a = node_phi(f, kb, bc, la)
    b = node_phi(f, kb, bc, lb)
    verts[vertex[t]] = wp.lerp(node_position(f, bc, la), node_position(f, bc, lb), wp.clamp((0.0 - a) / (b - a), 0.0, 1.0))


@wp.func
def cube_case(f: BlockField, kb: int, bc: wp.vec3i, l: wp.vec3i, corners: wp.array(dtype=wp.vec3i)) -> int:
    code = int(0)
    for c in range(8):
        if node_phi(f, kb, bc, l + corners[c]) >= 0.0:
            code += 1 << c
    return code


@wp.kernel
def count_cell_triangles(
    offset: int,
    f: BlockField,
    corners: wp.array(dtype=wp.vec3i),
    tri_range: wp.array(dtype=wp.int32),
    cases: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
):
    t = wp.tid() + offset
    kb = t // CELLS3
    c = cube_case(f, kb, block_coords(f, kb), local_node(t % CELLS3), corners)
    cases[t] = c
    count[t] = (tri_range[c + 1] - tri_range[c]) // 3


@wp.kernel
def emit_cell_triangles(
    offset: int,
    f: BlockField,
    tri_range: wp.array(dtype=wp.int32),
    tri_edges: wp.array(dtype=wp.int32),
    edge_origin: wp.array(dtype=wp.vec4i),
    cases: wp.array(dtype=wp.int32),
    vertex: wp.array(dtype=wp.int32),
    first: wp.array(dtype=wp.int32),
    indices: wp.array(dtype=wp.int32),
):
    t = wp.tid() + offset
    c = cases[t]
    if tri_range[c + 1] == tri_range[c]:
        return
    kb = t // CELLS3
    bc = block_coords(f, kb)
    cl = local_node(t % CELLS3)
    out = 3 * first[t] - tri_range[c]
    for s in range(tri_range[c], tri_range[c + 1]):
        e = edge_origin[tri_edges[s]]
        l = cl + wp.vec3i(e[0], e[1], e[2])
        # an edge leaving a node on the block's upper faces is owned by the block above, which
        # is stored whenever the edge crosses (see node_phi)
        owner = kb
        if l[0] == BLOCK or l[1] == BLOCK or l[2] == BLOCK:
            owner = f.block_map[owner_block(f, bc, l)]
        indices[out + s] = vertex[(owner * CELLS3 + local_slot(l)) * 3 + e[3]]


def case_tables(device) -> dict:
    """Warp's public marching-cubes tables, plus each cube edge as (lowest corner, axis)."""
    mc = warp.geometry.IsoSurfaceMarchingCubes
    corners = np.array(mc.CUBE_CORNER_OFFSETS, dtype=np.int32)
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


def marching_cubes(field: SparseField, tables: dict, device) -> tuple[wp.array, wp.array]:
    """Vertices and triangle indices of ``phi = 0`` over the stored blocks: one vertex per
    crossed lattice edge (shared by the triangles around it), so the mesh comes out welded."""
    n_cells = field.n_stored * CELLS3
    if n_cells == 0:
        return wp.empty(0, dtype=wp.vec3, device=device), wp.empty(0, dtype=wp.int32, device=device)
    tb, f = tables, field.device
    crossing = wp.empty(3 * n_cells, dtype=wp.int32, device=device)
    launch_particles(count_edge_vertices, 3 * n_cells, [f, crossing], device)
    vertex, nv = exclusive_scan(crossing)
    verts = wp.empty(nv, dtype=wp.vec3, device=device)
    launch_particles(emit_edge_vertices, 3 * n_cells, [f, crossing, vertex, verts], device)
    cases = wp.empty(n_cells, dtype=wp.int32, device=device)
    count = wp.empty(n_cells, dtype=wp.int32, device=device)
    launch_particles(count_cell_triangles, n_cells, [f, tb["corners"], tb["tri_range"], cases, count], device)
    first, nt = exclusive_scan(count)
    indices = wp.empty(3 * nt, dtype=wp.int32, device=device)
    launch_particles(
        emit_cell_triangles, n_cells,
        [f, tb["tri_range"], tb["tri_edges"], tb["edge_origin"], cases, vertex, first, indices], device,
    )
    return verts, indices
