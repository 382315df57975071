"""The liquid's surface from its particles: distance field, marching cubes, smoothing, normals.

1. Signed distance (Zhu & Bridson 2005) on a lattice of cell ``cell`` over the particles'
   bounding box plus a margin: ``phi(x) = |x - xbar(x)| - r0``, ``xbar`` the average of the
   particles within ``R`` weighted by ``k(s) = max(0, (1 - s^2)^3)``, ``s = |x - x_i| / R``. A
   node with no particle within ``R`` is outside (``phi = R``). The lattice is cut into blocks of
   ``BLOCK``^3 cells; a coarse count of particles marks blocks that are all air (EMPTY) or all
   deep liquid (FULL), and only the rest (SURFACE) are stored and computed, so memory and work
   follow the surface's area, not the tank's volume.
2. Marching cubes at ``phi = 0`` on the SURFACE blocks, with the case tables of
   ``warp.geometry.IsoSurfaceMarchingCubes`` and the same result as it gives on the dense field:
   one vertex per crossed lattice edge, so the mesh comes out welded across blocks; triangles
   are wound so that their normals point out of the liquid.
3. Smoothing over a vertex-to-triangle adjacency built on the device: Laplacian (the report's 3
   passes) or Taubin's lambda/mu, which does not shrink droplets; then area-weighted vertex
   normals.

Every per-node and per-vertex stage is a kernel run through :func:`launch_particles`, so it is
split over CPU threads and runs unchanged on CUDA.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import warp as wp
import warp.geometry

from .launch import launch_particles
from .neighbors import make_grid
from .scene import Surface as SurfaceParams


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
    nb: wp.vec3i
    lower: wp.vec3
    cell: float
    outside: float
    inside: float


@wp.func
def unflatten_block(f: BlockField, b: int) -> wp.vec3i:
    return wp.vec3i(b // (f.nb[1] * f.nb[2]), (b // f.nb[2]) % f.nb[1], b % f.nb[2])


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
    if g[0] >= f.nb[0] or g[1] >= f.nb[1] or g[2] >= f.nb[2]:
        return -1
    return (g[0] * f.nb[1] + g[1]) * f.nb[2] + g[2]


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
Phi8 = wp.types.vector(length=8, dtype=float)


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
    px = Phi8()
    py = Phi8()
    pz = Phi8()
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
    wsum = Phi8()
    sx = Phi8()
    sy = Phi8()
    sz = Phi8()
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


@wp.kernel
def count_incident(indices: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32)):
    # atomics: one launch, never split
    wp.atomic_add(count, indices[wp.tid()], 1)


@wp.kernel
def fill_incident(
    indices: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),
    cursor: wp.array(dtype=wp.int32),
    tris: wp.array(dtype=wp.int32),
):
    # a scatter with an atomic cursor: one launch, never split
    c = wp.tid()
    v = indices[c]
    slot = wp.atomic_add(cursor, v, 1)
    tris[start[v] + slot] = c / 3


@wp.func
def triangle_corners(verts: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), t: int):
    return verts[indices[3 * t]], verts[indices[3 * t + 1]], verts[indices[3 * t + 2]]


@wp.kernel
def smooth_vertices(
    offset: int,
    verts: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    tris: wp.array(dtype=wp.int32),
    factor: float,
    out: wp.array(dtype=wp.vec3),
):
    """One umbrella pass: move each vertex by ``factor`` towards the mean of its neighbours (each
    incident triangle's two other corners, so every edge of a closed mesh counts twice)."""
    v = wp.tid() + offset
    p = verts[v]
    s = wp.vec3(0.0)
    m = count[v]
    for k in range(start[v], start[v] + m):
        a, b, c = triangle_corners(verts, indices, tris[k])
        s += a + b + c - p
    if m > 0:
        out[v] = p + factor * (s / float(2 * m) - p)
    else:
        out[v] = p


@wp.kernel
def vertex_normals(
    offset: int,
    verts: wp.array(dtype=wp.vec3),
    indices: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    tris: wp.array(dtype=wp.int32),
    normals: wp.array(dtype=wp.vec3),
):
    v = wp.tid() + offset
    n = wp.vec3(0.0)
    for k in range(start[v], start[v] + count[v]):
        a, b, c = triangle_corners(verts, indices, tris[k])
        n += wp.cross(b - a, c - a)  # area-weighted
    ln = wp.length(n)
    if ln > 0.0:
        normals[v] = n / ln
    else:
        normals[v] = wp.vec3(0.0, 1.0, 0.0)


@wp.kernel
def flip_winding(offset: int, indices: wp.array(dtype=wp.int32)):
    t = wp.tid() + offset
    a = indices[3 * t + 1]
    indices[3 * t + 1] = indices[3 * t + 2]
    indices[3 * t + 2] = a


@dataclass
class SurfaceMesh:
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) int32, counter-clockwise seen from outside
    normals: np.ndarray  # (V, 3) float32, outward
    ms: dict  # wall milliseconds per stage
    stored_nodes: int = 0  # distance-field nodes computed and kept (SURFACE blocks)
    lattice_nodes: int = 0  # nodes of the whole lattice over the bounding box (a dense grid)


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


def _tables(device) -> dict:
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


def _bounds(x: wp.array) -> tuple[np.ndarray, np.ndarray, int]:
    """Lower and upper corner of ``x`` and how many of its points are not finite."""
    bounds = wp.array(np.array([[np.inf] * 3, [-np.inf] * 3], dtype=np.float32), dtype=wp.vec3, device=x.device)
    bad = wp.zeros(1, dtype=wp.int32, device=x.device)
    wp.launch(particle_bounds, dim=x.shape[0], inputs=[x, bounds, bad], device=x.device)
    b = bounds.numpy()  # float32, as the positions
    return b[0], b[1], int(bad.numpy()[0])


def _exclusive_scan(flags: wp.array) -> tuple[wp.array, int]:
    """Exclusive prefix sum of ``flags`` and its total, in one read back to the host: the
    inclusive sum is written one element on, after a leading zero."""
    n = flags.shape[0]
    sums = wp.empty(n + 1, dtype=flags.dtype, device=flags.device)
    sums[:1].zero_()
    if n:
        wp.utils.array_scan(flags, sums[1:], inclusive=True)
    return sums[:n], int(sums[n:].numpy()[0])


class SurfaceReconstructor:
    """Meshes particle sets of spacing ``h`` on one device; reuse it across frames.

    Memory and work follow the surface, not the bounding box: the field and marching cubes run
    on blocks of ``BLOCK``^3 cells that hold both liquid and air within R."""

    def __init__(self, h: float, params: SurfaceParams | None = None, device="cpu"):
        self.h = float(h)
        self.params = (params or SurfaceParams()).validate()
        self.device = wp.get_device(device)
        self.grid = make_grid(self.device)
        self.tables = _tables(self.device)
        self._winding_sign = None

    def _sync(self):
        wp.synchronize_device(self.device)

    def distance_field(self, x: np.ndarray | wp.array) -> SparseField:
        """The signed distance on the blocks near the surface of particle positions ``x``."""
        h, p = self.h, self.params
        cell, R, r0 = p.cell * h, p.radius * h, p.r0 * h
        if isinstance(x, wp.array):
            xd = x
        else:
            xd = wp.array(np.asarray(x, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=self.device)
        lo, hi, bad = _bounds(xd)
        if bad:
            raise ValueError(f"{bad} particles have non-finite positions")
        margin = R + 2.0 * cell
        lower = lo - margin
        nb = np.ceil((hi + margin - lower) / (cell * BLOCK)).astype(int)
        n_blocks = int(np.prod(nb))
        if float(np.prod(nb.astype(float))) > 2.0**31 / (3 * CELLS3):
            raise ValueError(f"mesh grid of {(BLOCK * nb + 1).tolist()} nodes is too large; increase the cell size")
        self.grid.build(xd, R)
        cdims = np.ceil(nb * BLOCK * cell / R).astype(int) + 1
        counts = wp.zeros(int(np.prod(cdims)), dtype=wp.int32, device=self.device)
        cd = wp.vec3i(*[int(c) for c in cdims])
        f = BlockField()
        f.nb = wp.vec3i(*[int(b) for b in nb])
        f.lower = wp.vec3(*lower.tolist())
        f.cell, f.outside, f.inside = float(cell), float(R), float(-r0)
        wp.launch(count_coarse, dim=xd.shape[0], inputs=[xd, f.lower, float(R), cd, counts], device=self.device)
        # a cube of side R = 2h holds about (R/h)^3 = 8 particles; "full" leaves room for jitter
        full = max(1, int(0.75 * (R / h) ** 3))
        f.kind = wp.empty(n_blocks, dtype=wp.int32, device=self.device)
        launch_particles(classify_blocks, n_blocks, [f, float(R), counts, cd, full], self.device)
        flag = wp.empty_like(f.kind)
        wp.launch(surface_flags, dim=n_blocks, inputs=[f.kind, flag], device=self.device)
        slot, n_surface = _exclusive_scan(flag)
        f.block_map = wp.empty_like(f.kind)
        blocks = wp.empty(max(n_surface, 1), dtype=wp.int32, device=self.device)
        wp.launch(compact_blocks, dim=n_blocks, inputs=[f.kind, slot, f.block_map, blocks], device=self.device)
        f.blocks = blocks[:n_surface]
        f.phi = wp.empty(n_surface * CELLS3, dtype=float, device=self.device)
        launch_particles(signed_distance, n_surface * SUBS**3,
                         [f, self.grid.id, xd, float(R), float(r0), counts, cd, full], self.device)
        return SparseField(f, tuple(int(b) for b in nb), lower, cell)

    def marching_cubes(self, field: SparseField) -> tuple[wp.array, wp.array]:
        """Vertices and triangle indices of ``phi = 0`` over the stored blocks: one vertex per
        crossed lattice edge (shared by the triangles around it), so the mesh comes out welded."""
        n_cells = field.n_stored * CELLS3
        if n_cells == 0:
            return wp.empty(0, dtype=wp.vec3, device=self.device), wp.empty(0, dtype=wp.int32, device=self.device)
        tb, f = self.tables, field.device
        crossing = wp.empty(3 * n_cells, dtype=wp.int32, device=self.device)
        launch_particles(count_edge_vertices, 3 * n_cells, [f, crossing], self.device)
        vertex, nv = _exclusive_scan(crossing)
        verts = wp.empty(nv, dtype=wp.vec3, device=self.device)
        launch_particles(emit_edge_vertices, 3 * n_cells, [f, crossing, vertex, verts], self.device)
        cases = wp.empty(n_cells, dtype=wp.int32, device=self.device)
        count = wp.empty(n_cells, dtype=wp.int32, device=self.device)
        launch_particles(count_cell_triangles, n_cells, [f, tb["corners"], tb["tri_range"], cases, count], self.device)
        first, nt = _exclusive_scan(count)
        indices = wp.empty(3 * nt, dtype=wp.int32, device=self.device)
        launch_particles(
            emit_cell_triangles, n_cells,
            [f, tb["tri_range"], tb["tri_edges"], tb["edge_origin"], cases, vertex, first, indices], self.device,
        )
        return verts, indices

    def _adjacency(self, indices: wp.array, nv: int):
        count = wp.zeros(nv, dtype=wp.int32, device=self.device)
        wp.launch(count_incident, dim=indices.shape[0], inputs=[indices, count], device=self.device)
        start = wp.zeros(nv, dtype=wp.int32, device=self.device)
        wp.utils.array_scan(count, start, inclusive=False)
        cursor = wp.zeros(nv, dtype=wp.int32, device=self.device)
        tris = wp.empty(indices.shape[0], dtype=wp.int32, device=self.device)
        wp.launch(fill_incident, dim=indices.shape[0], inputs=[indices, start, cursor, tris], device=self.device)
        return start, count, tris

    def reconstruct(self, x) -> SurfaceMesh:
        """The surface mesh of particle positions ``x`` ((N, 3) NumPy or a wp.array of vec3)."""
        ms = {}
        t = time.perf_counter()
        n_particles = len(x) if not isinstance(x, wp.array) else x.shape[0]
        if n_particles == 0:
            empty = np.zeros((0, 3), dtype=np.float32)
            return SurfaceMesh(empty, np.zeros((0, 3), dtype=np.int32), empty, {"distance_field": 0.0, "marching_cubes": 0.0, "smoothing": 0.0})
        field = self.distance_field(x)
        self._sync()
        ms["distance_field"] = 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        verts, indices = self.marching_cubes(field)
        nv, nt = verts.shape[0], indices.shape[0] // 3
        if nt > 0 and self._outward_sign(verts, indices) < 0:
            launch_particles(flip_winding, nt, [indices], self.device)
        self._sync()
        ms["marching_cubes"] = 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        normals = wp.zeros(nv, dtype=wp.vec3, device=self.device)
        if nt > 0:
            start, count, tris = self._adjacency(indices, nv)
            verts = self._smooth(verts, indices, start, count, tris)
            launch_particles(vertex_normals, nv, [verts, indices, start, count, tris, normals], self.device)
        self._sync()
        ms["smoothing"] = 1e3 * (time.perf_counter() - t)
        return SurfaceMesh(verts.numpy(), indices.numpy().reshape(-1, 3), normals.numpy(), ms,
                           field.n_stored * CELLS3, int(np.prod(field.node_dims)))

    def _smooth(self, verts, indices, start, count, tris):
        p = self.params
        if p.smoothing == "none" or p.passes == 0:
            return verts
        factors = [p.lam] if p.smoothing == "laplacian" else [p.lam, p.mu]
        a = wp.clone(verts)
        b = wp.empty_like(verts)
        for _ in range(p.passes):
            for f in factors:
                launch_particles(smooth_vertices, a.shape[0], [a, indices, start, count, tris, float(f), b], self.device)
                a, b = b, a
        return a

    def _outward_sign(self, verts: wp.array, indices: wp.array) -> float:
        """+1 when marching cubes winds triangles counter-clockwise seen from outside (phi > 0),
        found once on the first mesh by its signed volume."""
        if self._winding_sign is None:
            v = verts.numpy().astype(np.float64)
            f = indices.numpy().reshape(-1, 3)
            vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0
            if vol == 0.0:
                return 1.0
            self._winding_sign = math.copysign(1.0, vol)
        return self._winding_sign
