"""Graph capture (record once, replay) against the plain launches it records: one step
(``Simulation.step``) and the device-side loop over steps (``Simulation.advance``)."""

import numpy as np
import pytest

from warp_iisph import DivergenceError, Simulation, scenes
from warp_iisph.cli import main

from conftest import requires_cuda


def run(scene, graph: bool, duration: float = 0.15, device: str = "cpu", shrink_lists: bool = False):
    sim = Simulation(scene, device, graph=graph)
    sim.step()
    if shrink_lists:  # far too little neighbour storage: the next step overflows and is redone
        sim.solver.search.fluid.grow(100)
    sim.advance(duration)
    return sim


@pytest.mark.parametrize("method", ["iisph", "wcsph"])
def test_captured_step_equals_plain_launches(method):
    scene = lambda: scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1, method=method, viscosity=1e-4, boundary_viscosity=0.003)  # noqa: E731
    plain, graph = run(scene(), False), run(scene(), True)
    frames = graph._frames
    assert frames.captures == 1 and graph.step_count == plain.step_count > 20
    assert frames.replays == -(-(graph.step_count - 1) // frames.capacity)  # one per 256 steps, no host sync between
    np.testing.assert_array_equal(graph.positions, plain.positions)
    np.testing.assert_array_equal(graph.velocities, plain.velocities)
    for key in ("dt", "iterations", "density_error", "compression", "max_velocity"):
        assert [s[key] for s in graph.stats] == [s[key] for s in plain.stats], key
    if method == "iisph":
        assert max(s["iterations"] for s in graph.stats) > 2  # the device-side loop ran to convergence


def test_neighbour_overflow_inside_the_graph_is_redone():
    scene = lambda: scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1)  # noqa: E731
    plain, graph = run(scene(), False), run(scene(), True, shrink_lists=True)
    assert graph._frames.redone == 1 and graph._frames.captures == 2
    np.testing.assert_array_equal(graph.positions, plain.positions)


def test_single_captured_steps_and_a_short_log_match_plain():
    """Simulation.step replays a one-step graph; a log of 8 steps makes advance replay often."""
    from warp_iisph.stepping.graph import FrameGraph

    scene = lambda: scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1)  # noqa: E731
    plain, graph = Simulation(scene(), "cpu"), Simulation(scene(), "cpu", graph=True)
    for _ in range(12):  # crosses a reorder (every 10 steps)
        plain.step()
        graph.step()
    assert graph.stepper.captures == 1
    graph._frames = FrameGraph(graph, log_capacity=8)
    plain.advance(0.1)
    graph.advance(0.1)
    assert graph._frames.replays >= 3 and graph.step_count == plain.step_count
    np.testing.assert_array_equal(graph.positions, plain.positions)
    assert [s["t"] for s in graph.stats] == [s["t"] for s in plain.stats]


def test_divergence_is_caught_in_graph_mode():
    sim = Simulation(scenes.martin_moyce(spacing=0.04, a=0.2, depth=0.1, method="wcsph", dt=0.02), "cpu", graph=True)
    with pytest.raises(DivergenceError) as e:
        sim.advance(1.0)
    assert e.value.step == sim.step_count < 50  # the loop on the device stopped at the failing step


def test_cli_graph_flag(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "martin_moyce", "--duration", "0.05", "--spacing", "0.04", "--graph", "--out", str(out), "--no-progress"]) == 0
    assert '"graph": true' in (out / "run.json").read_text()


@requires_cuda
def test_cuda_graph_matches_cpu():
    scene = lambda: scenes.martin_moyce(spacing=0.02, a=0.2, depth=0.1)  # noqa: E731
    cpu, cuda = run(scene(), False, 0.1), run(scene(), True, 0.1, device="cuda")
    assert cuda.step_count == cpu.step_count
    assert np.max(np.abs(cuda.positions - cpu.positions)) < 0.02  # GPU atomics and FMA reorder sums
