"""Triangle meshes as boundary particles: coverage, obstacles that hold water out, speed."""

import time

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from warp_iisph import Simulation
from warp_iisph.scene import Box, MeshShape, Scene
from warp_iisph.setup.rasterize import clear_fluid, sample_mesh


def _points_on_triangle(v, n, rng):
    s = rng.random((n, 2))
    flip = s.sum(axis=1) > 1
    s[flip] = 1 - s[flip]
    return v[0] + s[:, :1] * (v[1] - v[0]) + s[:, 1:] * (v[2] - v[0])


def test_thin_stretched_triangle_leaves_no_gap_wider_than_h():
    """A long sliver at an odd angle: every point of it lies in an occupied cell, so within half
    a cell diagonal of a particle, and cells are distinct."""
    h = 0.05
    v = np.array([[0.013, -0.2, 0.07], [1.31, 0.47, 0.33], [1.31, 0.4702, 0.3303]])
    xb = sample_mesh(v, np.array([[0, 1, 2]]), h)
    d, _ = cKDTree(xb).query(_points_on_triangle(v, 50_000, np.random.default_rng(0)))
    assert d.max() <= 0.5 * np.sqrt(3) * h + 1e-6
    assert len(np.unique(np.floor(xb / h), axis=0)) == len(xb)
    # ... and only cells the triangle passes through: a sliver this thin occupies a thin chain
    assert len(xb) < 3.0 * np.linalg.norm(v[1] - v[0]) / h * 3


def test_triangle_on_cell_faces_claims_cells():
    """A triangle lying exactly on a grid plane still gets particles, covering all of it."""
    h = 0.1
    v = np.array([[0.0, 0.3, 0.0], [1.0, 0.3, 0.0], [0.0, 0.3, 1.0]])
    xb = sample_mesh(v, np.array([[0, 1, 2]]), h)
    assert np.all(np.abs(xb[:, 1] - 0.3) <= 0.05 + 1e-6)
    d, _ = cKDTree(xb).query(_points_on_triangle(v, 20_000, np.random.default_rng(1)))
    assert d.max() <= 0.5 * np.sqrt(3) * h + 1e-6


def test_large_mesh_samples_in_seconds():
    mesh = trimesh.creation.icosphere(subdivisions=6, radius=1.0)  # 81,920 triangles
    mesh = trimesh.util.concatenate([mesh, trimesh.creation.icosphere(subdivisions=5, radius=0.5)])
    assert len(mesh.faces) > 100_000
    sample_mesh(mesh.vertices, mesh.faces[:1], 0.1)  # compile outside the timing
    t = time.perf_counter()
    xb = sample_mesh(mesh.vertices, mesh.faces, 0.02)
    seconds = time.perf_counter() - t
    assert seconds < 10.0
    r = np.linalg.norm(xb, axis=1)
    outer = r > 0.75
    assert np.all(np.abs(r[outer] - 1.0) < 0.02)  # cell centres within a half diagonal of the sphere


def test_bad_mesh_arrays_are_refused():
    """Indices past the vertex array or non-finite vertices would make the kernel read out of
    bounds or loop over a near-infinite cell range: refused before any launch."""
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    with pytest.raises(ValueError, match="face indices"):
        sample_mesh(v, np.array([[0, 1, 3]]), 0.1)
    with pytest.raises(ValueError, match="non-finite"):
        sample_mesh(np.where(np.arange(9).reshape(3, 3) == 4, np.nan, v), np.array([[0, 1, 2]]), 0.1)


def test_clear_fluid_removes_inside_and_near():
    box = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    h = 0.02
    xb = sample_mesh(box.vertices, box.faces, h)
    g = np.arange(-0.39, 0.4, h)
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    kept = clear_fluid(x, xb, [(box.vertices, box.faces)], h)
    assert np.all(np.max(np.abs(kept), axis=1) > 0.2)  # nothing inside
    assert cKDTree(xb).query(kept)[0].min() >= 0.999 * h
    # as a container, the same box keeps only what is inside
    kept_in = clear_fluid(x, xb, [], h, containers=[(box.vertices, box.faces)])
    assert np.all(np.max(np.abs(kept_in), axis=1) < 0.2) and len(kept_in) > 0


def test_water_poured_on_a_mesh_box_stays_out_of_it(tmp_path):
    """A block of water falls onto a box obstacle given as an OBJ file: after 1 s nothing has
    entered the box and the water is at rest density on average."""
    path = tmp_path / "block.obj"
    trimesh.creation.box(extents=[0.3, 0.2, 0.3]).export(path)
    scene = Scene(spacing=0.02, tank=Box((0, 0, 0), (0.6, 0.8, 0.3)))
    scene.add_fluid_box((0.1, 0.35, 0.05), (0.5, 0.65, 0.25))
    scene.add_obstacle(MeshShape(path="block.obj", translate=(0.3, 0.1, 0.15), base_dir=str(tmp_path)))
    sim = Simulation(scene, "cpu")
    sim.advance(1.0)
    x = sim.positions
    inside = np.all((x > [0.15, 0.0, 0.0]) & (x < [0.45, 0.2, 0.3]), axis=1)
    assert inside.sum() == 0
    assert all(s["escaped"] == 0 for s in sim.stats)
    assert np.mean([s["compression"] for s in sim.stats[-50:]]) < 0.01
    # some water sits on top of the box
    assert np.any((x[:, 1] > 0.2) & (x[:, 1] < 0.3) & (np.abs(x[:, 0] - 0.3) < 0.1))
