"""Mesh smoothing over a vertex adjacency built on the device: Laplacian (the report's) or Taubin's
lambda/mu (no shrinking), and area-weighted vertex normals.

Feature weights (on by default, ``SurfaceSettings.feature_weights``) scale each vertex's step by
how many particles are near it, as splashsurf's do (it counts each particle's neighbours and
interpolates them to the vertices), so that lone droplets keep their shape while the bulk
surface is smoothed; here the count is the coarse cells' particle count interpolated at the
vertex, which the field has already made.

The adjacency lists, for each vertex, its incident triangles by their other two corners in
winding order (``ring[start[v] + k] = (next, prev)``), so a pass reads two positions per
triangle and no triangle indices."""

from __future__ import annotations

import warp as wp

from ..engine.launch import launch_particles

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.kernel
def count_incident(indices: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32), rank: wp.array(dtype=wp.int32)):
    # atomics: one launch, never split (on the CPU the ranks follow the triangle order)
    rank[wp.tid()] = wp.atomic_add(count, indices[wp.tid()], 1)


@wp.kernel
def fill_incident(
    offset: int,
    indices: wp.array(dtype=wp.int32),
    start: wp.array(dtype=wp.int32),
    rank: wp.array(dtype=wp.int32),
    ring: wp.array(dtype=wp.vec2i),
):
    # a scatter to the slots that count_incident handed out: each corner writes its own
    c = wp.tid() + offset
    t = 3 * (c / 3)
    k = c - t
    ring[start[indices[c]] + rank[c]] = wp.vec2i(indices[t + (k + 1) % 3], indices[t + (k + 2) % 3])


@wp.kernel
def feature_weights(
    offset: int,
    verts: wp.array(dtype=wp.vec3),
    lower: wp.vec3,
    C: float,
    cdims: wp.vec3i,
    start: wp.array(dtype=wp.int32),
    full: float,
    weights: wp.array(dtype=float),
):
    """Each vertex's weight: the particle count of the coarse cells (size C, from ``lower``;
    ``start`` their ranges in the grouped order) interpolated trilinearly at the vertex,
    over ``full``, clamped to 1 and put through the smoothstep 6x^5 - 15x^4 + 10x^3."""
    v = wp.tid() + offset
    q = (verts[v] - lower) / C - wp.vec3(0.5)  # cell centres at integer q
    i0 = int(wp.floor(q[0]))
    j0 = int(wp.floor(q[1]))
    k0 = int(wp.floor(q[2]))
    f = q - wp.vec3(float(i0), float(j0), float(k0))
    n = float(0.0)
    for a in range(2):
        for b in range(2):
            for e in range(2):
                i = wp.clamp(i0 + a, 0, cdims[0] - 1)
                j = wp.clamp(j0 + b, 0, cdims[1] - 1)
                k = wp.clamp(k0 + e, 0, cdims[2] - 1)
                cell = (i * cdims[1] + j) * cdims[2] + k
                w = (
                    wp.where(a == 1, f[0], 1.0 - f[0])
                    * wp.where(b == 1, f[1], 1.0 - f[1])
                    * wp.where(e == 1, f[2], 1.0 - f[2])
                )
                n += w * float(start[cell + 1] - start[cell])
    x = wp.min(1.0, n / full)
    weights[v] = x * x * x * (x * (x * 6.0 - 15.0) + 10.0)


@wp.kernel
def smooth_vertices(
    offset: int,
    verts: wp.array(dtype=wp.vec3),
    start: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    ring: wp.array(dtype=wp.vec2i),
    factor: float,
    weights: wp.array(dtype=float),
    weighted: int,
    out: wp.array(dtype=wp.vec3),
):
    """One umbrella pass: move each vertex by ``factor`` (times its weight when ``weighted``)
    towards the mean of its neighbours (each incident triangle's two other corners, so every
    edge of a closed mesh counts twice)."""
    v = wp.tid() + offset
    p = verts[v]
    s = wp.vec3(0.0)
    m = count[v]
    for k in range(start[v], start[v] + m):
        r = ring[k]
        s += verts[r[0]] + verts[r[1]]
    step = factor
    if weighted != 0:
        step = factor * weights[v]
    if m > 0:
        out[v] = p + step * (s / float(2 * m) - p)
    else:
        out[v] = p


@wp.kernel
def vertex_normals(
    offset: int,
    verts: wp.array(dtype=wp.vec3),
    start: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    ring: wp.array(dtype=wp.vec2i),
    normals: wp.array(dtype=wp.vec3),
):
    v = wp.tid() + offset
    p = verts[v]
    n = wp.vec3(0.0)
    for k in range(start[v], start[v] + count[v]):
        r = ring[k]
        n += wp.cross(verts[r[0]] - p, verts[r[1]] - p)  # area-weighted
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


def adjacency(indices: wp.array, nv: int, device, work=None):
    """Each vertex's incident triangles by their other corners: ``ring[start[v] : start[v] +
    count[v]]`` (arrays from ``work``, a surface ``Workspace``, when given)."""
    get = work.get if work is not None else (lambda name, n, dtype: wp.empty(n, dtype=dtype, device=device))
    count = get("incident_count", nv, wp.int32)
    count.zero_()
    rank = get("incident_rank", indices.shape[0], wp.int32)
    wp.launch(count_incident, dim=indices.shape[0], inputs=[indices, count, rank], device=device)
    start = get("incident_start", nv, wp.int32)
    wp.utils.array_scan(count, start, inclusive=False)
    ring = get("ring", indices.shape[0], wp.vec2i)
    launch_particles(fill_incident, indices.shape[0], [indices, start, rank, ring], device)
    return start, count, ring


def vertex_weights(verts, field, h: float, device, work=None) -> wp.array:
    """The feature weight of each vertex (see :func:`feature_weights`) from the coarse particle
    counts of ``field`` (a ``SparseField``): 1 where a coarse cell's worth of particles holds a
    quarter of what a full one does, less towards lone particles."""
    nv = verts.shape[0]
    w = work.get("weights", nv, float) if work is not None else wp.empty(nv, dtype=float, device=device)
    full = 0.25 * (field.coarse_cell / h) ** 3  # a full cell of side R holds about (R / h)^3
    launch_particles(
        feature_weights,
        nv,
        [
            verts,
            wp.vec3(*[float(c) for c in field.lower]),
            float(field.coarse_cell),
            wp.vec3i(*field.coarse_dims),
            field.coarse_start,
            float(full),
            w,
        ],
        device,
    )
    return w


def smooth(verts, start, count, ring, params, device, work=None, weights=None):
    """``params.passes`` passes of Laplacian smoothing, or of Taubin's lambda/mu pairs, each
    vertex's step times its ``weights`` when given. The result is in ``verts``, overwritten
    (one more array from ``work`` when given)."""
    p = params
    if p.smoothing == "none" or p.passes == 0:
        return verts
    factors = [p.lam] if p.smoothing == "laplacian" else [p.lam, p.mu]
    a = verts
    b = work.get("smoothed", verts.shape[0], wp.vec3) if work is not None else wp.empty_like(verts)
    w = weights if weights is not None else wp.empty(0, dtype=float, device=device)
    for _ in range(p.passes):
        for f in factors:
            launch_particles(
                smooth_vertices, a.shape[0], [a, start, count, ring, float(f), w, int(weights is not None), b], device
            )
            a, b = b, a
    if a is not verts:
        wp.copy(verts, a)
    return verts
