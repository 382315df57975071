"""Triangle meshes as boundary particles: coverage, obstacles that hold water out, speed."""

import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from warp_iisph import Simulation
from warp_iisph.scene import Box, MeshShape, Scene
from warp_iisph.setup.rasterize import CLEAR, fluid_room, sample_mesh


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


def test_fluid_room_leaves_out_inside_and_near():
    box = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    h = 0.02
    xb = sample_mesh(box.vertices, box.faces, h)
    g = np.arange(-0.39, 0.4, h)
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    kept = x[fluid_room(x, xb, [(box.vertices, box.faces)], h) == CLEAR]
    assert np.all(np.max(np.abs(kept), axis=1) > 0.2)  # nothing inside
    assert cKDTree(xb).query(kept)[0].min() >= 0.999 * h
    # as a container, the same box keeps only what is inside
    kept_in = x[fluid_room(x, xb, [], h, containers=[(box.vertices, box.faces)]) == CLEAR]
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


def test_a_closed_surface_is_sampled_in_two_layers_behind_it_wherever_it_meets_the_grid():
    """A closed mesh's particles lie h/2 and h behind its surface on the solid's side (inside an
    obstacle, outside a container), as a box tank's walls do, whether its faces lie on planes of
    the grid or between them: the cell centres lay up to h/2 either side of a face (a box obstacle
    sampled h too wide on its high faces, a container's floor at y = 0 inside the liquid). A
    container's lattice of liquid then fills it to its faces, as a box tank's does, and a
    cylinder half full of water stands as high as its particles' volume says."""
    import trimesh

    from warp_iisph import load_scene
    from warp_iisph.setup import build_model
    from warp_iisph.setup.rasterize import surface_layers

    h = 0.0125
    for shift in (0.0, 0.3 * h, -0.45 * h):
        lo, hi = np.array([0.4, 0.1, 0.2]) + shift, np.array([0.5, 0.2, 0.3]) + shift
        box = trimesh.creation.box(bounds=[lo, hi])
        for sign in (1.0, -1.0):
            x, depth = surface_layers(box.vertices, box.faces, h, "cpu", sign)
            outside = np.maximum(lo - x, 0.0) + np.maximum(x - hi, 0.0)
            inside = np.minimum(x - lo, hi - x).min(axis=1)
            behind = np.linalg.norm(outside, axis=1) if sign < 0 else inside
            assert np.all((behind > 0.5 * h - 1e-6) & (behind < h * np.sqrt(2) + 1e-6)), (shift, sign)
            np.testing.assert_allclose(depth, behind, atol=1e-6)  # the depth kept is the distance
            # beside one face only (more than 1.5 h from the others' planes), the faces' two layers
            planes = np.sort(np.abs(np.concatenate([x - lo, hi - x], axis=1)), axis=1)
            one_face = planes[:, 1] > 1.5 * h
            assert set(np.round(depth[one_face] / h, 6)) == {0.5, 1.0}, (shift, sign)
            if sign > 0:  # inside: centred in the box, every face's layers at h/2 and h
                np.testing.assert_allclose(x.min(axis=0) + x.max(axis=0), lo + hi, atol=1e-6)
                np.testing.assert_allclose(x.min(axis=0), lo + 0.5 * h, atol=1e-6)
    # a box tank given as a mesh, its floor at y = 0: filled to its faces as the box tank is
    folder = Path(tempfile.mkdtemp())
    trimesh.creation.box(bounds=[[0.0, 0.0, 0.0], [0.2, 0.2, 0.1]]).export(folder / "tank.obj")
    scene = Scene(spacing=h, tank=MeshShape("tank.obj", base_dir=str(folder)), name="aligned")
    scene.add_fluid_box((0.0, 0.0, 0.0), (0.2, 0.1, 0.1))
    model, state = build_model(scene, "cpu")
    xb, x = model.boundary_x.numpy(), state.x.numpy()[: state.n]
    under = (np.abs(xb[:, 0] - 0.1) < 0.05) & (np.abs(xb[:, 2] - 0.05) < 0.03) & (xb[:, 1] < 0.0)
    assert set(np.round(xb[under, 1] / h, 5)) == {-0.5, -1.0} and np.isclose(xb[:, 1].min(), -h)
    # the lattice, to the walls (but along the container's edges, where its weights read 1.2 % over
    # rho0 and the build leaves such liquid out; a box tank's edges read 0.6 % under)
    away = np.min(np.stack([x[:, 0], 0.2 - x[:, 0], x[:, 2], 0.1 - x[:, 2]]), axis=0)
    assert np.isclose(x[:, 1].min(), 0.5 * h) and np.sum(away > h) == 14 * 6 * 8 and state.n > 0.9 * 16 * 8 * 8
    # a cylinder of 0.1 m radius (32 sides) half full, at rest after 0.6 s: its level over the height
    # its particles fill (their count h^3 over its floor's area) within 5 % (25-42 % with the cells)
    cylinder = trimesh.creation.cylinder(radius=0.1, height=0.25, sections=32)
    cylinder.apply_translation((0.0, 0.0, 0.125))
    cylinder.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    cylinder.export(folder / "cylinder.obj")
    (folder / "cylinder.toml").write_text(
        'spacing = 0.01\n[tank]\nshape = "mesh"\npath = "cylinder.obj"\n'
        "[[fluids]]\nlower = [-0.1, 0.0, -0.1]\nupper = [0.1, 0.1, 0.1]\n"
        '[[probes]]\nname = "level"\nkind = "level"\nposition = [0.0, 0.0]\n'
    )
    sim = Simulation(load_scene(str(folder / "cylinder.toml")), "cpu")
    sim.advance(0.6)
    area = 0.5 * 32 * 0.1**2 * np.sin(2 * np.pi / 32)
    assert sim.probes["level"][-20:].mean() == pytest.approx(sim.n_particles * 1e-6 / area, rel=0.05)


def test_a_sliver_face_is_sampled_as_its_neighbours_cover_it():
    """A closed mesh with a face of next to no area (a CAD tessellation's sliver: here the box's
    top as a fan round a vertex on one of its edges) samples as the plain box does; trimesh's
    normals leave such a face out, which once shifted every later face's normal (an internal
    error building a mesh tank)."""
    from warp_iisph.setup.rasterize import surface_layers

    L, h = 0.3, 0.03
    v = np.array([[0, 0, 0], [L, 0, 0], [L, 0, L], [0, 0, L], [0, L, 0], [L, L, 0], [L, L, L], [0, L, L]], float)
    sides = [[0, 4, 5], [0, 5, 1], [1, 5, 6], [1, 6, 2], [2, 6, 7], [2, 7, 3], [3, 7, 4], [3, 4, 0]]
    plain = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7], *sides], process=False)
    fan = [[4, 8, 5], [5, 8, 6], [6, 8, 7], [7, 8, 4]]
    sliver = trimesh.Trimesh(np.vstack([v, [L / 2, L, 0.0]]), [[0, 1, 2], [0, 2, 3], *fan, *sides], process=False)
    assert sliver.is_watertight and not trimesh.triangles.normals(sliver.triangles)[1].all()
    for sign in (1.0, -1.0):
        for m in (plain, sliver):
            trimesh.repair.fix_normals(m)
        a, b = (surface_layers(m.vertices, m.faces, h, "cpu", sign)[0] for m in (plain, sliver))
        assert len(a) == len(b) and np.allclose(np.sort(a, axis=0), np.sort(b, axis=0), atol=1e-6)


def test_a_box_thinner_than_three_spacings_is_sampled_as_a_closed_mesh_and_kept_out_of():
    """A plate half a spacing thick (a box obstacle's default sampling, by faces, needs 3 spacings):
    one layer at its middle, and a particle a tenth of a spacing into it put back onto its surface
    (where a solid is thinner than a spacing its layers meet at its middle, and a last line h/2
    inside it, as for a thick box, would lie past that middle: nothing would stop a particle
    crossing)."""
    import warp as wp

    from warp_iisph.sph.neighbors import NeighborListBuffer

    h = 0.02
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (0.6, 0.3, 0.3)), name="plate")
    scene.add_fluid_box((0.0, 0.0, 0.0), (0.1, 0.1, 0.3))
    scene.add_obstacle(Box((0.2, 0.1, 0.05), (0.4, 0.11, 0.25)))
    sim = Simulation(scene, "cpu")
    model = sim.model
    xb = model.boundary_x.numpy()[model.boundary_owner.numpy() == 0]
    assert len(xb) > 0.8 * (0.2 / h) ** 2 and np.allclose(xb[:, 1], 0.105, atol=1e-6)
    walls = model.containment
    near = NeighborListBuffer(1, "cpu", capacity=1)
    near.lists.count.fill_(1)
    x = wp.array([[0.3, 0.11 - 0.1 * h, 0.15]], dtype=wp.vec3, device="cpu")
    v = wp.array([[0.0, -1.0, 0.0]], dtype=wp.vec3, device="cpu")
    walls.apply(x, v, near.lists, 1, wp.array([1e-3], dtype=wp.float64, device="cpu"))
    assert walls.corrections.numpy()[1] == 1 and 0.11 < x.numpy()[0, 1] < 0.11 + 0.01 * h
    assert abs(v.numpy()[0, 1]) < 1e-6


def test_a_curved_container_that_leaves_the_liquid_short_is_warned_of(tmp_path):
    """The lattice does not lie along a curved container's wall, so the sites closer than a spacing
    to its particles (about h/2 of the wall) are left out: a 0.15 m cylinder filled 0.15 m deep at
    2 cm keeps 86 % of its lattice sites in it, and the set-up says so; a box given as a mesh, its
    faces on the lattice's planes, keeps them all and says nothing."""
    from warp_iisph.setup import build_model

    cylinder = trimesh.creation.cylinder(radius=0.15, height=0.4, sections=24)
    cylinder.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    cylinder.apply_translation((0.2, 0.2, 0.2))
    cylinder.export(tmp_path / "cylinder.obj")
    trimesh.creation.box(bounds=[[0.0, 0.0, 0.0], [0.3, 0.4, 0.3]]).export(tmp_path / "box.obj")
    notes = {}
    blocks = {"cylinder": ((0.05, 0.0, 0.05), (0.35, 0.15, 0.35)), "box": ((0, 0, 0), (0.3, 0.15, 0.3))}
    for name, (lower, upper) in blocks.items():
        scene = Scene(spacing=0.02, tank=MeshShape(f"{name}.obj", base_dir=str(tmp_path)), name=name)
        scene.add_fluid_box(lower, upper)
        notes[name] = build_model(scene, "cpu")[0].setup_warnings
    (warning,) = notes["cylinder"]
    assert warning.startswith("tank: the liquid starts with 1071 of the 1239 lattice sites") and "(86 %)" in warning
    assert notes["box"] == []
