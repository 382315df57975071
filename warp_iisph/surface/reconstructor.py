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
from dataclasses import field as dataclass_field

import numpy as np
import warp as wp

from ..engine.launch import launch_particles
from ..engine.timing import StageTimes
from ..scene import SurfaceSettings
from .field import CELLS3, SparseField, Workspace, sparse_distance_field, substage
from .marching import case_tables, marching_cubes
from .smoothing import adjacency, flip_winding, smooth, vertex_normals, vertex_weights

STAGES = ("distance_field", "marching_cubes", "smoothing")


@dataclass
class SurfaceMesh:
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) int32, counter-clockwise seen from outside
    normals: np.ndarray  # (V, 3) float32, outward
    seconds: dict  # wall seconds per stage
    stored_nodes: int = 0  # distance-field nodes computed and kept (SURFACE blocks)
    lattice_nodes: int = 0  # nodes of the whole lattice over the bounding box (a dense grid)
    detail: dict = dataclass_field(default_factory=dict)  # seconds per step within the stages (with profile=True)


# +1 when warp.geometry's case tables wind triangles counter-clockwise seen from phi > 0 (outside),
# -1 if not: a property of the tables, found once per process on the first mesh's signed volume
_winding_sign: float | None = None


class SurfaceReconstructor:
    """Meshes particle sets of spacing ``h`` on one device; reuse it across frames (it keeps its
    scratch arrays). ``profile=True`` also times each step within the stages (``SurfaceMesh.detail``;
    on CUDA it synchronises after each).

    Memory and work follow the surface, not the bounding box: the field and marching cubes run
    on blocks of ``BLOCK``^3 cells that hold both liquid and air within R."""

    def __init__(self, h: float, params: SurfaceSettings | None = None, device="cpu", profile: bool = False):
        self.h = float(h)
        self.params = (params or SurfaceSettings()).validate()
        self.device = wp.get_device(device)
        self.work = Workspace(self.device)  # scratch arrays reused from frame to frame
        self.tables = case_tables(self.device)
        self.profile = profile

    def distance_field(self, x: np.ndarray | wp.array, times=None) -> SparseField:
        """Stage 1: the signed distance on the blocks near the surface of positions ``x`` (its
        arrays are this reconstructor's scratch: valid until its next frame)."""
        return sparse_distance_field(x, self.h, self.params, self.device, self.work, times)

    def marching_cubes(self, field: SparseField, flip: bool = False, times=None) -> tuple[wp.array, wp.array]:
        """Stage 2: vertices and triangle indices of ``phi = 0``, welded (the tables' winding,
        or its reverse with ``flip``)."""
        return marching_cubes(field, self.tables, self.device, self.work, flip, times)

    def reconstruct(self, x) -> SurfaceMesh:
        """The surface mesh of particle positions ``x`` ((N, 3) NumPy or a wp.array of vec3)."""
        global _winding_sign
        times = StageTimes(self.device, STAGES)
        detail = StageTimes(self.device) if self.profile else None
        n_particles = len(x) if not isinstance(x, wp.array) else x.shape[0]
        if n_particles == 0:
            empty = np.zeros((0, 3), dtype=np.float32)
            return SurfaceMesh(empty, np.zeros((0, 3), dtype=np.int32), empty, times.seconds)
        with times("distance_field"):
            field = self.distance_field(x, detail)
        with times("marching_cubes"):
            verts, indices = self.marching_cubes(
                field, flip=_winding_sign is not None and _winding_sign < 0, times=detail
            )
            nv, nt = verts.shape[0], indices.shape[0] // 3
            if nt > 0 and _winding_sign is None:
                _winding_sign = _signed_volume_sign(verts, indices)
                if _winding_sign is not None and _winding_sign < 0:
                    launch_particles(flip_winding, nt, [indices], self.device)
        with times("smoothing"):
            normals = wp.empty(nv, dtype=wp.vec3, device=self.device)
            if nt > 0:
                with substage(detail, "adjacency"):
                    start, count, ring = adjacency(indices, nv, self.device, self.work)
                with substage(detail, "smooth"):
                    weights = None
                    if self.params.feature_weights and self.params.smoothing != "none" and self.params.passes > 0:
                        weights = vertex_weights(verts, field, self.h, self.device, self.work)
                    verts = smooth(verts, start, count, ring, self.params, self.device, self.work, weights)
                with substage(detail, "normals"):
                    launch_particles(vertex_normals, nv, [verts, start, count, ring, normals], self.device)
        return SurfaceMesh(
            verts.numpy(),
            indices.numpy().reshape(-1, 3),
            normals.numpy(),
            times.seconds,
            field.n_stored * CELLS3,
            int(np.prod(field.node_dims)),
            detail.seconds if detail else {},
        )


def _signed_volume_sign(verts: wp.array, indices: wp.array) -> float | None:
    """The sign of the mesh's signed volume (+1: counter-clockwise seen from outside); None if 0."""
    v = verts.numpy().astype(np.float64)
    f = indices.numpy().reshape(-1, 3)
    vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0
    return math.copysign(1.0, vol) if vol != 0.0 else None
