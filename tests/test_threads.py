"""Per-particle kernels split over CPU threads give bitwise the results of one launch."""

import numpy as np
import pytest
import warp as wp

import warp_iisph.engine.launch as launch
from warp_iisph import Simulation, scenes
from warp_iisph.scene import load_scene

# modules that launch per-particle kernels through the helper
USERS = [
    "warp_iisph.setup.model",
    "warp_iisph.setup.boundary",
    "warp_iisph.sph.grid",
    "warp_iisph.sph.neighbors",
    "warp_iisph.sph.bodies",
    "warp_iisph.sph.wall_mask",
    "warp_iisph.sph.solvers.base",
    "warp_iisph.sph.solvers.iisph",
    "warp_iisph.sph.solvers.wcsph",
    "warp_iisph.sph.solvers.dfsph",
    "warp_iisph.sph.wall_forces",
    "warp_iisph.sph.containment",
    "warp_iisph.sph.rigid",
    "warp_iisph.surface.field",
    "warp_iisph.surface.marching",
    "warp_iisph.surface.smoothing",
    "warp_iisph.surface.reconstructor",
    "warp_iisph.run.obj_text",
]


def _arrays(inputs):
    out = []
    for a in inputs:
        if isinstance(a, wp.array):
            out.append(a)
        elif hasattr(a, "_cls"):  # a Warp struct: its array fields
            out.extend(v for v in (getattr(a, k) for k in a._cls.vars) if isinstance(v, wp.array))
    return out


def _bytes(arr):
    return arr.numpy().tobytes()


@pytest.fixture
def split_small(monkeypatch):
    """Split launches of any size into uneven chunks over 3 threads."""
    monkeypatch.setattr(launch, "MIN_CHUNK", 50)
    monkeypatch.setattr(launch, "SPLIT_WORTH", 0.0)  # split every launch, however light
    launch.set_threads(3)
    yield
    launch.set_threads(launch.available_cores())


def test_every_split_kernel_matches_one_launch(split_small, monkeypatch):
    """Each launch of a real run is done both ways from the same inputs; all arrays the kernel
    can touch must come out bitwise equal."""
    import importlib

    original = launch.launch_particles
    seen = set()

    def checked(kernel, n, inputs, device, **kw):
        arrays = _arrays(inputs)
        before = [a.numpy().copy() for a in arrays]
        wp.launch(kernel, dim=n, inputs=[0, *inputs], device=device)
        single = [_bytes(a) for a in arrays]
        for a, b in zip(arrays, before):
            a.assign(b)
        original(kernel, n, inputs, device, **kw)  # a kernel's first launch is never split
        for a, b in zip(arrays, before):
            a.assign(b)
        original(kernel, n, inputs, device, **kw)
        split = [_bytes(a) for a in arrays]
        assert single == split, kernel.key
        least = min(kw.get("min_chunk") or launch.MIN_CHUNK, launch.MIN_CHUNK)
        if n // least >= 2:  # it was split
            seen.add((kernel.key, n))

    for name in USERS:
        monkeypatch.setattr(importlib.import_module(name), "launch_particles", checked)
    sim = Simulation(
        load_scene("fluid_flow", ["spacing=0.03", "physics.viscosity=0.001", "physics.boundary_viscosity=0.001"]), "cpu"
    )
    for _ in range(12):  # past a cell reordering (every 10 steps)
        sim.step()
    wc = Simulation(scenes.martin_moyce(spacing=0.04, method="wcsph", dt=2e-4), "cpu")
    for _ in range(3):
        wc.step()
    df = Simulation(scenes.martin_moyce(spacing=0.04, method="dfsph", viscosity=1e-3), "cpu")
    for _ in range(3):
        df.step()
    body = Simulation(load_scene("flood", ["spacing=0.03"]), "cpu")  # free bodies (188 contact samples)
    for _ in range(3):
        body.step()
    from warp_iisph.surface import SurfaceReconstructor

    SurfaceReconstructor(0.03).reconstruct(sim.positions)
    keys = {k for k, _ in seen}
    for expected in (
        "splat_blocks",
        "block_cases",
        "block_emit",
        "fill_incident",
        "smooth_vertices",
        "vertex_normals",
        "count_neighbors",
        "fill_neighbors",
        "compute_density",
        "predict_advection_velocity",
        "predict_advection_density",
        "pressure_sum_dij_pj",
        "pressure_jacobi",
        "integrate",
        "predict_velocity",
        "state_equation",
        "boundary_psi",
        "initial_density",
        "dfsph_factor",
        "start_divergence_solve",
        "divergence_jacobi",
        "apply_stiffness",
        "start_density_solve",
        "density_jacobi",
        "finish_step",
        "contain",
        "sample_gaps",
        "cell_keys",
        "cell_starts",
        "place_bodies",
        "mark_moving",
    ):
        assert any(expected in k for k in keys), (expected, keys)


def test_containment_split_over_threads_puts_back_and_counts_as_one_launch(split_small):
    """The last line's launch cut over 3 threads: the same positions, velocities and counts as one
    launch, with particles past the tank's walls, inside an obstacle and clear of both."""
    import trimesh

    from warp_iisph.sph import containment
    from warp_iisph.sph.neighbors import NeighborListBuffer

    h = 0.02
    block = trimesh.creation.box(extents=(0.2, 0.2, 0.2))  # an obstacle with faces at +-0.1
    box = (np.array([-0.3, -0.3, -0.3]), np.array([0.3, 0.3, 0.3]))
    rng = np.random.default_rng(7)
    x0 = rng.uniform(-0.36, 0.36, size=(3000, 3)).astype(np.float32)
    v0 = rng.normal(0.0, 1.0, size=(3000, 3)).astype(np.float32)
    outside = np.any(np.abs(x0) > 0.3, axis=1)
    # past the obstacle's inner layer, within the last line's reach (2 h) of its faces
    depth = 0.1 - np.abs(x0).max(axis=1)
    inside = (depth > 0.5 * h + 1e-3) & (depth < 2 * h - 1e-3)
    results = []
    for split in (False, True):
        walls = containment.Containment("cpu", box, [(block.vertices, block.faces, -1, False, 0.5 * h)], spacing=h)
        near = NeighborListBuffer(len(x0), "cpu", capacity=len(x0))
        near.lists.count.fill_(1)  # every particle had wall neighbours at the step's start
        x = wp.array(x0, dtype=wp.vec3, device="cpu")
        v = wp.array(v0, dtype=wp.vec3, device="cpu")
        launch.set_threads(3 if split else 1)
        walls.apply(x, v, near.lists, len(x0), wp.array([1e-3], dtype=wp.float64, device="cpu"))
        results.append((x.numpy(), v.numpy(), walls.corrections.numpy().tolist()))
    (xa, va, ca), (xb, vb, cb) = results
    assert np.array_equal(xa, xb) and np.array_equal(va, vb) and ca == cb
    # every one past the inner layer put back; near the edges, where the layer is thinner, a few more
    assert ca[0] == int(outside.sum()) and int(inside.sum()) <= ca[1] <= int(((depth > 0) & (depth < 2 * h)).sum())
    assert min(ca) > 10
    assert np.all(np.abs(xb) <= 0.3 + 1e-6)


def test_dam_break_with_one_and_two_threads_is_identical(monkeypatch):
    monkeypatch.setattr(launch, "MIN_CHUNK", 50)
    monkeypatch.setattr(launch, "SPLIT_WORTH", 0.0)  # split every launch, however light
    runs = {}
    for threads in (1, 2):
        launch.set_threads(threads)
        sim = Simulation(scenes.martin_moyce(spacing=0.03, viscosity=1e-3, boundary_viscosity=1e-3), "cpu")
        sim.advance(0.1)
        runs[threads] = (
            sim.positions,
            sim.velocities,
            sim.pressures,
            [s["iterations"] for s in sim.stats],
            [s["density_error"] for s in sim.stats],
        )
    launch.set_threads(launch.available_cores())
    a, b = runs[1], runs[2]
    for x, y in zip(a[:3], b[:3]):
        assert np.array_equal(x, y)
    assert a[3] == b[3] and a[4] == b[4]


def test_chunks_cover_the_range_once():
    for n, parts in [(10, 3), (7, 7), (5, 8), (100_000, 2)]:
        cs = launch.chunks(n, parts)
        idx = np.concatenate([np.arange(s, s + c) for s, c in cs])
        assert np.array_equal(idx, np.arange(n))


def test_thread_setting_is_validated():
    with pytest.raises(ValueError, match=r"threads = 0: must be an integer in \[1, 1024\]"):
        launch.set_threads(0)


@pytest.mark.parametrize("n", [1, 255, 256, 1000, 70001])
def test_reductions_by_tiles(n):
    """engine.reduce: the sum in index order (array_sum's bits) and the exact maximum by tiles,
    over a length that is no multiple of the tile (the tail's lanes load zeros)."""
    import warp as wp

    from warp_iisph.engine.reduce import max_into, sum_into

    rng = np.random.default_rng(n)
    values = rng.random(n + 7) * 3.0
    total, top = wp.zeros(1, dtype=wp.float64), wp.full(1, 0.5, dtype=float)
    sum_into(wp.array(values, dtype=wp.float64), n, total)
    assert total.numpy()[0] == wp.utils.array_sum(wp.array(values[:n], dtype=wp.float64))
    max_into(wp.array(values.astype(np.float32), dtype=float), n, top)
    assert top.numpy()[0] == max(np.float32(0.5), values[:n].astype(np.float32).max())


def test_warp_debug_mode_launches_in_one_piece(monkeypatch):
    """Warp's debug build shares one CPU tile-storage pointer across threads, so split launches
    crashed there (a segfault in the reorder's gather with 2 threads): in debug mode every launch
    is one piece."""
    launched = []
    monkeypatch.setattr(launch, "_run_split", lambda packed: launched.append(len(packed)))
    monkeypatch.setattr(launch, "get_threads", lambda: 4)
    monkeypatch.setattr(launch, "SPLIT_WORTH", 0.0)
    out = wp.zeros(100_000, dtype=float)
    launch.launch_particles(_fill_index, 100_000, [out], "cpu")  # loads the module: one piece
    launch.launch_particles(_fill_index, 100_000, [out], "cpu")
    assert launched == [4]  # split in release mode
    monkeypatch.setattr(wp.config, "mode", "debug")
    launch.launch_particles(_fill_index, 100_000, [out], "cpu")
    assert launched == [4] and out.numpy()[-1] == 99_999.0


@wp.kernel
def _fill_index(offset: int, out: wp.array(dtype=float)):
    i = wp.tid() + offset
    out[i] = float(i)
