"""The liquid's surface from its particles: distance field, marching cubes, smoothing, normals.

1. Signed distance (Zhu & Bridson 2005) on a grid of cell ``cell`` over the particles' bounding
   box plus a margin: ``phi(x) = |x - xbar(x)| - r0``, ``xbar`` the average of the particles
   within ``R`` weighted by ``k(s) = max(0, (1 - s^2)^3)``, ``s = |x - x_i| / R``. A node with no
   particle within ``R`` is outside (``phi = R``).
2. Marching cubes at ``phi = 0`` (``warp.geometry.IsoSurfaceMarchingCubes``); triangles are
   wound so that their normals point out of the liquid.
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


@wp.kernel
def signed_distance(
    offset: int,
    grid: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    lower: wp.vec3,
    cell: float,
    ny: int,
    nz: int,
    R: float,
    r0: float,
    counts: wp.array(dtype=wp.int32),
    cdims: wp.vec3i,
    full: int,
    phi: wp.array(dtype=float),
):
    n = wp.tid() + offset
    i = n // (ny * nz)
    j = (n // nz) % ny
    k = n % nz
    p = lower + cell * wp.vec3(float(i), float(j), float(k))
    # Narrow band: coarse cells of size R count particles. A node whose 27 surrounding coarse
    # cells are empty has no particle within R (outside); one whose cells are all full lies at
    # least R deep in the liquid, where only the sign matters. Neither needs the grid query.
    c = _coarse_index(p, lower, R, cdims)
    lo_count = int(2147483647)
    hi_count = int(0)
    for a in range(-1, 2):
        for b in range(-1, 2):
            for e in range(-1, 2):
                ca = c[0] + a
                cb = c[1] + b
                cd = c[2] + e
                m = int(0)
                if ca >= 0 and ca < cdims[0] and cb >= 0 and cb < cdims[1] and cd >= 0 and cd < cdims[2]:
                    m = counts[(ca * cdims[1] + cb) * cdims[2] + cd]
                lo_count = wp.min(lo_count, m)
                hi_count = wp.max(hi_count, m)
    if hi_count == 0:
        phi[n] = R
        return
    if lo_count >= full:
        phi[n] = -r0
        return
    wsum = float(0.0)
    xbar = wp.vec3(0.0)
    inv_R2 = 1.0 / (R * R)
    for q in wp.hash_grid_query(grid, p, R):
        d = x[q] - p
        s2 = wp.dot(d, d) * inv_R2
        if s2 < 1.0:
            t = 1.0 - s2
            w = t * t * t
            wsum += w
            xbar += w * x[q]
    if wsum > 0.0:
        phi[n] = wp.length(p - xbar / wsum) - r0
    else:
        phi[n] = R


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


class SurfaceReconstructor:
    """Meshes particle sets of spacing ``h`` on one device; reuse it across frames."""

    def __init__(self, h: float, params: SurfaceParams | None = None, device="cpu"):
        self.h = float(h)
        self.params = (params or SurfaceParams()).validate()
        self.device = wp.get_device(device)
        self.grid = make_grid(self.device)
        self._winding_sign = None

    def _sync(self):
        wp.synchronize_device(self.device)

    def distance_field(self, x: np.ndarray | wp.array):
        """(phi as a (nx, ny, nz) wp.array, lower corner, cell size)."""
        h, p = self.h, self.params
        cell, R, r0 = p.cell * h, p.radius * h, p.r0 * h
        if isinstance(x, wp.array):
            xd = x
            xn = x.numpy()
        else:
            xn = np.asarray(x, dtype=np.float32).reshape(-1, 3)
            xd = wp.array(xn, dtype=wp.vec3, device=self.device)
        if not np.all(np.isfinite(xn)):
            raise ValueError(f"{int((~np.isfinite(xn).all(axis=1)).sum())} particles have non-finite positions")
        margin = R + 2.0 * cell
        lower = xn.min(axis=0) - margin
        dims = np.ceil((xn.max(axis=0) + margin - lower) / cell).astype(int) + 1
        if float(np.prod(dims.astype(float))) > 2.0**31 - 1:
            raise ValueError(f"mesh grid of {dims.tolist()} nodes is too large; increase the cell size")
        self.grid.build(xd, R)
        n = int(np.prod(dims))
        lo = wp.vec3(*lower.tolist())
        cdims = np.ceil((dims - 1) * cell / R).astype(int) + 1
        counts = wp.zeros(int(np.prod(cdims)), dtype=wp.int32, device=self.device)
        cd = wp.vec3i(*[int(c) for c in cdims])
        wp.launch(count_coarse, dim=xd.shape[0], inputs=[xd, lo, float(R), cd, counts], device=self.device)
        # a cube of side R = 2h holds about (R/h)^3 = 8 particles; "full" leaves room for jitter
        full = max(1, int(0.75 * (R / h) ** 3))
        phi = wp.empty(n, dtype=float, device=self.device)
        launch_particles(
            signed_distance, n,
            [self.grid.id, xd, lo, float(cell), int(dims[1]), int(dims[2]), float(R), float(r0), counts, cd, full, phi],
            self.device,
        )
        return phi.reshape(tuple(int(d) for d in dims)), lower, cell

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
        phi, lower, cell = self.distance_field(x)
        self._sync()
        ms["distance_field"] = 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        nx, ny, nz = phi.shape
        upper = lower + cell * (np.array(phi.shape) - 1)
        mc = warp.geometry.IsoSurfaceMarchingCubes(nx, ny, nz, wp.vec3(*lower.tolist()), wp.vec3(*upper.tolist()))
        mc.surface(phi, 0.0)
        verts, indices = mc.verts, mc.indices
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
        return SurfaceMesh(verts.numpy(), indices.numpy().reshape(-1, 3), normals.numpy(), ms)

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
