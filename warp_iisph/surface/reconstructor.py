"""The liquid's surface from its particles: distance field, marching cubes, smoothing, normals.

1. :mod:`.field`: Zhu & Bridson's signed distance on the blocks of cells the surface can cross.
2. :mod:`.marching`: marching cubes at ``phi = 0`` on those blocks, welded, wound outward.
3. :mod:`.smoothing`: Laplacian (the report's 3 passes) or Taubin smoothing, vertex normals.

Every per-node and per-vertex stage is a kernel run through :func:`launch_particles`, so it is
split over CPU threads and runs unchanged on CUDA.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..engine.launch import launch_particles
from ..engine.timing import StageTimes
from ..scene import SurfaceSettings
from ..sph.neighbors import make_grid
from .field import CELLS3, SparseField, sparse_distance_field
from .marching import case_tables, marching_cubes
from .smoothing import adjacency, flip_winding, smooth, vertex_normals

STAGES = ("distance_field", "marching_cubes", "smoothing")


@dataclass
class SurfaceMesh:
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) int32, counter-clockwise seen from outside
    normals: np.ndarray  # (V, 3) float32, outward
    seconds: dict  # wall seconds per stage
    stored_nodes: int = 0  # distance-field nodes computed and kept (SURFACE blocks)
    lattice_nodes: int = 0  # nodes of the whole lattice over the bounding box (a dense grid)


class SurfaceReconstructor:
    """Meshes particle sets of spacing ``h`` on one device; reuse it across frames.

    Memory and work follow the surface, not the bounding box: the field and marching cubes run
    on blocks of ``BLOCK``^3 cells that hold both liquid and air within R."""

    def __init__(self, h: float, params: SurfaceSettings | None = None, device="cpu"):
        self.h = float(h)
        self.params = (params or SurfaceSettings()).validate()
        self.device = wp.get_device(device)
        self.grid = make_grid(self.device)
        self.tables = case_tables(self.device)
        self._winding_sign = None

    def distance_field(self, x: np.ndarray | wp.array) -> SparseField:
        """Stage 1: the signed distance on the blocks near the surface of positions ``x``."""
        return sparse_distance_field(x, self.h, self.params, self.grid, self.device)

    def marching_cubes(self, field: SparseField) -> tuple[wp.array, wp.array]:
        """Stage 2: vertices and triangle indices of ``phi = 0``, welded (winding as found)."""
        return marching_cubes(field, self.tables, self.device)

    def reconstruct(self, x) -> SurfaceMesh:
        """The surface mesh of particle positions ``x`` ((N, 3) NumPy or a wp.array of vec3)."""
        times = StageTimes(self.device, STAGES)
        n_particles = len(x) if not isinstance(x, wp.array) else x.shape[0]
        if n_particles == 0:
            empty = np.zeros((0, 3), dtype=np.float32)
            return SurfaceMesh(empty, np.zeros((0, 3), dtype=np.int32), empty, times.seconds)
        with times("distance_field"):
            field = self.distance_field(x)
        with times("marching_cubes"):
            verts, indices = self.marching_cubes(field)
            nv, nt = verts.shape[0], indices.shape[0] // 3
            if nt > 0 and self._outward_sign(verts, indices) < 0:
                launch_particles(flip_winding, nt, [indices], self.device)
        with times("smoothing"):
            normals = wp.zeros(nv, dtype=wp.vec3, device=self.device)
            if nt > 0:
                start, count, tris = adjacency(indices, nv, self.device)
                verts = smooth(verts, indices, start, count, tris, self.params, self.device)
                launch_particles(vertex_normals, nv, [verts, indices, start, count, tris, normals], self.device)
        return SurfaceMesh(verts.numpy(), indices.numpy().reshape(-1, 3), normals.numpy(), times.seconds,
                           field.n_stored * CELLS3, int(np.prod(field.node_dims)))

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
