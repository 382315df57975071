"""Graph capture (record once, replay) against the plain launches it records: one step
(``Simulation.step``) and the device-side loop over steps (``Simulation.advance``)."""

import numpy as np
import pytest
from conftest import requires_cuda

from warp_iisph import DivergenceError, Simulation, scenes
from warp_iisph.cli import main


def run(scene, graph: bool, duration: float = 0.15, device: str = "cpu", shrink_lists: bool = False):
    sim = Simulation(scene, device, graph=graph)
    sim.step()
    if shrink_lists:  # far too little neighbour storage: the next step overflows and is redone
        sim.solver.search.fluid.grow(100)
    sim.advance(duration)
    return sim


@pytest.mark.parametrize(
    "method, warm_start",
    [("iisph", "hydrostatic"), ("iisph", "half"), ("iisph", "half_hydrostatic"), ("wcsph", None), ("dfsph", None)],
)
def test_captured_step_equals_plain_launches(method, warm_start):
    def scene():
        return scenes.martin_moyce(
            spacing=0.02,
            a=0.2,
            depth=0.1,
            method=method,
            viscosity=1e-4,
            boundary_viscosity=0.003,
            warm_start=warm_start,
        )

    plain, graph = run(scene(), False), run(scene(), True)
    replays = graph.graph
    assert replays.captures == 1 and graph.step_count == plain.step_count > 20
    assert replays.replays == -(
        -(graph.step_count - 1) // graph.loop.capacity
    )  # one per 256 steps, no host sync between
    np.testing.assert_array_equal(graph.positions, plain.positions)
    np.testing.assert_array_equal(graph.velocities, plain.velocities)
    for key in ("dt", "iterations", "density_error", "compression", "max_velocity"):
        assert [s[key] for s in graph.stats] == [s[key] for s in plain.stats], key
    if method != "wcsph":
        assert max(s["iterations"] for s in graph.stats) > 2  # the device-side loop ran to convergence
    if method == "dfsph":
        assert [s["divergence_iterations"] for s in graph.stats] == [s["divergence_iterations"] for s in plain.stats]
        assert max(s["divergence_iterations"] for s in graph.stats) > 1


def test_neighbour_overflow_inside_the_graph_is_redone():
    scene = lambda: scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1)  # noqa: E731
    plain, graph = run(scene(), False), run(scene(), True, shrink_lists=True)
    assert graph.graph.redone == 1 and graph.graph.captures == 2
    np.testing.assert_array_equal(graph.positions, plain.positions)


def test_single_captured_steps_and_a_short_log_match_plain():
    """Simulation.step replays the loop limited to one step; a log of 8 steps makes advance replay often."""
    from warp_iisph.stepping.graph import LoopGraph
    from warp_iisph.stepping.time_loop import TimeLoop

    scene = lambda: scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1)  # noqa: E731
    plain, graph = Simulation(scene(), "cpu"), Simulation(scene(), "cpu", graph=True)
    for _ in range(12):  # crosses a reorder (every 10 steps)
        plain.step()
        graph.step()
    assert graph.graph.captures == 1 and graph.graph.replays == 11  # the first step is plain
    old = graph.loop
    graph.loop = TimeLoop(old.model, old.state, old.solver, old.velocity_scale, old.velocity_limit, log_capacity=8)
    graph.graph = LoopGraph(graph.loop)
    plain.advance(0.1)
    graph.advance(0.1)
    assert graph.graph.replays >= 3 and graph.step_count == plain.step_count
    np.testing.assert_array_equal(graph.positions, plain.positions)
    assert [s["t"] for s in graph.stats] == [s["t"] for s in plain.stats]


def test_divergence_is_caught_in_graph_mode():
    sim = Simulation(
        scenes.martin_moyce(spacing=0.04, a=0.2, depth=0.1, method="wcsph", dt=0.02, substeps=False), "cpu", graph=True
    )
    with pytest.raises(DivergenceError) as e:
        sim.advance(1.0)
    assert e.value.step == sim.step_count < 50  # the loop on the device stopped at the failing step


def test_cli_graph_flag(tmp_path):
    out = tmp_path / "run"
    assert (
        main(
            [
                "run",
                "martin_moyce",
                "--duration",
                "0.05",
                "--spacing",
                "0.04",
                "--graph",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    assert '"graph": true' in (out / "run.json").read_text()


@requires_cuda
@pytest.mark.parametrize("method", ["iisph", "wcsph", "dfsph"])
def test_cuda_graph_matches_cpu(method):
    scene = lambda: scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1, method=method)  # noqa: E731
    cpu, cuda = run(scene(), False, 0.1), run(scene(), True, 0.1, device="cuda")
    # GPU atomics and FMA reorder sums: CFL steps and iteration counts may differ by one
    assert abs(cuda.step_count - cpu.step_count) <= max(1, cpu.step_count // 50)
    assert np.max(np.abs(cuda.positions - cpu.positions)) < 0.02


@pytest.mark.parametrize(
    "method, warm_start", [("iisph", "hydrostatic"), ("iisph", "half"), ("iisph", "half_hydrostatic"), ("dfsph", None)]
)
def test_nothing_in_a_conditional_body_allocates(conditional_body_allocations, method, warm_start):
    """On CUDA, a conditional body of a graph (the loop over steps, the reorder's capture_if, the
    Jacobi loops of IISPH and of DFSPH's two solves) may not allocate (the conftest fixture
    makes every allocation fail while one is recorded)."""
    calls = conditional_body_allocations
    # a scene with walls, an obstacle and a free body (its loads with wall friction, its contacts
    # with the floor) near the fluid: fluid, wall, body and reorder paths all recorded
    from warp_iisph import Box

    scene = scenes.martin_moyce(
        spacing=0.02, a=0.2, depth=0.1, method=method, warm_start=warm_start, boundary_viscosity=0.003
    )
    scene.add_obstacle(Box((0.3, 0.0, 0.0), (0.35, 0.1, 0.1)))
    scene.add_body(Box((0.21, 0.0, 0.02), (0.27, 0.06, 0.08)), density=700.0)
    sim = Simulation(scene, "cpu", graph=True)
    sim.advance(0.05)
    assert sim.graph.captures == 1 and sim.graph.replays >= 1 and not calls
    assert np.linalg.norm(sim.bodies["velocity"][0]) > 0  # the body moved: its update was recorded
    assert max(s["iterations"] for s in sim.stats) >= 2


def test_graphs_are_the_default_on_cuda_only(tmp_path):
    from warp_iisph.cli import use_graph

    assert use_graph(None, "cuda:0") and not use_graph(None, "cpu")
    assert not use_graph(False, "cuda:0") and use_graph(True, "cpu")
    out = tmp_path / "run"
    assert (
        main(["run", "martin_moyce", "--duration", "0.05", "--spacing", "0.04", "--out", str(out), "--no-progress"])
        == 0
    )
    assert '"graph": false' in (out / "run.json").read_text()
    assert (
        main(
            [
                "run",
                "martin_moyce",
                "--duration",
                "0.05",
                "--spacing",
                "0.04",
                "--no-graph",
                "--overwrite",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
