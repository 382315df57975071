"""Surface reconstruction: a ball of particles gives a closed, outward, right-sized mesh;
smoothing keeps volume; edge cases; the OBJ sequence of a run."""

import numpy as np
import pytest
import trimesh
import warp as wp

from warp_iisph.cli import main
from warp_iisph.run.formats import write_obj
from warp_iisph.scene import Box, Sphere
from warp_iisph.scene import SurfaceSettings as Surface
from warp_iisph.setup.sampling import sample_box, sample_sphere
from warp_iisph.surface import SurfaceReconstructor, blocks, splat
from warp_iisph.surface import field as surface

H = 0.02
CENTRE = np.array([0.1, 0.2, 0.3])


@pytest.fixture(scope="module")
def ball():
    return sample_sphere(Sphere(tuple(CENTRE), 0.2), H)


def _mesh(x, **params):
    m = SurfaceReconstructor(H, Surface(**params)).reconstruct(x)
    return m, trimesh.Trimesh(m.vertices, m.faces, process=False)


def test_ball_is_closed_outward_and_right_sized(ball):
    m, t = _mesh(ball, smoothing="none")
    assert t.is_watertight and t.is_winding_consistent
    assert t.volume > 0  # outward winding gives a positive volume
    r = np.linalg.norm(m.vertices - CENTRE, axis=1)
    assert abs(r.mean() - 0.2) < 0.5 * H  # within one grid cell (h/2)
    assert abs(t.volume / (len(ball) * H**3) - 1.0) < 0.05
    # normals point away from the centre
    assert np.mean(np.einsum("ij,ij->i", m.normals, m.vertices - CENTRE) > 0) > 0.999


def test_smoothing_keeps_volume(ball):
    v0 = _mesh(ball, smoothing="none")[1].volume
    lap = _mesh(ball, smoothing="laplacian", passes=3)[1]
    tau = _mesh(ball, smoothing="taubin", passes=3)[1]
    assert lap.is_watertight and tau.is_watertight
    assert 0.0 < 1.0 - lap.volume / v0 < 0.01  # Laplacian shrinks, by less than 1 %
    assert abs(1.0 - tau.volume / v0) < 0.002  # Taubin does not


def test_smoothing_smooths(ball):
    """Smoothing lowers the angles between neighbouring triangles (the marching-cubes facets)."""
    raw = _mesh(ball, smoothing="none")[1].face_adjacency_angles.mean()
    lap = _mesh(ball, smoothing="laplacian")[1].face_adjacency_angles.mean()
    tau = _mesh(ball, smoothing="taubin")[1].face_adjacency_angles.mean()
    assert lap < 0.75 * raw and tau < 0.95 * raw, (raw, lap, tau)  # measured: 0.65 and 0.89


def test_feature_weights_keep_lone_droplets():
    """Feature-weighted smoothing leaves a lone particle's blob nearly as it was (weight ~0: no
    particle near it) where plain Laplacian smoothing shrinks it to a fraction, and smooths the
    bulk ball as plain smoothing does (weight 1 there)."""
    ball = sample_sphere(Sphere(tuple(CENTRE), 0.12), H)
    ball = ball + np.random.default_rng(0).normal(0.0, 0.1 * H, ball.shape)
    x = np.concatenate([ball, [[0.5, 0.2, 0.3]]]).astype(np.float32)

    def bodies(**params):
        t = _mesh(x, **params)[1]
        return sorted(abs(c.volume) for c in t.split(only_watertight=False))

    raw, plain, weighted = bodies(smoothing="none"), bodies(feature_weights=False), bodies(feature_weights=True)
    assert len(raw) == len(plain) == len(weighted) == 2
    assert weighted[0] > 0.9 * raw[0] and plain[0] < 0.5 * raw[0], (raw[0], plain[0], weighted[0])
    assert abs(weighted[1] / plain[1] - 1.0) < 5e-4 and plain[1] < raw[1]


def test_feature_weights_are_the_interpolated_coarse_counts():
    """The weight kernel against NumPy: trilinear interpolation of the particles per coarse cell
    (cell centres at (i + 1/2) R from the field's lower corner), over a quarter of (R/h)^3,
    through the smoothstep."""
    from warp_iisph.surface.smoothing import vertex_weights

    x = _jittered_ball(0.1)
    r = SurfaceReconstructor(H, Surface(smoothing="none"))
    field = r.distance_field(x)
    verts, _ = r.marching_cubes(field)
    got = vertex_weights(verts, field, H, "cpu").numpy()
    dims = np.array(field.coarse_dims)
    counts = np.diff(field.coarse_start.numpy()).reshape(dims)
    assert counts.sum() == len(x)
    q = (verts.numpy().astype(np.float64) - field.lower) / field.coarse_cell - 0.5
    i0 = np.floor(q).astype(int)
    f = q - i0
    n = np.zeros(len(q))
    for corner in np.ndindex(2, 2, 2):
        idx = np.clip(i0 + corner, 0, dims - 1)
        w = np.prod(np.where(np.array(corner) == 1, f, 1.0 - f), axis=1)
        n += w * counts[idx[:, 0], idx[:, 1], idx[:, 2]]
    t = np.minimum(1.0, n / (0.25 * (field.coarse_cell / H) ** 3))
    want = t**3 * (t * (6.0 * t - 15.0) + 10.0)
    assert np.abs(got - want).max() < 1e-5 and 0.0 < got.min() and got.max() == 1.0


def test_no_particles_gives_an_empty_mesh():
    m = SurfaceReconstructor(H).reconstruct(np.zeros((0, 3)))
    assert m.vertices.shape == (0, 3) and m.faces.shape == (0, 3)


def test_one_particle_gives_a_small_closed_blob():
    m, t = _mesh(np.array([[0.0, 0.0, 0.0]]))
    assert len(m.faces) > 0 and t.is_watertight and t.volume > 0
    assert np.linalg.norm(m.vertices, axis=1).max() < 2 * H


def test_flat_sheet_gives_a_thin_closed_slab():
    x = sample_box(Box((0, 0, 0), (0.4, H, 0.4)), H)  # one layer of particles
    m, t = _mesh(x)
    assert t.is_watertight and t.volume > 0
    assert np.ptp(m.vertices[:, 1]) < 3 * H


def test_nan_frame_is_a_clear_error(ball):
    x = ball.copy()
    x[5, 1] = np.nan
    with pytest.raises(ValueError, match="1 particles have non-finite positions"):
        SurfaceReconstructor(H).reconstruct(x)


def test_a_particle_far_off_is_a_clear_error_and_the_preview_leaves_it_out(ball):
    """One particle 1e30 m off: the grid over the particles is refused by its size before any
    index is cast (a cast of inf to int64 made an internal error), and the preview draws the
    others (NumPy warned of invalid casts on stderr)."""
    import warnings

    from warp_iisph.view.preview import OrthoView, splat

    x = ball.copy()
    x[5, 0] = 1e30
    with pytest.raises(ValueError, match=r"extent \[1e\+30, .*\] m is too large for cells"):
        SurfaceReconstructor(H).reconstruct(x)
    x[6, 1] = np.nan
    view = OrthoView(x[7:].min(0), x[7:].max(0), 32, 32, 30.0, 20.0)
    image, depth = np.zeros((32, 32, 3)), np.full((32, 32), -np.inf)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        splat(image, depth, view, x, np.ones((len(x), 3)), H)
    assert np.isfinite(depth).sum() > 10


def test_obj_round_trip(tmp_path, ball):
    m, t = _mesh(ball)
    write_obj(tmp_path / "a.obj", m.vertices, m.faces, m.normals)
    back = trimesh.load(tmp_path / "a.obj", process=False)
    assert len(back.faces) == len(m.faces)
    assert np.allclose(back.vertices, m.vertices, atol=1e-5)


def test_ply_round_trip(tmp_path, ball):
    """Binary PLY: meshio and trimesh read back the same vertices, normals and faces."""
    import meshio

    from warp_iisph.run.formats import write_mesh

    m, t = _mesh(ball)
    path = write_mesh(tmp_path / "a.obj", m.vertices, m.faces, m.normals, "ply")
    assert path == tmp_path / "a.ply" and not (tmp_path / "a.obj").exists()
    back = meshio.read(path)
    assert np.array_equal(back.points, m.vertices) and np.array_equal(back.cells_dict["triangle"], m.faces)
    assert np.array_equal(np.stack([back.point_data[k] for k in ("nx", "ny", "nz")], 1), m.normals)
    tm = trimesh.load(path, process=False)
    assert tm.is_watertight and np.isclose(tm.volume, t.volume)
    with pytest.raises(ValueError, match="outside 0.."):
        write_mesh(tmp_path / "b.ply", m.vertices, m.faces + len(m.vertices), None, "ply")
    with pytest.raises(ValueError, match="surface.format = 'stl'"):
        Surface(format="stl").validate()


def test_frame_mesher_writes_the_chosen_format(tmp_path, ball):
    from warp_iisph.run.meshing import FrameMesher

    for fmt in ("obj", "ply"):
        mesher = FrameMesher(H, Surface(format=fmt))
        mesher.write(ball, tmp_path / "frame_00000.obj")
        assert (tmp_path / f"frame_00000.{fmt}").is_file()
        assert trimesh.load(tmp_path / f"frame_00000.{fmt}", process=False).is_watertight


def test_obj_text_is_printf_formatting(tmp_path):
    """The kernel-formatted OBJ says what printf's %.6f / %.4f / %d say (up to padding)."""
    from warp_iisph.run.obj_text import obj_bytes

    rng = np.random.default_rng(0)
    v = rng.normal(0.0, 2.0, (500, 3)).astype(np.float32)
    v[0] = (0.0, 12.5, -3.0000001)
    v[1] = (-0.4e-6, 1234.5678, 7e-7)
    n = rng.normal(0.0, 1.0, (500, 3))
    n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
    f = rng.integers(0, 500, (900, 3)).astype(np.int32)
    f[0] = (0, 9, 499)  # one- to three-digit indices
    ref = ["# warp_iisph surface: 500 vertices, 900 triangles"]
    ref += ["v %.6f %.6f %.6f" % tuple(map(float, r)) for r in v] + [
        "vn %.4f %.4f %.4f" % tuple(map(float, r)) for r in n
    ]
    plain = ref[:501] + ["f %d %d %d" % tuple(r + 1) for r in f]
    ref += ["f %d//%d %d//%d %d//%d" % tuple(np.repeat(r + 1, 2)) for r in f]
    assert [" ".join(s.split()) for s in obj_bytes(v, f, n).decode().splitlines()] == ref
    assert [" ".join(s.split()) for s in obj_bytes(v, f).decode().splitlines()] == plain
    assert obj_bytes(np.zeros((0, 3)), np.zeros((0, 3))).decode() == "# warp_iisph surface: 0 vertices, 0 triangles\n"
    with pytest.raises(ValueError, match="outside 0..499"):
        obj_bytes(v, f + 1)


def test_run_with_mesh_and_mesh_command(tmp_path, capsys):
    out = tmp_path / "run"
    assert (
        main(
            [
                "run",
                "martin_moyce",
                "--spacing",
                "0.04",
                "--duration",
                "0.1",
                "--fps",
                "20",
                "--out",
                str(out),
                "--mesh",
                "--no-progress",
            ]
        )
        == 0
    )
    objs = sorted((out / "mesh").glob("frame_*.obj"))
    assert [o.name for o in objs] == [f"frame_{k:05d}.obj" for k in range(3)]
    first = trimesh.load(objs[0])
    assert first.is_watertight and first.volume > 0
    import json

    stages = json.loads((out / "run.json").read_text())["stage_seconds"]
    assert {"distance_field", "marching_cubes", "smoothing", "export"} <= set(stages)
    # re-meshing an existing run with other settings
    assert main(["mesh", str(out), "--smoothing", "taubin", "--overwrite", "--no-progress"]) == 0
    assert "meshed 3 frames" in capsys.readouterr().out
    # another format is other settings: refused, then replaced with --overwrite (no mix of both)
    assert main(["mesh", str(out), "--format", "ply", "--no-progress"]) == 2
    assert "holds meshes made from other settings; pass --overwrite" in capsys.readouterr().err
    assert main(["mesh", str(out), "--format", "ply", "--overwrite", "--no-progress"]) == 0
    assert "meshed 3 frames (0 already there)" in capsys.readouterr().out
    assert not list((out / "mesh").glob("*.obj"))
    assert trimesh.load(out / "mesh" / "frame_00000.ply").is_watertight
    # the viewers find the PLY meshes
    from warp_iisph.run.folder import MESHES, RunFolder

    run = RunFolder(out)
    assert run.mesh_format == "ply" and [f.suffix for f in run.frames(MESHES)] == [".ply"] * 3
    assert (
        main(
            [
                "preview",
                str(out),
                "--source",
                "mesh",
                "--frames",
                "2:",
                "--out",
                str(tmp_path / "still.png"),
                "--no-progress",
            ]
        )
        == 0
    )
    assert (tmp_path / "still.png").stat().st_size > 0
    assert main(["mesh", str(tmp_path / "nothing"), "--no-progress"]) == 2
    assert "no such run folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["mesh", str(tmp_path / "empty"), "--no-progress"]) == 2
    assert "empty: not a warp-iisph run (no run.json); pass --spacing" in capsys.readouterr().err


def test_cuda_mesh_matches_cpu(ball):
    import warp as wp

    if not wp.is_cuda_available():
        pytest.skip("no CUDA device on this machine")
    a = SurfaceReconstructor(H, device="cpu").reconstruct(ball)
    b = SurfaceReconstructor(H, device="cuda:0").reconstruct(ball)
    ta, tb = (trimesh.Trimesh(m.vertices, m.faces) for m in (a, b))
    assert abs(ta.volume - tb.volume) < 1e-3 * ta.volume
    assert abs(len(a.faces) - len(b.faces)) <= 0.01 * len(a.faces)


def _jittered_ball(radius=0.12, seed=0):
    x = sample_sphere(Sphere(tuple(CENTRE), radius), H)
    return (x + np.random.default_rng(seed).normal(0.0, 0.1 * H, x.shape)).astype(np.float32)


@pytest.mark.parametrize("deep", [False, True])
def test_block_marching_cubes_equals_warps_dense_marching_cubes(deep):
    """Same vertices and triangles as warp.geometry's marching cubes on the densified field, for
    a ball and a slab whose surface crosses many block faces (positions agree to float rounding:
    warp derives its cell from the corners); and for a pool deep enough for FULL blocks, whose
    unstored cells must not cross."""
    import warp as wp
    import warp.geometry

    top = -0.4 if deep else -0.1
    slab = sample_box(Box((-0.2, top, 0.0), (0.4, 0.0, 0.3)), H)
    x = np.concatenate([_jittered_ball(), slab + np.random.default_rng(1).normal(0.0, 0.1 * H, slab.shape)])
    r = SurfaceReconstructor(H, Surface(smoothing="none"))
    field = r.distance_field(x)
    assert 0 < field.n_stored < np.prod(field.block_dims)
    assert (field.device.kind.numpy() == blocks.FULL).sum() > (0 if deep else -1)
    verts, indices = (a.numpy() for a in r.marching_cubes(field))
    dense = field.dense()
    upper = field.lower + field.cell * (np.array(dense.shape) - 1)
    ref_v, ref_i = warp.geometry.IsoSurfaceMarchingCubes.extract(
        wp.array(dense, dtype=float), 0.0, lower=wp.vec3(*field.lower.tolist()), upper=wp.vec3(*upper.tolist())
    )
    ref_v, ref_i = ref_v.numpy(), ref_i.numpy()
    assert len(verts) == len(ref_v) and len(indices) == len(ref_i)

    inside = dense >= 0.0
    crossed = sum(int((np.diff(inside, axis=a) != 0).sum()) for a in range(3))
    assert len(verts) == crossed  # welded: one vertex per crossed lattice edge
    # the same vertex on each edge: a one-to-one nearest match, within float rounding
    from scipy.spatial import cKDTree

    dist, match = cKDTree(ref_v).query(verts)
    assert dist.max() < 1e-4 * field.cell
    assert len(np.unique(match)) == len(verts)
    # and the same triangles between them
    ours = np.sort(match[indices.reshape(-1, 3)], axis=1)
    ref = np.sort(ref_i.reshape(-1, 3), axis=1)
    assert np.array_equal(ours[np.lexsort(ours.T)], ref[np.lexsort(ref.T)])


@pytest.mark.parametrize("settings", [{}, {"cell": 0.3, "radius": 2.5}])
def test_field_equals_zhu_bridson_at_stored_nodes(settings):
    """The stored nodes hold Zhu & Bridson's distance, computed here by brute force; EMPTY blocks
    have no particle within R and FULL blocks lie inside the liquid. The second settings put the
    2x2x2 node cubes of ``signed_distance`` across coarse cells (each node tests its own)."""
    x = _jittered_ball(0.1)
    p = Surface(**settings)
    R, r0 = p.radius * H, p.r0 * H
    field = SurfaceReconstructor(H, p).distance_field(x)
    dense = field.dense()
    nodes = field.lower + field.cell * np.stack(np.meshgrid(*[np.arange(n) for n in dense.shape], indexing="ij"), -1)
    nodes = nodes.reshape(-1, 3)
    d2 = ((nodes[:, None, :] - x[None, :, :].astype(np.float64)) ** 2).sum(-1) / R**2
    w = np.clip(1.0 - d2, 0.0, None) ** 3
    wsum = w.sum(1)
    near = wsum > 0
    xbar = (w[near] @ x) / wsum[near, None]
    exact = np.full(len(nodes), R)
    exact[near] = np.linalg.norm(nodes[near] - xbar, axis=1) - r0
    got = dense.reshape(-1)
    shortcut = (got == np.float32(R)) | (got == np.float32(-r0))
    assert (~shortcut).sum() > 1000
    assert np.abs(got[~shortcut] - exact[~shortcut]).max() < 1e-5
    assert np.all(exact[got == np.float32(R)] >= R - 1e-6)  # "outside" only where no particle is within R
    assert np.all(exact[got == np.float32(-r0)] < 0.0)  # "deep inside" is inside


def test_storage_follows_the_surface_not_the_box():
    """A thin wide sheet with a drop high above it (a dam break spread over the tank floor, one
    splash in the air) stores a small part of its bounding box's lattice."""
    sheet = sample_box(Box((0.0, 0.0, 0.0), (1.2, 0.06, 0.6)), H)
    x = np.concatenate([sheet, sample_sphere(Sphere((0.6, 0.8, 0.3), 0.05), H)])
    r = SurfaceReconstructor(H, Surface(smoothing="none"))
    field = r.distance_field(x)
    stored = field.n_stored * 8**3
    assert stored < 0.25 * np.prod(field.node_dims), (stored, np.prod(field.node_dims))  # measured: 0.19
    t = trimesh.Trimesh(*(a.numpy().reshape(-1, 3) for a in r.marching_cubes(field)), process=False)
    assert t.is_watertight and t.body_count == 2
    assert abs(abs(t.volume) / (len(x) * H**3) - 1.0) < 0.1


def test_exclusive_scan_and_total():
    from warp_iisph.surface.field import exclusive_scan as _exclusive_scan

    flags = np.random.default_rng(1).integers(0, 4, 10_001).astype(np.int32)
    start, total = _exclusive_scan(wp.array(flags, dtype=wp.int32, device="cpu"))
    assert total == flags.sum() and np.array_equal(start.numpy(), np.cumsum(flags) - flags)
    start, total = _exclusive_scan(wp.zeros(0, dtype=wp.int32, device="cpu"))
    assert total == 0 and start.shape[0] == 0


@wp.kernel
def per_node_signed_distance(
    f: blocks.BlockField,
    grid: wp.uint64,
    x: wp.array(dtype=wp.vec3),
    R: float,
    r0: float,
    counts: wp.array(dtype=wp.int32),
    cdims: wp.vec3i,
    full: int,
    phi: wp.array(dtype=float),
):
    """The plain definition: one node per thread, its own narrow-band test and grid query."""
    n = wp.tid()
    p = blocks.node_position(f, blocks.block_coords(f, n // blocks.CELLS3), blocks.local_node(n % blocks.CELLS3))
    c = blocks._coarse_index(p, f.lower, R, cdims)
    kind = blocks.coarse_kind(counts, cdims, c, c, full)
    phi[n] = R
    if kind == blocks.FULL:
        phi[n] = -r0
    elif kind == blocks.SURFACE:
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


def _splat_field(settings: dict, seed: int, monkeypatch):
    """A ball and a jittered pool deep enough for FULL nodes, its distance field with
    ``settings``, and the inputs splat_blocks was launched with (caught by a spy)."""
    launched = {}
    plain = surface.launch_particles

    def spy(kernel, n, inputs, device, **kw):
        if kernel is splat.splat_blocks:
            launched["inputs"] = inputs
        return plain(kernel, n, inputs, device, **kw)

    monkeypatch.setattr(surface, "launch_particles", spy)
    pool = sample_box(Box((-0.1, -0.3, 0.1), (0.3, 0.0, 0.5)), H)
    x = np.concatenate([_jittered_ball(0.1), pool + np.random.default_rng(seed).normal(0, 0.1 * H, pool.shape)]).astype(
        np.float32
    )
    field = SurfaceReconstructor(H, Surface(**settings)).distance_field(x)
    return x, field, launched["inputs"]


@pytest.mark.parametrize("settings", [{}, {"cell": 0.3, "radius": 2.5}])
def test_splat_equals_the_per_node_field(settings, monkeypatch):
    """splat_blocks (each block's nearby particles splatted onto its nodes, a row of 8 at a
    time) gives the one-node-per-thread gather of the definition to float rounding: exactly R
    where that gather's narrow-band test finds no particle near, inside where it says "deep
    inside", the same sums elsewhere. The second settings put blocks across coarse cells."""
    x, field, (_, f, _, start, cd, R, r0, _) = _splat_field(settings, 1, monkeypatch)
    counts = wp.array(np.diff(start.numpy()).astype(np.int32), dtype=wp.int32)  # particles per coarse cell
    xd = wp.array(x, dtype=wp.vec3)
    grid = wp.HashGrid(128, 128, 128, device="cpu")
    grid.build(xd, R)
    reference = wp.empty_like(f.phi)
    full = max(1, int(0.75 * (R / H) ** 3))
    wp.launch(
        per_node_signed_distance, dim=reference.shape[0], inputs=[f, grid.id, xd, R, r0, counts, cd, full, reference]
    )
    got, want = f.phi.numpy(), reference.numpy()
    outside, deep = want == np.float32(R), want == np.float32(-r0)
    summed = ~outside & ~deep
    # every path is exercised: outside, deep inside, summed
    assert field.n_stored > 50 and outside.sum() > 1000 and deep.sum() > 1000 and summed.sum() > 1000
    assert np.array_equal(got[outside], want[outside])
    assert np.all(got[deep] < 0.0)
    assert np.abs(got[summed] - want[summed]).max() < 2e-6  # float32 rounding of sums of positions of size ~0.5


def test_bounds_and_non_finite_count_on_the_device(ball):
    """A device frame's bounding box and non-finite check need no copy of its positions."""
    from warp_iisph.surface.field import particle_box as _bounds

    x = ball.astype(np.float32).copy()
    lo, hi, bad = _bounds(wp.array(x, dtype=wp.vec3, device="cpu"))
    assert bad == 0 and np.array_equal(lo, x.min(0)) and np.array_equal(hi, x.max(0))
    x[3, 0], x[7, 2] = np.nan, np.inf
    lo, hi, bad = _bounds(wp.array(x, dtype=wp.vec3, device="cpu"))
    finite = np.isfinite(x).all(1)
    assert bad == 2 and np.array_equal(lo, x[finite].min(0)) and np.array_equal(hi, x[finite].max(0))
    with pytest.raises(ValueError, match="2 particles have non-finite positions"):
        SurfaceReconstructor(H).reconstruct(wp.array(x, dtype=wp.vec3, device="cpu"))


@pytest.mark.parametrize("settings", [{}, {"cell": 0.3, "radius": 2.5}])
def test_gpu_row_gather_equals_the_splat(settings, monkeypatch):
    """gather_rows (CUDA's field kernel: a thread per row of 8 nodes gathers the particles whose
    ball reaches it) gives bitwise the field splat_blocks (the CPU's) gives: the same terms in
    the same order. Run here on the CPU, so a GPU is not needed to check it."""
    _, field, (_, f, xs, start, cd, R, r0, _) = _splat_field(settings, 2, monkeypatch)
    splatted = f.phi.numpy().copy()
    f.phi.fill_(np.nan)
    wp.launch(splat.gather_rows, dim=field.n_stored * splat.ROWS, inputs=[0, f, xs, start, cd, R, r0], device="cpu")
    gathered = f.phi.numpy()
    assert field.n_stored > 50 and np.isfinite(gathered).all()
    assert np.array_equal(gathered.view(np.int32), splatted.view(np.int32))
