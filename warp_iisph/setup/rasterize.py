"""Triangle meshes as boundary particles.

Each triangle is rasterised into a grid of cell size ``h``: only the cells of its bounding box
are visited and each is kept when the triangle overlaps it (the separating-axis triangle/box test
of Akenine-Moller 2001). Every occupied cell gives one point at its centre, so a surface is
covered without gaps wider than ``h`` however thin or stretched its triangles are. Two kernel
passes (count, then fill after a scan) write the cell keys; duplicates, where triangles share a
cell, are removed on the host. An open shell, and a box obstacle sampled by cells, keeps those
points as its particles.

A closed mesh is sampled behind its surface instead (:func:`surface_layers`; a mesh tank outside
it, an obstacle, a sphere, a thin box or a free body inside): each point moved onto the triangles
whose plane it projects into and from there by ``h/2`` to the solid's side, and the points of the
grid shifted by ``h/2`` likewise by ``h``, as a box tank's two staggered layers lie ``h/2`` and ``h`` outside its
faces, so the weights ``psi`` calibrated on those walls hold (one layer of cell centres outweighs
the liquid it replaces by 8 % of rho0 at one spacing) and where the cell centres fall (up to
``h/2`` either side of a surface, with how its faces meet the grid) no longer moves where the
liquid rests.

Fluid particles that would overlap an obstacle are told apart by :func:`fluid_room`: those inside a
closed mesh (winding number) and those closer than one spacing to a boundary particle.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..sph.neighbors import make_grid

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.func
def _axis_separates(a: wp.vec3, v0: wp.vec3, v1: wp.vec3, v2: wp.vec3, e: wp.vec3) -> bool:
    p0 = wp.dot(a, v0)
    p1 = wp.dot(a, v1)
    p2 = wp.dot(a, v2)
    r = e[0] * wp.abs(a[0]) + e[1] * wp.abs(a[1]) + e[2] * wp.abs(a[2])
    return wp.min(p0, wp.min(p1, p2)) > r or wp.max(p0, wp.max(p1, p2)) < -r


@wp.func
def triangle_box_overlap(c: wp.vec3, e: wp.vec3, a: wp.vec3, b: wp.vec3, d: wp.vec3) -> bool:
    """True when triangle (a, b, d) overlaps the box of centre ``c`` and half extents ``e``."""
    v0 = a - c
    v1 = b - c
    v2 = d - c
    f0 = v1 - v0
    f1 = v2 - v1
    f2 = v0 - v2
    # The box's face normals: the triangle's bounding box against the box.
    for k in range(3):
        if wp.min(v0[k], wp.min(v1[k], v2[k])) > e[k] or wp.max(v0[k], wp.max(v1[k], v2[k])) < -e[k]:
            return False
    # The triangle's plane.
    n = wp.cross(f0, f1)
    r = e[0] * wp.abs(n[0]) + e[1] * wp.abs(n[1]) + e[2] * wp.abs(n[2])
    if wp.abs(wp.dot(n, v0)) > r:
        return False
    # The nine cross products of box axes and triangle edges.
    for k in range(3):
        u = wp.vec3(0.0)
        u[k] = 1.0
        if _axis_separates(wp.cross(u, f0), v0, v1, v2, e):
            return False
        if _axis_separates(wp.cross(u, f1), v0, v1, v2, e):
            return False
        if _axis_separates(wp.cross(u, f2), v0, v1, v2, e):
            return False
    return True


@wp.func
def _cell_range(a: wp.vec3, b: wp.vec3, d: wp.vec3, h: float, k: int) -> wp.vec2i:
    lo = wp.min(a[k], wp.min(b[k], d[k]))
    hi = wp.max(a[k], wp.max(b[k], d[k]))
    return wp.vec2i(int(wp.floor(lo / h)), int(wp.floor(hi / h)))


@wp.kernel
def rasterize_triangles(
    vertices: wp.array(dtype=wp.vec3),
    faces: wp.array(dtype=wp.vec3i),
    h: float,
    origin: wp.vec3i,
    dims: wp.vec3i,
    start: wp.array(dtype=wp.int32),
    fill: int,
    count: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=wp.int64),
):
    """Pass 1 (fill = 0) counts the cells each triangle overlaps; pass 2 writes their keys."""
    t = wp.tid()
    f = faces[t]
    a = vertices[f[0]]
    b = vertices[f[1]]
    d = vertices[f[2]]
    rx = _cell_range(a, b, d, h, 0)
    ry = _cell_range(a, b, d, h, 1)
    rz = _cell_range(a, b, d, h, 2)
    # A hair larger than half a cell, so a triangle lying on a cell face still claims a cell.
    e = wp.vec3(0.5 * h * (1.0 + 1.0e-5))
    n = int(0)
    for i in range(rx[0], rx[1] + 1):
        for j in range(ry[0], ry[1] + 1):
            for k in range(rz[0], rz[1] + 1):
                c = wp.vec3((float(i) + 0.5) * h, (float(j) + 0.5) * h, (float(k) + 0.5) * h)
                if triangle_box_overlap(c, e, a, b, d):
                    if fill != 0:
                        key = wp.int64(i - origin[0]) + wp.int64(dims[0]) * (
                            wp.int64(j - origin[1]) + wp.int64(dims[1]) * wp.int64(k - origin[2])
                        )
                        keys[start[t] + n] = key
                    n += 1
    if fill == 0:
        count[t] = n


def sample_mesh(vertices: np.ndarray, faces: np.ndarray, h: float, device="cpu", pairs: bool = False):
    """Boundary particles of a triangle mesh: the centres of the grid cells (size ``h``, aligned
    to the origin) that its triangles overlap, each cell once. Returns an (N, 3) float64 array;
    with ``pairs``, every (cell centre, triangle index) a triangle claims, cells repeated."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
    if len(faces) == 0:
        return (np.zeros((0, 3)), np.zeros(0, dtype=np.int64)) if pairs else np.zeros((0, 3))
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"mesh face indices must lie in [0, {len(vertices) - 1}] (the vertex count)")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("mesh has non-finite vertex coordinates")
    lo = np.floor(vertices.min(axis=0) / h).astype(np.int64) - 1
    hi = np.floor(vertices.max(axis=0) / h).astype(np.int64) + 1
    dims = hi - lo + 1
    if float(np.prod(dims.astype(np.float64))) >= 2.0**62:
        raise ValueError(f"spacing = {h} m: the mesh spans too many cells")
    device = wp.get_device(device)
    v = wp.array(vertices.astype(np.float32), dtype=wp.vec3, device=device)
    f = wp.array(faces, dtype=wp.vec3i, device=device)
    count = wp.zeros(len(faces), dtype=wp.int32, device=device)
    start = wp.zeros(len(faces), dtype=wp.int32, device=device)
    origin = wp.vec3i(*[int(c) for c in lo])
    dimv = wp.vec3i(*[int(c) for c in dims])
    empty = wp.zeros(1, dtype=wp.int64, device=device)
    args = [v, f, float(h), origin, dimv, start]
    wp.launch(rasterize_triangles, dim=len(faces), inputs=[*args, 0, count, empty], device=device)
    wp.utils.array_scan(count, start, inclusive=False)
    total = int(start.numpy()[-1] + count.numpy()[-1])
    keys = wp.zeros(max(total, 1), dtype=wp.int64, device=device)
    wp.launch(rasterize_triangles, dim=len(faces), inputs=[*args, 1, count, keys], device=device)
    k = keys.numpy()[:total]
    if pairs:  # every cell with the triangle that claimed it
        triangles = np.repeat(np.arange(len(faces)), count.numpy())
    else:
        k = np.unique(k)
    ijk = np.stack([k % dims[0], (k // dims[0]) % dims[1], k // (dims[0] * dims[1])], axis=1) + lo
    return ((ijk + 0.5) * h, triangles) if pairs else (ijk + 0.5) * h


# What :func:`fluid_room` says of a fluid point: where the meshes leave no room for liquid (inside
# an obstacle, outside a container), where there is room but a boundary particle is closer than a
# spacing, and where it stays.
NO_ROOM, BESIDE_WALL, CLEAR = 0, 1, 2


@wp.kernel
def fluid_clearance(
    x: wp.array(dtype=wp.vec3),
    grid: wp.uint64,
    xb: wp.array(dtype=wp.vec3),
    min_distance: float,
    meshes: wp.array(dtype=wp.uint64),
    solid_inside: wp.array(dtype=wp.int32),
    room: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    p = x[i]
    clear = int(1)
    for b in wp.hash_grid_query(grid, p, min_distance):
        if wp.length(xb[b] - p) < min_distance:
            clear = 0
    inside = int(1)
    for m in range(meshes.shape[0]):
        q = wp.mesh_query_point_sign_winding_number(meshes[m], p, 1.0e6)
        if q.result:
            if (q.sign < 0.0) == (solid_inside[m] != 0):
                inside = 0
    room[i] = inside * (1 + clear)  # NO_ROOM, BESIDE_WALL or CLEAR


def fluid_room(
    x: np.ndarray, xb: np.ndarray, solids: list, h: float, containers: list = (), device="cpu"
) -> np.ndarray:
    """For each fluid point ``x``: ``NO_ROOM`` inside a closed obstacle mesh in ``solids`` or
    outside a container mesh in ``containers`` (meshes as ``(vertices, faces)`` pairs),
    ``BESIDE_WALL`` where it has room but lies closer than a spacing ``h`` to a boundary particle in
    ``xb``, else ``CLEAR``."""
    closed_meshes = list(solids) + list(containers)
    if len(x) == 0 or (len(xb) == 0 and not closed_meshes):
        return np.full(len(x), CLEAR, dtype=np.int32)
    device = wp.get_device(device)
    xd = wp.array(x.astype(np.float32), dtype=wp.vec3, device=device)
    xbd = wp.array(np.asarray(xb, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    grid = make_grid(device)
    grid.build(xbd, h)
    held = [
        wp.Mesh(
            points=wp.array(np.asarray(v, dtype=np.float32), dtype=wp.vec3, device=device),
            indices=wp.array(np.asarray(f, dtype=np.int32).reshape(-1), dtype=wp.int32, device=device),
        )
        for v, f in closed_meshes
    ]
    ids = wp.array(np.array([m.id for m in held], dtype=np.uint64), dtype=wp.uint64, device=device)
    solid = wp.array(np.array([1] * len(solids) + [0] * len(containers), dtype=np.int32), dtype=wp.int32, device=device)
    room = wp.zeros(len(x), dtype=wp.int32, device=device)
    # Slightly under h: a fluid lattice point exactly one spacing from a wall particle stays.
    wp.launch(fluid_clearance, dim=len(x), inputs=[xd, grid.id, xbd, 0.999 * h, ids, solid, room], device=device)
    return room.numpy()


@wp.func
def _room_behind(mesh: wp.uint64, c: wp.vec3, n: wp.vec3, depth: float) -> float:
    """``depth``, or half the solid's thickness behind surface point ``c`` along ``-n`` where that
    is less (a ray that only grazes a face meeting ``c``'s at an edge is no wall behind it)."""
    eps = 1.0e-4 * depth
    d = depth
    ray = wp.mesh_query_ray(mesh, c - eps * n, -n, 1.0e6)
    if ray.result and ray.t > eps:
        d = wp.min(depth, 0.5 * (ray.t + eps))
    return d


@wp.func
def _checked_depth(mesh: wp.uint64, x: wp.vec3, d: float, sign: float) -> float:
    """``d`` when point ``x`` lies on the solid's side at least that far from the surface, -1 when
    not (a cell that only touches a triangle at an edge, carried along its normal onto the face
    beside it)."""
    q = wp.mesh_query_point_sign_normal(mesh, x, 1.0e6)
    gap = wp.length(x - wp.mesh_eval_position(mesh, q.face, q.u, q.v))
    if q.sign * sign > 0.0 or gap < d * (1.0 - 1.0e-3):
        return -1.0
    return d


@wp.kernel
def depth_behind(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), sign: float, out: wp.array(dtype=float)):
    """Point i's distance from the surface where it lies on the solid's side (``sign`` +1: inside)
    behind an edge or a corner (its way from the closest surface point not along that face's
    normal: behind a face the faces' own layers lie), -1 elsewhere."""
    i = wp.tid()
    q = wp.mesh_query_point_sign_normal(mesh, points[i], 1.0e6)
    away = points[i] - wp.mesh_eval_position(mesh, q.face, q.u, q.v)
    out[i] = -1.0
    if q.sign * sign < 0.0:
        if wp.length(wp.cross(away, wp.mesh_eval_face_normal(mesh, q.face))) > 1.0e-3 * wp.length(away):
            out[i] = wp.length(away)


@wp.kernel
def layer_behind(
    mesh: wp.uint64,
    surface: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
    depth: float,
    sign: float,
    out: wp.array(dtype=wp.vec3),
    kept_depth: wp.array(dtype=float),
):
    """Surface point i moved ``depth`` against ``normal`` (from the solid towards the liquid), or
    to the middle of a part thinner than twice that (its depth there kept)."""
    i = wp.tid()
    c = surface[i]
    n = normal[i]
    d = _room_behind(mesh, c, n, depth)
    out[i] = c - d * n
    kept_depth[i] = _checked_depth(mesh, c - d * n, d, sign)


def oriented(mesh):
    """A copy of a closed ``mesh`` with its faces wound outwards, whatever the file's winding (the
    layers behind it and the containment's nearest-face and ray tests read the winding)."""
    import trimesh

    m = mesh.copy()
    trimesh.repair.fix_normals(m)
    return m


def unit_normals(triangles: np.ndarray) -> np.ndarray:
    """Each triangle's unit normal, zero for one without area (trimesh's ``normals`` leaves out a
    sliver's, shifting every index after it); a sliver's cells are also another face's."""
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _onto_faces(vertices: np.ndarray, faces: np.ndarray, h: float, device, shift: float):
    """The centres of the cells (of the grid shifted by ``shift`` along every axis) the faces
    cross, each moved onto every triangle whose plane it projects into (every face gets the points
    of its own cells, also beside an edge where a cell is nearer the other face), with that
    triangle's unit normal; and the cells' centres."""
    import trimesh

    cells, of = sample_mesh(vertices - shift, faces, h, device, pairs=True)
    cells = cells + shift
    triangles = vertices[faces]
    on_face = trimesh.triangles.closest_point(triangles[of], cells)
    unit = unit_normals(triangles)[of]
    in_plane = cells - np.einsum("ij,ij->i", cells - triangles[of][:, 0], unit)[:, None] * unit
    within = np.linalg.norm(on_face - in_plane, axis=1) <= 1.0e-6 * h
    return on_face[within], unit[within], cells


def surface_layers(vertices, faces, h: float, device, sign: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Boundary particles ``h/2`` and ``h`` behind a closed surface wound outwards (``sign`` +1:
    inside it, -1: outside it), the second layer only where there is room for it, particles
    closer than ``h/2`` to one kept left out (the second layer behind a face is kept: it lies
    ``h/2`` behind the first, staggered); and each one's depth behind the surface."""
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int64).reshape(-1, 3)
    m = wp.Mesh(
        points=wp.array(vertices.astype(np.float32), dtype=wp.vec3, device=device),
        indices=wp.array(faces.astype(np.int32).reshape(-1), dtype=wp.int32, device=device),
    )
    layers, depths = [], []
    # the inner layer from the cells' centres, the outer one from the cells of the grid shifted by
    # h/2 (their centres on the grid's corners): staggered, as a box tank's two layers are, so
    # that no column of particles lines up behind another and leaves a channel between them
    for depth, shift in ((0.5 * h, 0.0), (h, 0.5 * h)):
        on_face, normals, cells_here = _onto_faces(vertices, faces, h, device, shift)
        if shift == 0.0:
            cells = cells_here
        c = wp.array(on_face.astype(np.float32), dtype=wp.vec3, device=device)
        n = wp.array((normals * sign).astype(np.float32), dtype=wp.vec3, device=device)
        out = wp.zeros(len(on_face), dtype=wp.vec3, device=device)
        kept = wp.zeros(len(on_face), dtype=float, device=device)
        args = [m.id, c, n, float(depth), float(sign), out, kept]
        wp.launch(layer_behind, dim=len(on_face), inputs=args, device=device)
        p, d = out.numpy().astype(np.float64), kept.numpy().astype(np.float64)
        ok = d >= (depth * (1 - 1e-6) if depth > 0.5 * h else 0.0)  # the second layer where there is room
        layers.append(p[ok])
        depths.append(d[ok])
    # where the layers behind the faces leave a gap (behind an edge: a container's outside corner,
    # which no face's layer reaches), points of the grid on the solid's side behind an edge, as a
    # box tank's two staggered layers fill its corners: cell centres h/2 to h from the edge, cell
    # corners h to h sqrt(2) from it (the outer layer's corner)
    steps = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    index = np.unique(np.round(cells / h - 0.5).astype(np.int64), axis=0)
    near = np.unique((index[:, None, :] + steps).reshape(-1, 3), axis=0)
    for offset, lo, hi in ((0.5, 0.5 * h, h), (0.0, h * (1 + 2e-3), np.sqrt(2.0) * h)):
        grid_points = (near + offset) * h
        gap = wp.zeros(len(grid_points), dtype=float, device=device)
        points_in = wp.array(grid_points.astype(np.float32), dtype=wp.vec3, device=device)
        wp.launch(depth_behind, dim=len(grid_points), inputs=[m.id, points_in, float(sign), gap], device=device)
        gap = gap.numpy().astype(np.float64)
        fill = (gap >= lo * (1 - 1e-3)) & (gap <= hi * (1 + 1e-3))
        layers.append(grid_points[fill])
        depths.append(gap[fill])
    points, depth = np.concatenate(layers), np.concatenate(depths)
    keep = thinned(points, 0.5 * h * (1.0 - 1.0e-3))  # a second layer h/2 behind the first stays
    return points[keep], depth[keep]


def thinned(points: np.ndarray, least: float) -> np.ndarray:
    """Indices of points, in order, each at least ``least`` from every one kept before it."""
    cell = np.floor(points / least).astype(np.int64)
    kept: dict = {}
    out = []
    for i, key in enumerate(map(tuple, cell)):
        p = points[i]
        near = False
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for j in kept.get((key[0] + dx, key[1] + dy, key[2] + dz), ()):
                        if np.dot(points[j] - p, points[j] - p) < least * least:
                            near = True
                            break
                    if near:
                        break
                if near:
                    break
            if near:
                break
        if not near:
            kept.setdefault(key, []).append(i)
            out.append(i)
    return np.asarray(out, dtype=np.int64)
