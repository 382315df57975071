"""The walls' extrapolated pressure (physics.wall_pressure) and fixed steps cut into substeps
(physics.substeps): physics first, then the plain, graph and resumed paths agreeing bitwise."""

import numpy as np
import pytest

from warp_iisph import Box, Physics, Scene, Simulation, scenes
from warp_iisph.stepping.time_loop import viscous_dt_limit

G = 9.81


def floor_layer_over_hydrostatic(wall_pressure: str) -> float:
    """Water 0.3 m deep in a 0.16 x 0.4 x 0.16 m tank at 2 cm (960 particles), settled 1 s, then
    over 0.4 s of steps: the mean pressure of the layer touching the floor, away from the side
    walls, over rho0 g times its depth below the top layer (whose pressure is zero: the solver
    clamps the under-dense free surface at p = 0). Averaged over steps, as the column still
    breathes a little from step to step."""
    h = 0.02
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (0.16, 0.4, 0.16)), physics=Physics(wall_pressure=wall_pressure),
                  name="resting_column")
    scene.add_fluid_box((0.0, 0.0, 0.0), (0.16, 0.3, 0.16))
    sim = Simulation(scene, "cpu")
    sim.advance(1.0)
    ratios = []
    while sim.time < 1.4 - 1e-9:
        sim.step()
        x, p = sim.positions, sim.pressures
        top = np.sort(x[:, 1])[-len(x) // 15:].mean()  # the top layer (15 layers)
        inner = np.all((x[:, [0, 2]] > 1.5 * h) & (x[:, [0, 2]] < 0.16 - 1.5 * h), axis=1)
        floor = inner & (x[:, 1] < h)
        ratios.append(np.mean(p[floor]) / (1000.0 * G * np.mean(top - x[floor, 1])))
    return float(np.mean(ratios))


def test_extrapolated_walls_hold_the_floor_layer_at_hydrostatic_pressure():
    """Momentum balance at a wall: the layer on the floor carries the column above it. With the
    walls pushing with the fluid's own pressure in one term (Akinci, "fluid"), that layer needs
    about twice the hydrostatic pressure to hold it; with the pressure extrapolated into the wall
    it needs the hydrostatic pressure."""
    ratio = {w: floor_layer_over_hydrostatic(w) for w in ("extrapolated", "fluid")}
    assert abs(ratio["extrapolated"] - 1.0) < 0.1, ratio
    assert ratio["fluid"] > 1.4, ratio


def dam(dt: float, substeps: bool = True, graph: bool = False) -> Simulation:
    return Simulation(scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1, dt=dt, substeps=substeps), "cpu", graph=graph)


def test_a_fixed_step_is_cut_into_substeps_that_land_on_it():
    """A fixed 20 ms step on a 2 cm dam break is longer than the viscosity's limit allows
    (0.4 h^2 / mu = 3.2 ms): every step taken is within the limit, the substeps of one fixed
    step are equal, and their ends land on the multiples of 20 ms."""
    dt = 0.02
    sim = dam(dt)
    sim.advance(0.2)
    limit = viscous_dt_limit(sim.model.spacing, sim.physics)
    st = sim.stats
    assert all(s["dt"] <= limit * (1 + 1e-6) for s in st)
    assert min(s["substeps"] for s in st) >= int(np.ceil(dt / limit))
    ends = [s["t"] for s in st if abs(s["t"] / dt - round(s["t"] / dt)) < 1e-6]
    assert len(ends) == 10 and abs(sim.time - 0.2) < 1e-9
    t0 = 0.0
    for end in ends:  # the steps between two ends are equal pieces of one fixed step
        piece = [s["dt"] for s in st if t0 + 1e-9 < s["t"] <= end + 1e-9]
        assert len(piece) == int(piece and next(s["substeps"] for s in st if t0 + 1e-9 < s["t"] <= end + 1e-9))
        assert max(piece) - min(piece) < 1e-6 * dt and abs(sum(piece) - dt) < 1e-6 * dt
        t0 = end


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
    for _ in range(9):
        whole.step()
    assert whole.stats[-1]["substeps"] > 1 and abs(whole.time / 0.02 - round(whole.time / 0.02)) > 1e-3  # mid-way through a cut step
    saved = whole.checkpoint()
    resumed = dam(0.02)
    resumed.restore(saved)
    whole.advance(0.06)
    resumed.advance(0.06)
    np.testing.assert_array_equal(resumed.positions, whole.positions)
    assert [s["dt"] for s in resumed.stats] == [s["dt"] for s in whole.stats][-len(resumed.stats):]


@pytest.mark.parametrize("value", ["mirror", 1, None])
def test_wall_pressure_must_be_a_known_name(value):
    with pytest.raises(ValueError, match="physics.wall_pressure"):
        Physics(wall_pressure=value).validate()
