"""The benchmark scripts' --quick modes run and write their table, JSON and chart."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize(
    "script,stem", [("thread_scaling.py", "thread_scaling_quick"), ("surface.py", "surface_quick")]
)
def test_benchmark_quick_mode(script, stem, tmp_path):
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), "--quick", "--threads", "1,2", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    record = json.loads((tmp_path / f"{stem}.json").read_text())
    assert [r["threads"] for r in record["results"]][:2] == [1, 2]
    assert record["versions"]["warp"] and record["date"]
    assert (tmp_path / f"{stem}.png").stat().st_size > 10_000


def test_surface_benchmark_without_splashsurf(tmp_path):
    """splashsurf is an optional benchmark dependency: without it the surface benchmark measures
    ours alone and says so."""
    hide = tmp_path / "hide"
    hide.mkdir()
    (hide / "pysplashsurf.py").write_text("raise ImportError('hidden for this test')\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(hide), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "surface.py"), "--quick", "--threads", "1", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    assert "pysplashsurf is not installed" in proc.stdout
    record = json.loads((tmp_path / "surface_quick.json").read_text())
    assert record["splashsurf"] is None and "splashsurf_ms" not in record["results"][0]
    assert set(record["quality"]["synthetic_20k"]) == {"ours", "ours_taubin", "ours_none"}


@pytest.mark.parametrize("script,stem", [("validation.py", "validation_quick"), ("stability.py", "stability_quick")])
def test_accuracy_benchmark_quick_mode(script, stem, tmp_path):
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), "--quick", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    record = json.loads((tmp_path / f"{stem}.json").read_text())
    rows = record.get("runs") or record.get("results")
    assert rows and (tmp_path / f"{stem}.png").stat().st_size > 10_000
    if script == "stability.py":  # the point of the chart: IISPH takes far larger steps than WCSPH
        dt = {r["method"]: r["dt_max"] for r in rows}
        assert dt["iisph"] > 2 * dt["wcsph"], dt
    else:
        (run,) = rows  # the surge front leaves the column's foot and only moves on
        assert not run["diverged"] and run["Z"][0] < 1.1 < run["Z"][-1] and np.all(np.diff(run["Z"]) > -0.05)
        assert run["error_a_1125"] is not None and run["error_a_2250"] is not None
        rest = record["resting_tank"]  # hydrostatics: pressure grows as rho0 g depth, the water stays at rest
        assert abs(rest["slope_mean"] - 1.0) < 0.1 and rest["mean_speed_max"] < 0.02
        assert record["part_dates"] == {"martin_moyce": record["date"], "rest": record["date"]}  # the quick parts


def test_validation_spheric_quick_mode(tmp_path):
    """validation.py's SPHERIC part (5 cm, 0.6 s): scored against the experiment, with the front's
    depths at the downstream gauges, the column's fall and its clock's lead, and charted."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "validation.py"), "--quick", "--parts", "spheric"]
        + ["--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "the column's clock leads its release by" in proc.stdout
    (run,) = json.loads((tmp_path / "validation_quick.json").read_text())["spheric"]
    scores = run["scores"]
    assert not run["diverged"] and 0.0 < scores["P1"]["arrival_error"] < 0.2  # late, as the docs say
    assert set(scores["H_x1.488"]["front_depths"]) == {"1", "3", "5"}
    column = scores["H_x2.638"]
    assert set(column["drops"]) == {"1", "2", "3"} and column["lead"]["experiment"] == pytest.approx(0.0198)
    assert (tmp_path / "validation_quick_spheric.png").stat().st_size > 10_000


def test_a_benchmark_on_two_workers_measures_what_it_measures_alone(tmp_path):
    """validation.py's runs as the variants of a sweep on a LocalCluster of 2 workers: the same
    results as one after another in this process, but for the timings."""
    pytest.importorskip("distributed", reason="Dask distributed (the cluster extra) is not installed")
    records = []
    for extra in ([], ["--workers", "2"]):
        out = tmp_path / ("serial" if not extra else "workers")
        proc = subprocess.run(
            [sys.executable, str(ROOT / "benchmarks" / "validation.py"), "--quick", "--out", str(out), *extra],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert proc.returncode == 0, proc.stderr
        records.append(json.loads((out / "validation_quick.json").read_text()))

    def untimed(o):
        if isinstance(o, dict):
            return {k: untimed(v) for k, v in o.items() if k not in ("wall_seconds", "date")}
        return [untimed(v) for v in o] if isinstance(o, list) else o

    assert records[0]["runs"] and records[0]["resting_tank"]["steps"]
    assert untimed(records[0]) == untimed(records[1])


def test_validation_beside_the_peer_quick_mode(tmp_path):
    """With the bench extra, validation.py --peer runs SPlisHSPlasH's IISPH on the same Martin &
    Moyce set-up and scores its front as ours: it leaves the column's foot, moves on, and has an
    error against both series. Skipped where pysplishsplash is not installed (CI's dev extra)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import peer_splishsplash
    finally:
        sys.path.pop(0)
    if not peer_splishsplash.available():
        pytest.skip("pysplishsplash (the bench extra) is not installed")
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "validation.py"), "--quick", "--peer", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    (peer,) = json.loads((tmp_path / "validation_quick.json").read_text())["peer_runs"]
    assert peer["nx"] == 10 and peer["particles"] == 10 * 20 * 5 and peer["escaped"] == 0
    assert peer["Z"][0] < 1.1 < peer["Z"][-1] and np.all(np.diff(peer["Z"]) > -0.05)
    assert peer["T"][-1] > 1.45  # it ran to the end (T <= 1.5 in the quick mode)
    assert 0.0 < peer["error_a_1125"] < 0.5 and 0.0 < peer["error_a_2250"] < 0.5  # the same flow, scored as ours
    assert "SPlisHSPlasH IISPH, Martin & Moyce nx 10" in proc.stdout


def test_keep_parts_keeps_what_was_not_run_with_the_day_it_was_measured(tmp_path):
    """benchmarks/common.keep_parts: a part not run this time comes from the saved file with its
    date (from ``part_dates``, else an older file's ``<part>_date``, else the file's date), a part
    run now is dated today and not copied, a part the file lacks stays absent; quick runs keep
    nothing."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from common import keep_parts
    finally:
        sys.path.pop(0)
    old = {"date": "2026-01-03", "a": [1], "b": [2], "b_date": "2026-01-02", "c": [3], "settle": [1, 2]}
    old["part_dates"] = {"c": "2026-01-01"}
    (tmp_path / "x.json").write_text(json.dumps(old))
    parts = {"a": ("a",), "b": ("b", "settle"), "c": ("c",), "d": ("d",)}
    record = {"date": "2026-12-05"}
    keep_parts(record, tmp_path, "x", parts, {"a"}, quick=False)
    assert "a" not in record and record["b"] == [2] and record["settle"] == [1, 2] and record["c"] == [3]
    assert "d" not in record
    assert record["part_dates"] == {"a": "2026-12-05", "b": "2026-01-02", "c": "2026-01-01"}
    quick = {"date": "2026-12-05"}
    keep_parts(quick, tmp_path, "x", parts, {"a"}, quick=True)
    assert quick == {"date": "2026-12-05", "part_dates": {"a": "2026-12-05"}}


def _quick(script: str, tmp_path, stem: str, *extra) -> dict:
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), "--quick", "--out", str(tmp_path), *extra],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    record = json.loads((tmp_path / f"{stem}.json").read_text())
    assert record["versions"]["warp"] and record["date"] and record["device"] and record["machine"]
    assert (tmp_path / f"{stem}.png").stat().st_size > 10_000
    return record


def test_device_switch_quick_mode(tmp_path):
    record = _quick("device_switch.py", tmp_path, "device_switch_quick")
    rows = [r for r in record["results"] if r["device"] == "cpu"]
    assert [r["particles"] for r in rows] == sorted(r["particles"] for r in rows) and len(rows) == 2
    assert ("cuda" in record["devices_missing"]) != any(r["device"] == "cuda" for r in record["results"])
    for r in rows:  # the throughput is what the steps and wall time say
        assert r["particle_steps_per_second"] == pytest.approx(r["particles"] * r["steps"] / r["wall_seconds"])
        # the traffic bound: more bytes for more particles, a bound below the measured step
        assert r["bytes_per_step"] > 16 * r["neighbour_entries"]["fluid"] * 4 > 0
        assert 0 < r["fraction_of_bandwidth_bound"] < 1
        assert r["realtime_ratio"] == pytest.approx(r["simulated_seconds"] / r["wall_seconds"])
    assert rows[1]["bytes_per_step"] > 2 * rows[0]["bytes_per_step"]
    graph = _quick(
        "device_switch.py", tmp_path, "device_switch_graph_mesh_quick", "--devices", "cpu", "--graph", "--mesh"
    )
    assert graph["graph"] and all(r["graph"] for r in graph["results"])
    assert [r["steps"] for r in graph["results"]] == [r["steps"] for r in rows]  # same steps, replayed
    for r in graph["results"]:  # meshing at 30 frames per simulated second, counted in the real-time ratio
        assert r["mesh_frames"] == 2 and r["mesh_triangles"] > 100 and r["mesh_ms_per_frame"] > 0
        assert r["realtime_ratio"] == pytest.approx(r["simulated_seconds"] / r["wall_seconds_with_mesh"])
    dfsph = _quick(
        "device_switch.py",
        tmp_path,
        "device_switch_dfsph_graph_quick",
        "--devices",
        "cpu",
        "--graph",
        "--method",
        "dfsph",
    )  # DFSPH's solves replayed as graphs (gpu_session.sh runs this on CUDA)
    assert dfsph["method"] == "dfsph" and record["method"] == "iisph"
    assert all(r["graph"] and r["steps"] > 0 and r["mean_iterations"] >= 2 for r in dfsph["results"])


def test_speed_accuracy_quick_mode(tmp_path):
    rows = _quick("speed_accuracy.py", tmp_path, "speed_accuracy_quick")["results"]
    by = {r["method"]: r for r in rows}
    # WCSPH at 0.2 ms fixed steps costs several times IISPH's CFL steps for a like density error
    assert by["wcsph"]["wall_seconds_per_simulated_second"] > 3 * by["iisph"]["wall_seconds_per_simulated_second"]
    assert all(0 < r["mean_density_error"] < 0.01 and r["front_error"] < 0.15 for r in rows)
    assert any("mean_density_error" in r.get("pareto", ()) for r in rows)


def test_speed_accuracy_pareto_front():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from speed_accuracy import pareto

    pts = [(1.0, 5.0), (2.0, 6.0), (3.0, 1.0), (0.5, 9.0), (4.0, 1.0)]
    assert sorted(pareto(pts)) == [0, 2, 3]


def test_breakdown_quick_mode(tmp_path):
    record = _quick("breakdown.py", tmp_path, "breakdown_quick")
    st = record["stage_seconds"]
    for stage in (
        "neighbours",
        "density",
        "advection",
        "pressure",
        "integration",
        "distance_field",
        "marching_cubes",
        "smoothing",
        "export",
    ):
        assert st[stage] > 0, stage
    assert sum(record["share"].values()) == pytest.approx(1.0, abs=1e-6)
    assert record["frames"] == 4
    assert record["writer_thread_seconds"] > 0


def test_neighbor_access_quick_mode(tmp_path):
    rows = _quick("neighbor_access.py", tmp_path, "neighbor_access_quick", "--devices", "cpu")["results"]
    (r,) = rows
    # the query twins compute the solver's own Jacobi iteration: same neighbours, same order
    assert r["max_relative_difference"]["pressure"] < 1e-5 and r["max_relative_difference"]["sum_dij_pj"] < 1e-5
    it, step = r["jacobi_iteration_ms"], r["modelled_step_ms"]
    assert r["walks_per_step"] == pytest.approx(4 + 2 * r["mean_iterations"]) and r["mean_iterations"] >= 1
    assert step["lists"] == pytest.approx(r["list_fill_ms"] + r["walks_per_step"] * it["lists"] / 2)
    assert step["query"] == pytest.approx(r["walks_per_step"] * it["query"] / 2)
    # the verdict follows the model (timings themselves are not asserted: a loaded machine moves them)
    assert r["faster"] == ("lists" if step["lists"] <= step["query"] else "query")
    if it["query"] > it["lists"]:
        assert r["break_even_walks"] == pytest.approx(r["list_fill_ms"] / ((it["query"] - it["lists"]) / 2))
    # every other layout and the index-only twin give bitwise the solver's pressures
    assert (
        r["layout_max_difference"] == 0.0
        and r["warp_blocked_max_difference"] == 0.0
        and r["index_only_max_difference"] == 0.0
    )
    assert set(r["layout_iteration_ms"]) == {"slot-major", "particle-major", "warp-blocked"} and r["count_only_ms"] > 0


def test_soak_quick_mode(tmp_path):
    record = _quick("soak.py", tmp_path, "soak_quick")
    assert record["ended"] == "completed" and record["steps"] >= 600 and record["frames"] == 19
    # every frame opens and closes its files: beyond the few the frames in flight hold (3, and 4 on
    # a machine busy with other work, where the writer falls behind), no handle accumulates (a leak
    # of one per frame would add 19)
    assert record["open_files_max"] - record["open_files_min"] <= 6


def test_dfsph_benchmark_quick_mode(tmp_path):
    rows = _quick("dfsph.py", tmp_path, "dfsph_quick")["results"]
    assert [(r["case"], r["method"]) for r in rows] == [
        (c, m) for c in ("0.005", "0.01", "cfl") for m in ("iisph", "dfsph")
    ]
    for r in rows:  # a run's record says how far it got and what it cost
        assert r["particles"] == 4096 and r["steps"] > 0 and r["wall_seconds_per_simulated_second"] > 0
        assert (r["diverged"] is None) == (abs(r["reached_s"] - 0.1) < 1e-9)
        assert (r["mean_divergence_iterations"] or 0) >= (1 if r["method"] == "dfsph" else 0)
    fixed = [r for r in rows if r["dt"] == 0.01]
    assert all(r["steps"] == 10 or r["diverged"] for r in fixed)


def test_resting_tank_study_quick_mode(tmp_path):
    rows = _quick("resting_tank.py", tmp_path, "resting_tank_quick")["runs"]
    assert [r["label"].split(",")[0] for r in rows] == ["IISPH"] * 6 + ["DFSPH", "WCSPH"]
    for r in rows:  # every case reports its steps, or how it diverged
        assert r["steps"] or r["diverged"]
    default = rows[0]  # IISPH at the defaults: pressure carries the weight, the water rests
    assert not default["diverged"] and abs(default["slope_mean"] - 1.0) < 0.05 and default["mean_speed_max"] < 0.03
    assert default["step_number"] == pytest.approx(default["steps"][0]["dt"] ** 2 * 9.81 * 0.6 / 0.04**2, rel=0.05)


def test_step_change_benchmark_quick_mode(tmp_path):
    rows = _quick("step_change.py", tmp_path, "step_change_quick")["runs"]
    assert [r["name"] for r in rows] == ["defaults", "min_iterations 8", "warm_start half"]
    for r in rows:  # six steps by hand at 2 ms, then back at the CFL step, each measured
        assert r["steps"][:6] == [0.002] * 6 and r["steps"][6] == pytest.approx(r["cfl_step"]) and r["cfl_step"] > 0.003
        # pressure carries the weight throughout (at 4 cm, 5 ms to 2 ms kicks it by up to 13 %)
        assert (
            len(r["slopes"]) == 24
            and abs(np.mean(r["slopes"]) - 1.0) < 0.05
            and all(abs(s - 1.0) < 0.2 for s in r["slopes"])
        )
        assert r["spread"] == pytest.approx(max(abs(s / np.mean(r["slopes"]) - 1.0) for s in r["slopes"]))
        # the first jump, and that per unit of the solve's stiffening (dt / dt_short)^2 - 1
        assert r["short_step"] == 0.002 and r["first_jump"] == pytest.approx(r["slopes"][0] - r["slope_before"])
        ratio = (r["cfl_step"] / r["short_step"]) ** 2 - 1.0
        assert r["jump_per_stiffening"] == pytest.approx(r["first_jump"] / ratio)
    assert min(rows[1]["iterations"]) >= 8  # the variant's settings reach the solver


def test_the_two_level_twin_solves_its_coarse_poisson_problem():
    """benchmarks/solve_variants.py's coarse problem, whose correction docs/pressure_solve.md reports
    as diverging: on a column of 7 liquid cells under one of air (uniform residual, the floor
    mirrored, the surface at the face between them by the fill fractions), its SOR sweeps give the
    parabola of ``dt^2 e'' = rho0 r`` with ``e' = 0`` at the floor and ``e = 0`` at the surface, to
    the ghost-fluid surface's first-order error."""
    import warp as wp

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import solve_variants as sv
    finally:
        sys.path.pop(0)
    H, n, dt, rho0, r = 0.08, 8, 3.0e-3, 1000.0, -1.0e-3
    g = sv.CoarseGrid()
    g.lower, g.size, g.dims, g.full = wp.vec3(0.0, 0.0, 0.0), wp.vec3(1.0, H, 1.0), wp.vec3i(1, n, 1), 1.0
    kind, fill = np.ones(n, dtype=np.int32), np.ones(n, dtype=np.float32)
    kind[-1], fill[-1] = 0, 0.0
    g.kind, g.fill = wp.array(kind, dtype=int), wp.array(fill, dtype=float)
    g.walls, g.e = wp.zeros(n, dtype=float), wp.zeros(n, dtype=float)
    g.r = wp.full(n, r, dtype=float)
    wp.launch(sv.coarse_solve, dim=1, inputs=[g, wp.array([dt], dtype=float), rho0, 200, 1.6])
    e = g.e.numpy()[:-1]
    y = (np.arange(n - 1) + 0.5) * H
    surface = (n - 1) * H
    exact = 0.5 * (-rho0 * r / dt**2) * (surface**2 - y**2)  # e'' = rho0 r / dt^2 < 0: a compression's bump
    np.testing.assert_allclose(e, exact, rtol=0.05, atol=0.02 * exact.max())
    assert g.e.numpy()[-1] == 0.0  # air keeps no correction


def _heave_reference():
    import importlib.util

    spec = importlib.util.spec_from_file_location("heave_reference", ROOT / "benchmarks" / "heave_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_heave_reference_free_decay_without_radiation_is_the_undamped_oscillator():
    """Cummins' equation with no radiation damping is a mass M + A_inf on a spring k: released
    from rest it swings at 2 pi sqrt((M + A_inf) / k) without losing or gaining amplitude; the
    frequency-domain resonance with a constant A is the same oscillator's."""
    linear = _heave_reference()
    omega = np.arange(1.0, 30.0, 0.25)
    rad = {"omega": omega.tolist(), "added_mass": [0.8] * len(omega), "damping": [0.0] * len(omega)}
    rad["added_mass_infinite"] = 0.8
    mass, stiffness = 1.0, 250.0
    t, z = linear.free_decay(mass, stiffness, rad, -0.02, 1.2)
    period = 2.0 * np.pi * np.sqrt((mass + 0.8) / stiffness)
    np.testing.assert_allclose(z, -0.02 * np.cos(2.0 * np.pi * t / period), atol=3e-4)
    assert linear.natural_frequency(mass, stiffness, rad) == pytest.approx(2.0 * np.pi / period, rel=1e-3)


def test_heave_reference_radiation_damps_the_decay_by_its_damping():
    """With a radiation damping B0 the same at every frequency the memory kernel is nearly B0 times
    a delta, and the decay's damping ratio B0 / (2 sqrt(k (M + A))), read from the log decrement of
    successive swings; the swings shrink one after another."""
    linear = _heave_reference()
    omega = np.arange(1.0, 30.0, 0.25)
    mass, added, stiffness, b0 = 1.0, 1.2, 250.0, 2.0
    rad = {"omega": omega.tolist(), "added_mass": [added] * len(omega), "damping": [b0] * len(omega)}
    rad["added_mass_infinite"] = added
    t, z = linear.free_decay(mass, stiffness, rad, -0.02, 2.0)
    peaks = [abs(z[k]) for k in range(1, len(z) - 1) if abs(z[k]) >= abs(z[k - 1]) and abs(z[k]) > abs(z[k + 1])]
    assert len(peaks) >= 6 and all(b < a for a, b in zip(peaks, peaks[1:]))
    decrement = np.log(peaks[0] / peaks[2])  # one period: from a swing to the next on the same side
    zeta = decrement / np.sqrt(4.0 * np.pi**2 + decrement**2)
    assert zeta == pytest.approx(b0 / (2.0 * np.sqrt(stiffness * (mass + added))), rel=0.05)


def test_cluster_benchmark_quick_mode_measures_its_bounds(tmp_path):
    """cluster.py --quick: the sweep and the render on 2 workers write what they write one after
    another, and beside each ratio the bound measured with no engine (the sweep split over plain
    processes; the serial render's busy cores over the workers)."""
    pytest.importorskip("distributed", reason="Dask distributed (the cluster extra) is not installed")
    record = _quick("cluster.py", tmp_path, "cluster_quick")
    sweep = record["sweep"]
    assert sweep["same_results"] and sweep["variants"] == 4
    assert len(sweep["split_runs"]) == 1 and sweep["floor"] == pytest.approx(
        sweep["split_seconds"] / sweep["serial_seconds"]
    )
    assert 0.3 < sweep["floor"] < 2.0
    render = record["render"]
    if render is not None:  # with the render extra
        assert render["same_results"] and render["frames"] == 8
        # the busy cores are the machine's to give (a shared CI machine gave a third of one)
        assert 0.0 < render["serial_cores_busy"] <= os.cpu_count() + 0.2
        assert render["floor"] == pytest.approx(render["serial_cores_busy"] / len(os.sched_getaffinity(0)))


def test_pressure_operator_quick_mode(tmp_path):
    """The release column at nx 10, 4 spacings deep: its operator's least eigenvalue is positive with
    either walls (relaxed Jacobi converges there; at nx 20 it does not, docs/pressure_solve.md), and
    the uniform pressure compresses the layers between the side walls only with extrapolated walls."""
    (case,) = _quick("pressure_operator.py", tmp_path, "pressure_operator_quick")["cases"]
    assert case["particles"] == 800
    for walls in ("extrapolated", "akinci"):
        assert 0.0 < case[walls]["least_eigenvalue"][0] < 0.05
        assert case[walls]["jacobi_factor"] < 1.0
    assert case["extrapolated"]["uniform_between"] < 0.0 < case["akinci"]["uniform_between"]
    assert -0.07 < case["side_wall_gradient_sum"] < -0.03
    assert (tmp_path / "pressure_operator_quick.png").stat().st_size > 0


def test_edge_weights_quick_mode(tmp_path):
    """The edge-weights study: Akinci's weights put the fluid beside a convex edge of a lattice box
    above the build's 0.5 % (so it is left out), a flat wall's weight below rho0 and the calibrated
    cap at it; with the calibrated cap the bar keeps the fluid beside its edges (two lines along
    each of its four edges: 48 particles at 8 spacings) and only the bar's weights change."""
    record = _quick("edge_weights.py", tmp_path, "edge_weights_quick")
    cal = record["calibration"]
    assert cal["edge_density"]["akinci"] > 1.015 and 0.99 < cal["edge_density"]["flat"] < 0.997
    assert cal["edge_density"]["calibrated"] == pytest.approx(1.0, abs=1e-9)
    assert 1.0 < cal["factor"] < 1.2
    rows = {r["weights"]: r for r in record["results"]}
    assert set(rows) == {"akinci", "calibrated"}
    assert rows["calibrated"]["particles"] - rows["akinci"]["particles"] == 48
    assert rows["akinci"]["capped"] is None and rows["calibrated"]["capped"] > 0
    for r in rows.values():
        assert r["L_over_h"] == 8 and 0.95 < r["ratio"] < 1.08


def test_held_bar_quick_mode(tmp_path):
    """The held bar's study: its split of the bar's force over faces and edges adds up to the force
    probe's reading (the same step's wall sums, grouped otherwise), the faces carry about their
    hydrostatic load (within what the split between a face's two layers leaves uncertain), the
    half start pays for its rest in iterations, the crossed runs switch their start where they
    say (the settling, not the solve, is what the crossed part compares), and the completed walls'
    part runs with them."""
    record = _quick("held_bar.py", tmp_path, "held_bar_quick")
    rows = {r["warm_start"]: r for r in record["results"]}
    assert set(rows) == {"hydrostatic", "half"}
    for r in rows.values():
        assert r["samples"] == 20 and r["L_over_h"] == 8
        assert r["parts_sum"] == pytest.approx(r["ratio"], rel=1e-6)
        assert 0.95 < r["ratio"] < 1.06
        for face in ("top", "bottom"):
            assert r[f"{face}_face_pressure"] == pytest.approx(r[f"{face}_face_hydrostatic"], rel=0.15)
        assert 0.98 < r["beside_slope"] < 1.08
    assert rows["half"]["iterations_per_step"] > 2 * rows["hydrostatic"]["iterations_per_step"]
    # the crossed runs change the start at 0.3 s: until then the one settled from the hydrostatic
    # start is the plain hydrostatic run step for step, and each phase iterates as its start does
    crossed = {(r["settled_from"], r["warm_start"]): r for r in record["crossed"]}
    assert set(crossed) == {("half", "hydrostatic"), ("hydrostatic", "half")}
    before, after = crossed[("half", "hydrostatic")]["iterations_before_after"]
    assert before > 2 * after
    before, after = crossed[("hydrostatic", "half")]["iterations_before_after"]
    assert after > 2 * before
    plain, switched = rows["hydrostatic"]["series"], crossed[("hydrostatic", "half")]["series"]
    settling = [k for k, t in enumerate(plain["time"]) if 0.0 < t < 0.3]  # sampled between steps
    assert len(settling) >= 5 and plain["time"][: len(settling) + 1] == switched["time"][: len(settling) + 1]
    assert [plain["ratio"][k] for k in settling] == [switched["ratio"][k] for k in settling]
    assert [plain["under"][k] for k in settling] == [switched["under"][k] for k in settling]
    assert switched["ratio"][-1] != plain["ratio"][-1]
    # the completed walls' run: the same measurement, the faces nearer their hydrostatic load
    (completed,) = record["completed"]
    assert completed["wall_gradient"] == "completed" and rows["hydrostatic"]["wall_gradient"] == "akinci"
    assert completed["parts_sum"] == pytest.approx(completed["ratio"], rel=1e-6) and 0.95 < completed["ratio"] < 1.06


def test_pinned_films_quick_mode(tmp_path):
    """The pinned-films study: the coarse dam break's compressed particles all keep a diagonal
    above the floor and the run ends bit for bit as without it, and the coarse flood runs with and
    without the floor in both ways of advancing, each run's record complete; the same for DFSPH's
    denominator floor (its flood frame by frame)."""
    record = _quick("pinned_films.py", tmp_path, "pinned_films_quick")
    (d,) = record["diagonals"]
    assert d["scene"] == "dam_break" and d["compressed_samples"] > 1000
    assert d["least"] > record["floor"] and d["below"]["0.25"] == 0 and d["identical_without_floor"]
    runs = record["flood"]
    assert {(r["fps"], r["floor"]) for r in runs} == {(0, 0.0), (0, record["floor"]), (30, 0.0), (30, record["floor"])}
    for r in runs:
        assert abs(r["simulated_seconds"] - 0.3) < 1e-9 and r["steps"] == len(r["t"]) == len(r["max_velocity"])
        assert 0.5 < r["fastest"] < 2.0 * 2.0 * np.sqrt(9.81 * 0.35) and r["mean_iterations"] >= 2
    (d,) = record["dfsph_denominators"]
    assert d["scene"] == "dam_break" and d["pushed_samples"] > 1000
    assert d["least"] > record["denominator_floor"] and d["below"]["0.25"] == 0 and d["identical_without_floor"]
    assert abs(d["percentiles"]["50"] - 1.0) < 0.05  # the bulk's denominator: the median pushed particle's
    runs = record["dfsph_flood"]
    assert [(r["method"], r["fps"], r["floor"]) for r in runs] == [
        ("dfsph", 30.0, 0.0),
        ("dfsph", 30.0, record["denominator_floor"]),
    ]
    for r in runs:
        assert r["diverged"] is None and abs(r["simulated_seconds"] - 0.3) < 1e-9 and r["steps"] == len(r["t"])
        assert 0.5 < r["fastest"] < 2.0 * 2.0 * np.sqrt(9.81 * 0.35) and r["mean_iterations"] >= 2


def test_obstacle_sampling_quick_mode(tmp_path):
    """The obstacle-sampling study: a bar held in water, sampled on the cells its faces cross,
    outweighs the liquid beside it and reads its buoyancy far above rho0 g V (25 % at 8 spacings
    and 3 s; here 6 spacings, 0.5 s); in layers, as a box by faces and as a mesh, it reads
    alike, far closer; the dam break's submarine counts its put-backs."""
    record = _quick("obstacle_sampling.py", tmp_path, "obstacle_sampling_quick")
    runs = {(r["kind"], r["shift"]): r for r in record["bar"]["runs"]}
    assert set(runs) == {("box_cells", 0.0), ("box_faces", 0.0), ("mesh", 0.0)}
    cells, faces, mesh = (runs[k, 0.0]["ratio"] for k in ("box_cells", "box_faces", "mesh"))
    assert cells > 1.15 and abs(faces - 1.0) < 0.06 and abs(mesh - faces) < 0.01
    assert runs["mesh", 0.0]["fluid_particles"] == runs["box_faces", 0.0]["fluid_particles"]
    dam = record["dam_break"]
    assert dam["steps"] > 10 and dam["fluid_particles"] == 9216 and dam["wall_corrections"] == 0


def test_a_replayed_body_follows_the_path_it_was_given():
    """benchmarks/bodies.py's replays (the flood's boxes moved along the free bodies' path, the
    coupling's cost set apart): at every key the keyframed box stands where the free body stood,
    corners and all, through a spin of more than a turn (the angles unwrapped)."""
    import importlib.util

    from scipy.spatial.transform import Rotation

    from warp_iisph.scene.bodies import quaternion_matrix

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location("bodies_benchmark", ROOT / "benchmarks" / "bodies.py")
        bodies = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(bodies)
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    scene = bodies.load_scene("flood", ["spacing=0.04"])
    n, k = len(scene.bodies), 40
    times = np.linspace(0.0, 0.8, k)
    rng = np.random.default_rng(3)
    # centres of mass off the boxes' middles (a body may set its own): the boxes turn about them
    starts = np.array([0.5 * (np.add(b.shape.lower, b.shape.upper)) for b in scene.bodies]) + [0.01, -0.005, 0.02]
    position = starts + np.cumsum(rng.normal(0.0, 0.01, (k, n, 3)), axis=0) * (times[:, None, None] > 0)
    spin = np.radians(np.linspace(0.0, 400.0, k))  # about y, past a whole turn
    tilt = 0.3 * np.sin(np.linspace(0.0, 3.0, k))
    rot = Rotation.from_euler("xyz", np.stack([tilt, spin, 0.5 * tilt], axis=1))
    orientation = np.stack([rot.as_quat()] * n, axis=1)
    orientation[:, 1] *= -1.0  # the same rotations with the quaternions' other sign
    path = {"times": times, "position": position, "orientation": orientation}
    motions = bodies.replay_motions(scene, path)
    for j, (body, motion) in enumerate(zip(scene.bodies, motions)):
        lo, hi = np.asarray(body.shape.lower), np.asarray(body.shape.upper)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        for i in range(0, k, 7):
            m = motion.matrix(times[i], np.asarray(motion.pivot))
            moved = corners @ m[:3, :3].T + m[:3, 3]
            want = (corners - starts[j]) @ quaternion_matrix(orientation[i, j]).T + position[i, j]
            np.testing.assert_allclose(moved, want, atol=1e-9)
        for i in range(k - 1):  # between keys: near the halfway rotation (keys 10 degrees of spin apart)
            m = motion.matrix(0.5 * (times[i] + times[i + 1]), np.asarray(motion.pivot))
            half = Rotation.from_quat(orientation[i : i + 2, j]).mean().as_matrix()
            assert np.degrees(np.arccos(np.clip((np.trace(m[:3, :3].T @ half) - 1.0) / 2.0, -1, 1))) < 2.0


def test_step_setters_distances_are_taken_in_each_box_frame():
    """benchmarks/bodies.py's box_distance, as StepSetters and inside_count use it: a point's
    offset from a box's centre taken into its frame (``(p - centre) @ R``, R the body-to-world
    rotation of its quaternion), then the signed distance to the box (negative inside)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from bodies import box_distance
    finally:
        sys.path.pop(0)
    from warp_iisph.scene.bodies import quaternion_matrix

    half = np.array([0.06, 0.04, 0.06])
    assert box_distance(np.zeros(3), half) == pytest.approx(-0.04)
    assert box_distance(np.array([0.1, 0.0, 0.0]), half) == pytest.approx(0.04)
    assert box_distance(np.array([0.09, 0.07, 0.0]), half) == pytest.approx(np.hypot(0.03, 0.03))
    # turned 30 degrees about y (x y z w): 8 cm along the box's own x axis is 2 cm beyond its x face
    # (the other way round, R d, turns the offset by 60 degrees: 0.9 cm beyond its z face)
    R = quaternion_matrix(np.array([0.0, np.sin(np.pi / 12), 0.0, np.cos(np.pi / 12)]))
    centre = np.array([1.0, 0.5, 0.2])
    p = centre + 0.08 * R[:, 0]
    assert box_distance((p - centre) @ R, half) == pytest.approx(0.02)
    assert box_distance(R @ (p - centre), half) == pytest.approx(0.08 * np.sin(np.pi / 3) - 0.06, abs=1e-9)
