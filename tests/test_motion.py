"""Moving obstacles: keyframes evaluated the same on the host and the device, a body pushed
through still water leaves no particle inside it at any step, and it drags the water along."""

import numpy as np
import pytest
import warp as wp

from warp_iisph import Box, Scene, Simulation
from warp_iisph.scene.motion import Motion, rotation_xyz
from warp_iisph.sph.bodies import BodyKeys, MovingBodies, body_place


@wp.kernel
def place_points(keys: BodyKeys, rest: wp.array(dtype=wp.vec3), t: wp.float64, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = body_place(keys, 0, t, rest[i])


@pytest.mark.parametrize("interpolation", ["linear", "smooth"])
def test_device_keyframes_match_the_scene_motion(interpolation):
    m = Motion(
        times=[0.0, 0.5, 1.0, 2.0],
        translate=[[0, 0, 0], [0.3, 0.1, 0], [0.6, 0.1, 0.2], [1.0, 0, 0]],
        rotate=[[0, 0, 0], [10, 0, 0], [0, 45, 0], [0, 90, 30]],
        pivot=(0.2, 0.3, 0.1),
        interpolation=interpolation,
    )
    m.validate("m")
    rest = np.random.default_rng(0).uniform(-0.5, 0.5, (64, 3))
    bodies = MovingBodies([m], rest, np.zeros(len(rest), int), 0, "cpu")
    for t in (0.0, 0.2, 0.5, 0.77, 1.0, 1.5, 2.0, 3.0):
        out = wp.zeros(len(rest), dtype=wp.vec3, device="cpu")
        wp.launch(place_points, dim=len(rest), inputs=[bodies.keys, bodies.rest, wp.float64(t), out], device="cpu")
        M = m.matrix(t, np.asarray(m.pivot))
        np.testing.assert_allclose(out.numpy(), rest @ M[:3, :3].T + M[:3, 3], atol=2e-6)
    # the keys are met exactly; outside them the body holds still
    np.testing.assert_allclose(m.at(0.5)[0], [0.3, 0.1, 0])
    np.testing.assert_allclose(m.at(5.0)[1], [0, 90, 30])
    np.testing.assert_allclose(rotation_xyz([0, 90, 0]) @ [1, 0, 0], [0, 0, -1], atol=1e-12)


def post_scene(spacing=0.04, duration=1.0) -> Scene:
    """A post pushed along a shallow tank, accelerating to about 0.6 m/s (the bundled wake scene,
    coarser)."""
    scene = Scene(spacing=spacing, tank=Box((0, 0, 0), (1.6, 0.4, 0.4)), name="post")
    scene.add_fluid_box((0, 0, 0), (1.6, 0.2, 0.4))
    scene.add_obstacle(
        Box(
            (0.2, 0.0, 0.14),
            (0.32, 0.36, 0.26),
            motion=Motion(times=[0.0, 0.3, 1.0], translate=[[0, 0, 0], [0.08, 0, 0], [0.5, 0, 0]]),
        )
    )
    scene.output.duration = duration
    return scene


def test_a_moving_post_lets_no_particle_in_and_pushes_the_water():
    sim = Simulation(post_scene(), "cpu")
    sim.advance(0.8)
    # measured every step: the solver kept every particle out of the moving body (the last-line
    # projection had nothing to do there)
    assert len(sim.stats) > 100 and all(s["obstacle_corrections"] == 0 for s in sim.stats)
    m = sim.scene.obstacles[0].motion
    front = 0.32 + m.at(0.8)[0][0]
    x, v = sim.positions, sim.velocities
    ahead = (x[:, 0] > front) & (x[:, 0] < front + 0.08) & (np.abs(x[:, 2] - 0.2) < 0.08)
    behind = (x[:, 0] < front - 0.12) & (x[:, 0] > front - 0.2) & (np.abs(x[:, 2] - 0.2) < 0.08)
    assert ahead.sum() > 10 and v[ahead, 0].mean() > 0.1  # pushed along by the post (about 0.6 m/s at 0.8 s)
    # a bow wave ahead, a trough behind
    assert x[ahead, 1].max() > x[behind, 1].max() + 0.01


def test_boundary_positions_are_a_copy_the_next_step_leaves_alone():
    """The accessors hand out copies: a moving obstacle's boundary positions kept from one step
    are still that step's after the next (on the CPU ``numpy()`` alone is a view of the device
    array the step rewrites)."""
    sim = Simulation(post_scene(), "cpu")
    sim.advance(0.4)
    kept = sim.boundary_positions
    before = kept.copy()
    sim.advance(0.05)
    assert np.array_equal(kept, before)
    assert not np.array_equal(sim.boundary_positions, before)  # the post moved


def test_moving_obstacles_reach_the_viewers(tmp_path):
    from warp_iisph.cli import main
    from warp_iisph.run.folder import RunFolder
    from warp_iisph.run.runner import run_scene

    out = tmp_path / "post"
    scene = post_scene(duration=0.2)
    scene.output.mesh = True
    assert run_scene(scene, out, progress=False)["ended"] == "completed"
    run = RunFolder(out)
    assert run.obstacles_move
    first, last = run.obstacle_mesh(0), run.obstacle_mesh(6)
    m = scene.obstacles[0].motion
    np.testing.assert_allclose(last.bounds - first.bounds, np.tile(m.at(0.2)[0] - m.at(0.0)[0], (2, 1)), atol=1e-5)
    assert main(["preview", str(out), "--no-progress", "--resolution", "64x36"]) == 0
    assert main(["blender-script", str(out)]) == 0
    assert "OBSTACLE_FRAMES = [[0, " in (out / "blender_scene.py").read_text()


def test_motion_errors_are_one_line():
    bad = [
        ({"times": [0.0, 0.0]}, "motion.times = [0.0, 0.0]: must be finite, >= 0 and increasing"),
        ({"times": [0.0, 1.0], "translate": [[0, 0, 0]]}, "motion.translate: must give one [x, y, z] per key time (2)"),
        ({"times": [0.0, 1.0], "interpolation": "cubic"}, "motion.interpolation = 'cubic'"),
        ({"times": [0.0, 1.0], "speed": 2}, "motion.speed: unknown key"),
        ({"translate": [[0, 0, 0]]}, "motion.times: required"),
        ({"times": [0.0, 1.0], "rotate": [[0, 0, 0], [1e300, 0, 0]]}, "motion.rotate: angles must stay within 1e.06"),
        ({"times": [0.0, 1.0], "translate": [[0, 0, 0], [0, -2e3, 0]]}, "motion.translate: must stay within"),
    ]
    for motion, message in bad:
        scene = post_scene()
        scene.obstacles[0].motion = motion
        with pytest.raises(
            ValueError, match=message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(").replace(")", r"\)")
        ):
            scene.validate()
    scene = post_scene()
    scene.fluids[0].motion = Motion(times=[0.0])
    with pytest.raises(ValueError, match=r"fluids\[0\].motion: fluid blocks do not move"):
        scene.validate()


def test_a_run_with_a_moving_obstacle_resumes_bitwise(tmp_path):
    from warp_iisph.cli import main
    from warp_iisph.run.formats import read_particles
    from warp_iisph.run.runner import run_scene

    whole, cut = tmp_path / "whole", tmp_path / "cut"
    run_scene(post_scene(duration=0.3), whole, progress=False)
    run_scene(post_scene(duration=0.3), cut, duration=0.1, progress=False)
    assert main(["run", "--resume", str(cut), "--duration", "0.3", "--no-progress"]) == 0
    a, b = (read_particles(r / "particles" / "frame_00009.ply") for r in (whole, cut))
    assert np.array_equal(a["x"], b["x"]) and np.array_equal(a["v"], b["v"])
