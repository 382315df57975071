"""The walls' extrapolated pressure (physics.wall_pressure) and completed kernel gradient
(physics.wall_gradient), fixed steps cut into substeps (physics.substeps) and the viscosity's own
sub-steps: physics first, then the plain, graph and resumed paths agreeing bitwise."""

import numpy as np
import pytest

from warp_iisph import Box, Physics, Scene, Simulation, load_scene, scenes
from warp_iisph.analysis.dam_break import surge_front
from warp_iisph.sph.solvers.forces import viscous_dt_limit

G = 9.81


COLUMN_H, COLUMN_DEPTH = 0.02, 0.3


def floor_layer_of_a_resting_column(physics: Physics, ratio) -> float:
    """Water 0.3 m deep in a 0.16 x 0.4 x 0.16 m tank at 2 cm (960 particles), settled 1 s, then
    over 0.4 s of steps the mean of ``ratio(x, p, inner, floor)``: the particles' positions and
    pressures, those away from the side walls, and those of them in the layer touching the floor.
    Averaged over steps, as the column still breathes a little from step to step."""
    h = COLUMN_H
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (0.16, 0.4, 0.16)), physics=physics, name="resting_column")
    scene.add_fluid_box((0.0, 0.0, 0.0), (0.16, COLUMN_DEPTH, 0.16))
    sim = Simulation(scene, "cpu")
    sim.advance(1.0)
    ratios = []
    while sim.time < 1.4 - 1e-9:
        sim.step()
        x, p = sim.positions, sim.pressures
        inner = np.all((x[:, [0, 2]] > 1.5 * h) & (x[:, [0, 2]] < 0.16 - 1.5 * h), axis=1)
        ratios.append(ratio(x, p, inner, inner & (x[:, 1] < h)))
    return float(np.mean(ratios))


def floor_layer_over_hydrostatic(wall_pressure: str) -> float:
    """The resting column's floor layer: its mean pressure over rho0 g times its depth below the top
    layer (whose pressure is zero: the solver clamps the under-dense free surface at p = 0)."""

    def ratio(x, p, inner, floor):
        top = np.sort(x[:, 1])[-len(x) // 15 :].mean()  # the top layer (15 layers)
        return np.mean(p[floor]) / (1000.0 * G * np.mean(top - x[floor, 1]))

    return floor_layer_of_a_resting_column(Physics(wall_pressure=wall_pressure), ratio)


def test_extrapolated_walls_hold_the_floor_layer_at_hydrostatic_pressure():
    """Momentum balance at a wall: the layer on the floor carries the column above it. With the
    walls pushing with the fluid's own pressure in one term (Akinci, "fluid"), that layer needs
    about twice the hydrostatic pressure to hold it; with the pressure extrapolated into the wall
    it needs the hydrostatic pressure."""
    ratio = {w: floor_layer_over_hydrostatic(w) for w in ("extrapolated", "fluid")}
    assert abs(ratio["extrapolated"] - 1.0) < 0.1, ratio
    assert ratio["fluid"] > 1.4, ratio


def floor_layer_against_interior(wall_gradient: str) -> float:
    """The resting column's floor layer: its mean pressure over the pressure a linear fit of the
    interior's (more than two spacings from the floor, three from the top) gives at its height."""
    h = COLUMN_H

    def ratio(x, p, inner, floor):
        interior = inner & (x[:, 1] > 2 * h) & (x[:, 1] < COLUMN_DEPTH - 3 * h)
        fit = np.polyfit(x[interior, 1], p[interior], 1)
        return np.mean(p[floor]) / np.mean(np.polyval(fit, x[floor, 1]))

    return floor_layer_of_a_resting_column(Physics(wall_gradient=wall_gradient), ratio)


def test_completed_wall_gradients_keep_the_wall_layer_on_the_interior_pressure():
    """Akinci's volumes fill a wall particle's share of the density, not of the kernel gradient:
    a uniform pressure pushes the layer on the floor off it, and that layer carries less than the
    hydrostatic field around it (about 8 % at 2 cm). With the walls completing the gradient
    (physics.wall_gradient = "completed", the default only with free bodies) it carries the
    field's pressure."""
    ratio = {w: floor_layer_against_interior(w) for w in ("completed", "akinci")}
    assert abs(ratio["completed"] - 1.0) < 0.02, ratio
    assert ratio["akinci"] < 0.95, ratio


def dam(dt: float, substeps: bool = True, graph: bool = False) -> Simulation:
    return Simulation(scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1, dt=dt, substeps=substeps), "cpu", graph=graph)


def test_a_fixed_step_is_cut_into_substeps_that_land_on_it():
    """A fixed 20 ms step on a 2 cm dam break lets particles cross several spacings: every step
    taken is at most h / v_ref (v_ref = sqrt(2 g y_top), the free-fall speed of the column's
    top), the substeps of one fixed step are equal, and their ends land on the multiples of 20 ms."""
    dt = 0.02
    sim = dam(dt)
    sim.advance(0.2)
    v_ref = np.sqrt(2 * G * 0.4)
    st = sim.stats
    assert all(s["dt"] <= sim.model.spacing / v_ref * (1 + 1e-6) for s in st)
    assert min(s["substeps"] for s in st) >= 3
    ends = [s["t"] for s in st if abs(s["t"] / dt - round(s["t"] / dt)) < 1e-6]
    assert len(ends) == 10 and abs(sim.time - 0.2) < 1e-9
    t0 = 0.0
    for end in ends:  # the steps between two ends are equal pieces of one fixed step
        group = [s for s in st if t0 + 1e-9 < s["t"] <= end + 1e-9]
        piece = [s["dt"] for s in group]
        assert len(piece) == group[0]["substeps"]
        assert max(piece) - min(piece) < 1e-6 * dt and abs(sum(piece) - dt) < 1e-6 * dt
        t0 = end


def fine_column(dt=None, graph: bool = False, **physics) -> Simulation:
    """Martin & Moyce, a = 0.1 m at 1 cm (800 particles, 4 layers deep): the default viscosity's
    limit 0.4 h^2 / mu is 0.8 ms, a third of the flow's own step."""
    return Simulation(scenes.martin_moyce(spacing=0.01, a=0.1, depth=0.04, dt=dt, **physics), "cpu", graph=graph)


def test_viscosity_takes_its_own_substeps_where_the_step_exceeds_its_limit():
    """The step follows the flow (CFL), not the viscosity: steps of 2-3 times the viscosity's
    limit run stable (an explicit viscous step that long blows up: the stability benchmark's
    bisection), and the front they give is the front of steps within the limit (the same
    viscosity, applied in sub-steps instead of whole steps)."""
    limit = viscous_dt_limit(0.01, Physics())
    T = np.array([0.5, 1.0, 1.5, 2.0])
    fronts = {}
    for name, dt in (("cfl", None), ("small", 0.9 * limit)):
        sim = fine_column(dt)
        Z = []
        for t in T / np.sqrt(2 * G / 0.1):
            sim.advance(t - sim.time)
            Z.append(surge_front(sim.positions, 0.01) / 0.1)
        st = sim.stats
        assert all(s["escaped"] == 0 and s["wall_corrections"] == 0 for s in st)
        assert np.mean([s["compression"] for s in st]) < 2 * sim.physics.eta
        fronts[name] = np.array(Z)
        if name == "cfl":
            assert np.median([s["dt"] for s in st]) > 2 * limit
    np.testing.assert_allclose(fronts["cfl"], fronts["small"], rtol=0.03)


def test_viscous_substeps_in_a_graph_are_bitwise_the_plain_run():
    plain, graph = fine_column(), fine_column(graph=True)
    plain.advance(0.05)
    graph.advance(0.05)
    assert max(s["dt"] for s in plain.stats) > 2 * viscous_dt_limit(0.01, plain.physics)
    np.testing.assert_array_equal(graph.positions, plain.positions)
    np.testing.assert_array_equal(graph.velocities, plain.velocities)


def test_without_substeps_a_fixed_step_is_taken_as_it_is():
    sim = dam(0.004, substeps=False)
    sim.advance(0.04)
    assert all(s["substeps"] == 1 and abs(s["dt"] - 0.004) < 1e-9 for s in sim.stats)


def test_substeps_in_a_graph_and_after_a_resume_are_bitwise_the_plain_run():
    """The substep state lives on the device: a captured loop takes the same substeps, and a run
    restored from a checkpoint taken in the middle of a cut step continues as the run that never
    stopped."""
    plain, graph = dam(0.02), dam(0.02, graph=True)
    plain.advance(0.1)
    graph.advance(0.1)
    np.testing.assert_array_equal(graph.positions, plain.positions)
    assert [s["dt"] for s in graph.stats] == [s["dt"] for s in plain.stats]

    whole = dam(0.02)
    for _ in range(10):
        whole.step()
    assert (
        whole.stats[-1]["substeps"] > 1 and abs(whole.time / 0.02 - round(whole.time / 0.02)) > 1e-3
    )  # mid-way through a cut step
    saved = whole.checkpoint()
    resumed = dam(0.02)
    resumed.restore(saved)
    whole.advance(0.06)
    resumed.advance(0.06)
    np.testing.assert_array_equal(resumed.positions, whole.positions)
    assert [s["dt"] for s in resumed.stats] == [s["dt"] for s in whole.stats][-len(resumed.stats) :]


@pytest.mark.parametrize("value", ["mirror", 1, None])
def test_wall_pressure_must_be_a_known_name(value):
    with pytest.raises(ValueError, match="physics.wall_pressure"):
        Physics(wall_pressure=value).validate()


@pytest.mark.parametrize("value", ["akinci2012", 0, ""])
def test_wall_gradient_must_be_a_known_name(value):
    with pytest.raises(ValueError, match="physics.wall_gradient"):
        Physics(wall_gradient=value).validate()


@pytest.mark.parametrize("substeps", [True, False])
def test_landing_on_frame_times_leaves_no_sliver_of_a_fixed_step(substeps):
    """Frames every 9.1 ms with a fixed 4 ms step: where the step does not divide the frame
    interval, the steps before each frame are fitted to it (two equal halves of what remains
    rather than a full step and a sliver, which builds almost no pressure and leaves the next
    step to start from half of it). No step is shorter than half the fixed step."""
    sim = dam(0.004, substeps=substeps)
    for k in range(1, 21):
        sim.advance(k * 0.0091 - sim.time)
        assert abs(sim.time - k * 0.0091) < 1e-9
    assert min(s["dt"] for s in sim.stats) >= 0.5 * 0.004
    assert max(s["dt"] for s in sim.stats) <= 0.004 * 1.05 + 1e-9


def test_a_run_with_steps_too_long_for_the_solve_warns_and_names_the_cure(tmp_path, capsys):
    """The solve's criterion is met on its linearised prediction, so a fixed step too long for
    it (substeps off) leaves the liquid compressed well above eta without a step stopping at
    max_iterations: the run's mean compression says so, and the command warns with the keys to
    change; the same scene at its CFL defaults does not warn."""
    from warp_iisph.cli import main

    path = tmp_path / "column.toml"
    path.write_text("""
spacing = 0.02
name = "column"
[tank]
lower = [0, 0, 0]
upper = [0.6, 0.5, 0.2]
[[fluids]]
lower = [0, 0, 0]
upper = [0.25, 0.4, 0.2]
""")
    out = str(tmp_path / "out")
    too_long = ["--set", "physics.dt=0.01", "--set", "physics.substeps=false"]
    for extra, warned in ((too_long, True), ([], False)):
        args = ["run", str(path), "--duration", "0.4", "--out", out, "--overwrite", "--no-progress"]
        assert main(args + extra) == 0
        err = capsys.readouterr().err
        assert ("too long for the pressure solve" in err) is warned, err
        if warned:
            assert "physics.dt (now 0.01 s) or set physics.substeps = true" in err


def test_the_compression_warning_names_the_setting_that_sets_the_steps():
    from warp_iisph.run.run_record import COMPRESSION_WARNING, run_warnings

    def warnings(compression, unconverged=0, probes=(), **physics):
        import dataclasses

        totals = {"steps": 100, "mean_compression": compression, "unconverged_steps": unconverged}
        totals["worst_unconverged_error"] = 0.01
        scene = {"physics": dataclasses.asdict(Physics(**physics)), "probes": [{"kind": k} for k in probes]}
        return run_warnings({"totals": totals, "scene": scene})

    eta = Physics().eta
    assert warnings(0.99 * COMPRESSION_WARNING * eta) == []
    assert "lower physics.cfl (now 0.5)" in warnings(1.01 * COMPRESSION_WARNING * eta)[0]
    assert "shorten physics.dt (now 0.003 s)" in warnings(0.01, dt=0.003)[0]
    assert "raise physics.max_iterations" in warnings(0.01, 3, dt=0.003, substeps=False)[1]
    assert warnings(0.01, method="wcsph") == []  # WCSPH's compression is set by its stiffness
    # pressure sensors beside Akinci's walls (a hostile pass: 30-36 % high at rest) are warned of
    assert warnings(0.0, probes=["pressure", "level"]) == []
    assert "1 pressure probe read the liquid's layer" in warnings(0.0, probes=["pressure"], method="dfsph")[0]
    assert 'physics.wall_pressure = "fluid"' in warnings(0.0, probes=["pressure"] * 2, wall_pressure="fluid")[0]
    assert warnings(0.0, probes=["level"], method="dfsph") == []


def test_step_rules_take_heights_along_gravity_whichever_way_it_points():
    """The same resting column, 0.8 m deep along gravity and 0.12 m across, with gravity along -y
    and along -x: the first step's length, a fixed step's substeps and the divergence limit are
    the same (they were taken from the y extent: along -x the 6 ms step was not cut and the
    column, never at rest, diverged at 0.18 s)."""
    sims = []
    for axis in (1, 0):
        deep = np.full(3, 0.12)
        deep[axis] = 0.8
        top = deep.copy()
        top[axis] += 0.1  # room above the water, along gravity
        gravity = [0.0, 0.0, 0.0]
        gravity[axis] = -G
        scene = Scene(spacing=0.02, tank=Box((0, 0, 0), tuple(top)), name="column")
        scene.physics = Physics(gravity=tuple(gravity), dt=0.006)
        scene.add_fluid_box((0, 0, 0), tuple(deep))
        sims.append(Simulation(scene, "cpu"))
    first = [sim.step() for sim in sims]
    assert first[0]["substeps"] == first[1]["substeps"] > 1
    assert first[0]["dt"] == pytest.approx(first[1]["dt"], rel=1e-9)
    assert sims[0].loop.velocity_limit == pytest.approx(sims[1].loop.velocity_limit, rel=1e-9)


def test_a_level_gauge_needs_gravity_along_minus_y():
    from warp_iisph import Probe

    scene = Scene(spacing=0.04, tank=Box((0, 0, 0), (0.4, 0.4, 0.4)), name="gauge")
    scene.add_fluid_box((0, 0, 0), (0.4, 0.2, 0.4))
    scene.add_probe(Probe("h", "level", position=(0.2, 0.2)))
    scene.physics = Physics(gravity=(-9.81, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"probes\[0\]: a level gauge reads the water's height along y"):
        scene.validate()


def test_a_liquid_too_small_for_the_default_viscosity_is_warned_about():
    """The default viscosity (a kinematic 0.01 m^2/s, ten thousand times water's) slows a small
    liquid's flow: Martin & Moyce's front at its own 11.4 cm column (sqrt(g H) H / nu = 12) runs a
    third slower than without viscosity (benchmarks/viscosity_scale.py), a 4 cm column (2.5) flows
    like honey (a hostile pass: its front crossed 3 cm in 0.15 s, not 0.04 s). Below 20 it is
    warned of, naming the key; every bundled scene (28 and more) is not."""
    import dataclasses

    from warp_iisph.run.run_record import liquid_reynolds, run_warnings
    from warp_iisph.scene import scene_to_dict
    from warp_iisph.scene.library import bundled_scenes

    def record(height, **physics):
        scene = {"physics": dataclasses.asdict(Physics(**physics))}
        scene["fluids"] = [{"shape": "box", "lower": [0, 0, 0], "upper": [0.02, height, 0.02]}]
        totals = {"steps": 10, "mean_compression": 0.0, "unconverged_steps": 0}
        return {"totals": totals, "scene": scene}

    (warning,) = run_warnings(record(0.04))
    assert "physics.viscosity = 0.05 (a kinematic 0.01 m^2/s)" in warning and "= 2.5," in warning
    (warning,) = run_warnings(record(0.114))
    assert "= 12.1, below 20" in warning and "lower physics.viscosity" in warning
    assert liquid_reynolds(record(0.114)["scene"]) == pytest.approx(12.05, abs=0.01)
    assert run_warnings(record(0.04, viscosity=0.002)) == [] and run_warnings(record(0.114, viscosity=0.01)) == []
    assert run_warnings(record(0.19)) == []  # 25.9
    for name in bundled_scenes():
        reynolds = liquid_reynolds(scene_to_dict(load_scene(name)))
        assert reynolds is None or reynolds > 25.0, name


def test_a_block_of_liquid_its_lattice_fills_short_or_over_is_warned_of():
    """A box holds the whole layers of the spacing that fit: 5 cm of water at 2 cm is 4 cm, 20 %
    short; below 90 % the run's warnings say so, naming the block (exactly 90 % is not below); a
    sphere outside 90-110 % too; no bundled scene is."""
    from warp_iisph.scene import scene_to_dict
    from warp_iisph.scene.library import bundled_scenes
    from warp_iisph.setup.fill import lattice_shortfalls, sphere_share

    shallow = {"lower": [0.0, 0.0, 0.0], "upper": [0.2, 0.05, 0.2]}
    ball = {"center": [0.5, 0.5, 0.5], "radius": 0.1}
    (warning,) = lattice_shortfalls({"spacing": 0.02, "fluids": [ball, shallow]})
    assert warning.startswith("fluids[1]: whole layers of spacing = 0.02 m fill only 80 % of it (0.2 x 0.04 x 0.2 m")
    assert "20 % short" in warning
    assert lattice_shortfalls({"spacing": 0.025, "fluids": [shallow]}) == []  # two whole layers
    assert lattice_shortfalls({"spacing": 0.03, "fluids": [{"lower": [0, 0, 0], "upper": [0.2, 0.03, 0.03]}]}) == []
    # a sphere holds the lattice points within its radius: over or short by the shells it cuts
    over = {"center": [0.3, 0.3, 0.3], "radius": 0.123}
    (warning,) = lattice_shortfalls({"spacing": 0.05, "fluids": [over]})
    assert warning.startswith("fluids[0]: the lattice of spacing = 0.05 m holds 130 % of this sphere's volume")
    assert "30 % over; a radius of 0.1194 m holds its volume within 1 %" in warning
    assert sphere_share(0.1194, 0.05) == pytest.approx(1.0, abs=0.01)
    assert lattice_shortfalls({"spacing": 0.02, "fluids": [ball]}) == []  # 93 %
    for name in bundled_scenes():
        assert lattice_shortfalls(scene_to_dict(load_scene(name))) == [], name


def test_the_choices_a_scene_leaves_unset_resolve_by_method_and_bodies():
    """``Physics.resolved`` (run.json's ``resolved``): IISPH's warm start where unset by gravity,
    the walls' gradient by whether the scene has free bodies; DFSPH's walls are Akinci's whatever
    is set, and so are the ``"fluid"`` wall pressure's."""
    assert Physics().resolved() == {"warm_start": "hydrostatic", "wall_gradient": "akinci"}
    assert Physics().resolved(free_bodies=True) == {"warm_start": "hydrostatic", "wall_gradient": "completed"}
    assert Physics(gravity=(0.0, 0.0, 0.0)).resolved(True) == {"warm_start": "half", "wall_gradient": "completed"}
    set_ = Physics(warm_start="half_hydrostatic", wall_gradient="completed").resolved()
    assert set_ == {"warm_start": "half_hydrostatic", "wall_gradient": "completed"}
    assert Physics(method="dfsph", wall_gradient="completed").resolved(True) == {
        "warm_start": None,
        "wall_gradient": "akinci",
    }
    assert Physics(wall_pressure="fluid").resolved(True)["wall_gradient"] == "akinci"
    assert Physics(method="wcsph").resolved(True) == {"warm_start": None, "wall_gradient": "completed"}
