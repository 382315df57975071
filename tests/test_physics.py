"""Physics against physics: hydrostatic pressure, the Martin & Moyce dam break, stability."""

import numpy as np
import pytest
import warp as wp

from warp_iisph import Box, DivergenceError, Physics, Scene, Simulation, scenes
from warp_iisph.analysis.dam_break import load_martin_moyce, surge_front
from warp_iisph.analysis.hydrostatic import hydrostatic_slope
from warp_iisph.scene import load_scene

G = 9.81


def test_water_at_rest_holds_hydrostatic_pressure_every_step():
    """Water at rest in a closed tank (2,000 particles, 20 layers, the defaults): after settling,
    at every step the pressure fitted over the interior (two spacings from the walls) grows as
    rho0 g depth within 3 % (it has to carry the column's weight: momentum balance), also on the
    steps shortened to land on frame times; the water stays at rest and no particle needs putting
    back. The layer on the floor is compressed by at most twice the solver's tolerance eta (with
    Akinci's walls it carried twice the pressure, and more). The solve ends where its error
    reaches eta: relaxed Jacobi leaves a long-wave error, whose pressure the step's last
    iteration would otherwise move by percents with the iteration count."""
    sim = settled_resting_tank()
    rows = []
    while sim.time < 2.3 - 1e-9:  # every step of the CFL rule
        rows.append(at_rest(sim, sim.step()))
    for frame in range(70, 73):  # frames of a 30 fps run: each ends on a step fitted to land there
        sim.advance(frame / 30.0 - sim.time)
        rows.append(at_rest(sim, sim.stats[-1]))
    slopes, mean_speed, max_speed, bottom = (np.asarray(c) for c in zip(*rows))
    assert np.all(np.abs(slopes - 1.0) <= 0.03), (slopes.min(), slopes.max())
    assert max(mean_speed) < 0.01  # m/s: at rest
    assert max(max_speed) < 0.1
    assert max(bottom) <= 2 * sim.physics.eta


REST_SPACING, REST_TANK, REST_DEPTH = 0.02, (0.2, 0.5, 0.2), 0.4  # 2,000 particles, 20 layers


def test_resting_pressure_holds_still_through_frame_landings():
    """The settled tank run on frame by frame (30 frames/s, as a run writes them): the hydrostatic
    slope at every step, those landing on a frame and those right after included, stays within
    1 % of its own mean. The steps into a landing are equal; a landing cut as full steps and two
    halves kicked resting water's pressure by several per cent at every frame (the pressure's
    response to the state's compression grows as 1/dt^2). At the defaults (the hydrostatic warm
    start) each step takes at most 5 iterations."""
    sim = settled_resting_tank()
    slopes = []
    first = int(np.ceil(sim.time * 30.0)) + 1
    for frame in range(first, first + 4):
        sim.advance(frame / 30.0 - sim.time, callback=lambda rec: slopes.append(at_rest(sim, rec)[0]))
    slopes = np.asarray(slopes)
    assert np.all(np.abs(slopes / slopes.mean() - 1.0) <= 0.01), slopes
    assert max(s["iterations"] for s in sim.stats[-len(slopes) :]) <= 5


def test_a_changed_step_length_moves_resting_pressure_less_from_the_hydrostatic_start():
    """The settled tank stepped by hand at 2 ms and back at the CFL rule's step (3.6 ms): the
    slope's largest departure from its own mean stays under 3 % from the hydrostatic start (the
    default, which keeps nothing of the last step's pressure; 2.7 % measured) and under half the
    half start's (7.7 %): what remains is the solve's response to the compression left at eta,
    which grows as 1/dt^2 (benchmarks/step_change.py, docs/pressure_solve.md)."""
    spread = {}
    for warm_start in ("hydrostatic", "half"):
        sim = settled_resting_tank(warm_start=warm_start)
        dt = sim.stats[-1]["dt"]
        slopes = np.asarray([at_rest(sim, sim.step(step))[0] for step in [2e-3] * 6 + [dt] * 6])
        spread[warm_start] = float(np.abs(slopes / slopes.mean() - 1.0).max())
    assert spread["hydrostatic"] <= 0.03, spread
    assert spread["hydrostatic"] <= 0.5 * spread["half"], spread


def settled_resting_tank(**physics) -> Simulation:
    """Water 0.4 m deep at rest in a closed tank, after 2 s of settling (``physics``: settings
    other than the defaults)."""
    scene = Scene(
        spacing=REST_SPACING, tank=Box((0.0, 0.0, 0.0), REST_TANK), physics=Physics(**physics), name="resting_tank"
    )
    scene.add_fluid_box((0.0, 0.0, 0.0), (REST_TANK[0], REST_DEPTH, REST_TANK[2]))
    sim = Simulation(scene, "cpu")
    while sim.time < 2.0:
        sim.step()
    return sim


def at_rest(sim: Simulation, rec: dict) -> tuple[float, float, float, float]:
    """A step of the settled tank (no particle lost or put back): the hydrostatic slope over the
    interior in units of rho0 g, mean and largest speed, and the floor layer's compression."""
    assert rec["escaped"] == rec["non_finite"] == rec["wall_corrections"] == 0
    h, x, speed = REST_SPACING, sim.positions, np.linalg.norm(sim.velocities, axis=1)
    slope = hydrostatic_slope(x, sim.pressures, h, (0.0, 0.0, 0.0), REST_TANK, 1000.0, G)
    return slope, float(speed.mean()), float(speed.max()), float(sim.densities[x[:, 1] < h].mean() / 1000.0 - 1.0)


def _martin_moyce_front(nx: int, a: float = 0.3, t_max: float = 3.0, **physics):
    """The benchmark's Martin & Moyce column (a wide, 2a high, in a 6a x 3a x 0.5a tank) at nx
    particles across: the experiment's T <= t_max, Z = front / a there, and the experiment's Z."""
    h = a / nx
    scene = Scene(
        spacing=h, tank=Box((0.0, 0.0, 0.0), (6 * a, 3 * a, 0.5 * a)), physics=Physics(**physics), name="martin_moyce"
    )
    scene.add_fluid_box((0.0, 0.0, 0.0), (a, 2 * a, 0.5 * a))
    sim = Simulation(scene, "cpu")
    pts = np.concatenate(list(load_martin_moyce().values()))
    pts = pts[pts[:, 0] <= t_max]
    pts = pts[np.argsort(pts[:, 0])]
    Z = []
    for T, _ in pts:
        sim.advance(T / np.sqrt(2 * G / a) - sim.time)
        Z.append(surge_front(sim.positions, h) / a)
    assert all(s["escaped"] == 0 and s["non_finite"] == 0 for s in sim.stats)
    return pts[:, 0], np.asarray(Z), pts[:, 1]


def test_dam_break_front_between_experiment_and_shallow_water():
    """Martin & Moyce (1952), a = 0.3 m at nx = 12, the defaults. The front cannot outrun the
    dry-bed shallow-water front Z = 1 + 2T (Ritter 1892: no vertical acceleration, nothing
    dissipated), and with no gate to lift, no surface tension and free-slip walls it should not
    lag the experiment (5 % allowed for reading the paper's figure)."""
    T, Z, Z_exp = _martin_moyce_front(12)
    assert np.all(Z <= 1.0 + 2.0 * T), Z
    assert np.all(Z >= 0.95 * Z_exp), Z / Z_exp


def test_viscosity_slows_the_front():
    """Without viscosity the same column spreads faster: at no sample is the inviscid front
    behind the viscous one, and on average it is ahead."""
    _, Z_visc, _ = _martin_moyce_front(12, t_max=2.0)
    _, Z_inv, _ = _martin_moyce_front(12, t_max=2.0, viscosity=0.0)
    assert np.all(Z_inv >= Z_visc - 0.02) and Z_inv.mean() > Z_visc.mean()


def test_an_inviscid_dam_break_is_the_same_at_every_size_and_the_default_viscosity_is_not():
    """Under gravity an inviscid flow scales with its size (Froude scaling): Martin & Moyce's
    column at a = 0.3 m and at the experiment's own 5.7 cm, without viscosity, give one front
    Z(T) (within 0.0007 a measured; a length or time fixed in the method, not the scene's, would
    show here). The default viscosity, a fixed kinematic 0.01 m^2/s, is not scaled with them: the
    small column's front lags the large one's (by 11 % on average measured, 16 % at T = 2), which
    is what the small-liquid warning and docs/physics.md 6.6 say."""
    fronts = {
        (a, mu): _martin_moyce_front(12, a=a, t_max=2.0, **({} if mu is None else {"viscosity": mu}))[1]
        for a in (0.3, 0.05715)
        for mu in (0.0, None)
    }
    assert np.abs(fronts[0.3, 0.0] - fronts[0.05715, 0.0]).max() < 0.005, fronts
    lag = fronts[0.05715, None] / fronts[0.3, None]
    assert lag.mean() < 0.95 and lag.min() < 0.9, lag


def test_iisph_stable_where_wcsph_diverges():
    """The same dam break at a fixed 4 ms step, taken as it is (no substeps): WCSPH (k = 50 kPa,
    its usual stiffness; its sound-speed limit is 0.5 ms) blows up, IISPH stays bounded with no
    particle lost."""
    dt = 0.004
    with pytest.raises(DivergenceError) as info:
        Simulation(scenes.martin_moyce(spacing=0.02, method="wcsph", dt=dt, substeps=False), "cpu").advance(0.4)
    assert info.value.step > 0 and "step" in str(info.value)
    sim = Simulation(scenes.martin_moyce(spacing=0.02, method="iisph", dt=dt, substeps=False), "cpu")
    sim.advance(0.4)
    assert all(s["escaped"] == 0 and s["non_finite"] == 0 for s in sim.stats)
    free_fall = np.sqrt(2 * G * 0.4)  # the column is 0.4 m high
    assert max(s["max_velocity"] for s in sim.stats) < 3.0 * free_fall
    assert np.mean([s["compression"] for s in sim.stats]) < 0.01


def test_fine_dam_break_starts_from_rest_without_blowing_up():
    """At a/h = 20 the first steps from rest are no longer than the CFL rule at the free-fall
    speed sqrt(2 g H) (dt_max, 5 ms, is dt/h = 1 s/m there, beyond IISPH's linearised
    prediction), and the run stays bounded."""
    h, a = 0.005, 0.1
    sim = Simulation(scenes.martin_moyce(spacing=h, a=a, depth=4 * h, length=5 * a, height=2.5 * a), "cpu")
    sim.advance(0.1)
    assert sim.stats[0]["dt"] <= 0.5 * h / np.sqrt(2 * G * 2 * a) + 1e-9
    assert all(s["escaped"] == 0 and s["non_finite"] == 0 for s in sim.stats)


@pytest.mark.parametrize("spacing,depth", [(0.04, 0.1), (0.03, 0.1), (0.02, 0.1)])
def test_tank_not_a_multiple_of_h_starts_at_rest(spacing, depth):
    """Walls sampled closer than h (the side is not a multiple of h) still sit h/2 outside the
    faces: a tiny first step does not kick the fluid (walls closer than h/2 shot it out at tens
    of m/s)."""
    sim = Simulation(scenes.martin_moyce(spacing=spacing, a=0.2, depth=depth, dt=1e-4), "cpu")
    rec = sim.step()
    assert rec["max_velocity"] < 0.05 and rec["compression"] < 1e-4


@pytest.mark.parametrize("warm_start", ["hydrostatic", "half_hydrostatic"])
def test_the_hydrostatic_warm_starts_take_fewer_iterations_at_the_same_tolerance(warm_start):
    """The Martin & Moyce column's first 0.5 s from the hydrostatic starts takes at most half the
    iterations of the half warm start (0.7 times from the gated one, the default, whose floor is 4
    iterations), its mean compression stays at most eta, no particle is put back, and its front is
    within 3 % of the half warm start's (the gated one's within 1 %: an ungated start keeps an
    over-pressure in the collapsing column)."""
    runs = {}
    for start in ("half", warm_start):
        sim = Simulation(scenes.martin_moyce(spacing=0.02, warm_start=start), "cpu")
        sim.advance(0.5)
        st = sim.stats
        runs[start] = (
            np.mean([s["iterations"] for s in st]),
            np.mean([s["compression"] for s in st]),
            sum(s["wall_corrections"] + s["obstacle_corrections"] for s in st),
            surge_front(sim.positions, 0.02),
        )
    (it_half, _, _, front_half), (it_start, comp, put_back, front) = runs["half"], runs[warm_start]
    assert it_start <= (0.7 if warm_start == "hydrostatic" else 0.5) * it_half, runs
    assert comp <= 1e-3 and put_back == 0, runs
    assert abs(front / front_half - 1.0) < (0.01 if warm_start == "hydrostatic" else 0.03), runs


@pytest.mark.parametrize("warm_start", ["hydrostatic", "half_hydrostatic"])
def test_the_hydrostatic_warm_starts_keep_water_at_rest(warm_start):
    """Water settled from a hydrostatic start rests (mean speed under 1 cm/s, none above 10 cm/s)
    at its floor of iterations (4 from the gated start, 2 from the half-and-half one), its slope
    within 5 % of rho0 g; from the gated start, the default, within 1 % of its own mean at every
    step (the half-and-half start wanders by a few per cent)."""
    sim = settled_resting_tank(warm_start=warm_start)
    rows = [at_rest(sim, sim.step()) for _ in range(20)]
    slopes, mean_speed, max_speed, _ = (np.asarray(c) for c in zip(*rows))
    assert np.all(np.abs(slopes - 1.0) <= 0.05), slopes
    assert max(mean_speed) < 0.01 and max(max_speed) < 0.1
    assert all(s["iterations"] <= (5 if warm_start == "hydrostatic" else 3) for s in sim.stats[-20:])
    if warm_start == "hydrostatic":
        assert np.all(np.abs(slopes / slopes.mean() - 1.0) <= 0.01), slopes


def test_the_hydrostatic_warm_start_is_the_default_where_gravity_points_along_an_axis():
    """Unset, physics.warm_start resolves to the hydrostatic start (with its floor of 4 iterations)
    where gravity points along an axis, free bodies or not, and to the half start (floor 2)
    otherwise; a value set is kept."""
    assert Physics().pressure_start() == "hydrostatic" and Physics().iteration_floor() == 4
    assert Physics(gravity=(0.0, 0.0, 0.0)).pressure_start() == "half"
    assert Physics(gravity=(1.0, -9.81, 0.0)).pressure_start() == "half"
    assert Physics(warm_start="half").pressure_start() == "half" and Physics(warm_start="half").iteration_floor() == 2
    assert Physics(method="dfsph").iteration_floor() == 2 and Physics(min_iterations=3).iteration_floor() == 3
    assert Simulation(load_scene("flood"), "cpu").solver.warm_start == "hydrostatic"  # it has free bodies
    assert Simulation(load_scene("dam_break"), "cpu").solver.warm_start == "hydrostatic"


def test_a_box_sampled_by_faces_has_its_wall_at_its_inner_boundary_layer():
    """The last line (sph/containment.py) puts a particle back where it passed a wall's inner layer
    of boundary particles, as at the tank's walls: for a box obstacle sampled by faces that layer is
    h/2 inside the faces, so a particle whose centre is a quarter spacing past a face is left to the
    pressure and one 0.75 h past it is put back onto the layer. The bundled spheric_test2's put-backs
    at its box were all of the first kind (less than h/4 past the face)."""
    import trimesh

    from warp_iisph.sph.containment import CLEARANCE, Containment
    from warp_iisph.sph.neighbors import NeighborListBuffer

    h = 0.02
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.2))  # faces at +-0.1
    walls = Containment("cpu", None, [(box.vertices, box.faces, -1, False, 0.5 * h)], spacing=h)
    near = NeighborListBuffer(2, "cpu", capacity=2)
    near.lists.count.fill_(1)  # both had wall neighbours at the step's start
    x = wp.array([[0.1 - 0.25 * h, 0.0, 0.0], [0.1 - 0.75 * h, 0.0, 0.0]], dtype=wp.vec3, device="cpu")
    v = wp.array([[-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], dtype=wp.vec3, device="cpu")
    walls.apply(x, v, near.lists, 2, wp.array([1e-3], dtype=wp.float64, device="cpu"))
    assert walls.corrections.numpy().tolist() == [0, 1]
    np.testing.assert_allclose(x.numpy()[0], [0.1 - 0.25 * h, 0.0, 0.0], atol=1e-7)  # left to the pressure
    np.testing.assert_allclose(x.numpy()[1], [0.1 - 0.5 * h + CLEARANCE * h, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(v.numpy(), [[-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], atol=1e-6)  # into the wall: removed

    scene = Scene(spacing=h, tank=Box((0, 0, 0), (0.4, 0.3, 0.2)), name="walls")
    scene.add_fluid_box((0, 0, 0), (0.1, 0.1, 0.2))
    scene.add_obstacle(Box((0.2, 0.0, 0.06), (0.28, 0.08, 0.14), sampling="faces"))
    scene.add_obstacle(Box((0.3, 0.0, 0.06), (0.38, 0.08, 0.14), sampling="cells"))
    depth = Simulation(scene, "cpu").model.containment.solids.depth.numpy()
    np.testing.assert_allclose(depth, [0.5 * h, 0.0])
