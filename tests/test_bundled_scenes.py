"""The bundled scenes of the features beyond the report, at their default resolution, do what
they are for: the wine ends in the glass, the post leaves a bow wave ahead and a trough behind."""

import numpy as np
import pytest

from warp_iisph import DivergenceError, Simulation
from warp_iisph.scene import load_scene


def test_pour_fills_the_glass():
    scene = load_scene("pour")
    sim = Simulation(scene, "cpu", history=1)
    sim.advance(scene.output.duration)
    x = sim.positions
    r = np.hypot(x[:, 0], x[:, 2])
    in_bowl = (r < 0.045) & (x[:, 1] > 0.08) & (x[:, 1] < 0.17)  # the bowl (meshes/make_meshes.py wine_glass)
    assert sim.flows.emitted > 1000 and sim.n_particles == sim.flows.emitted
    assert in_bowl.mean() > 0.95  # poured into the glass, hardly a splash out
    assert np.linalg.norm(sim.velocities[in_bowl], axis=1).mean() < 0.1  # and settling there


def test_wake_has_a_bow_wave_ahead_and_a_trough_behind():
    scene = load_scene("wake")
    sim = Simulation(scene, "cpu", history=1)
    through = []
    sim.advance(1.5, callback=lambda s: through.append(s["obstacle_corrections"]))  # the post at full speed, 0.6 m/s
    post = scene.obstacles[0]
    front = post.bounds[1][0] + post.motion.at(1.5)[0][0]
    back = post.bounds[0][0] + post.motion.at(1.5)[0][0]
    x = sim.positions
    mid = np.abs(x[:, 2] - 0.3) < 0.1

    def surface(a, b):
        sel = mid & (x[:, 0] > a) & (x[:, 0] < b)
        return np.percentile(x[sel, 1], 98)

    still = surface(2.0, 2.3)  # far ahead: water the post has not reached
    assert surface(front, front + 0.1) > still + 0.005  # bow wave
    assert surface(back - 0.15, back) < still - 0.01  # trough behind
    assert len(through) > 100 and not any(through)  # measured every step: nothing through the post


def test_flood_sweeps_its_bodies_and_the_liquid_stays_out_of_them():
    """The flood scene at its defaults, advanced frame by frame as `warp-iisph run` does, runs to
    its end: after every step no fluid particle is inside a body (each body's box in its own
    frame) and every body is inside the tank; the crates float off the floor and the wave
    carries them and the heavy block downstream. (benchmarks/bodies.py counts the containment's
    corrections: about 1,700 particles put back out of the bodies and the post over the run.)"""
    from warp_iisph.scene.bodies import quaternion_matrix

    scene = load_scene("flood")
    sim = Simulation(scene, "cpu", history=1)
    halves = [0.5 * np.subtract(b.shape.upper, b.shape.lower) for b in scene.bodies]
    start = sim.bodies["position"].copy()
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    worst = {"inside": 0, "beyond": -np.inf}

    def check(record):
        b, x = sim.bodies, sim.positions
        for k, half in enumerate(halves):
            rot = quaternion_matrix(b["orientation"][k])
            local = (x - b["position"][k]) @ rot
            worst["inside"] = max(worst["inside"], int(np.all(np.abs(local) < half, axis=1).sum()))
            corners = b["position"][k] + (signs * half) @ rot.T
            beyond = max((scene.tank.lower - corners).max(), (corners - scene.tank.upper).max())
            worst["beyond"] = max(worst["beyond"], float(beyond))

    fps, frames = scene.output.fps, round(scene.output.duration * scene.output.fps)
    for k in range(1, frames + 1):
        sim.advance(k / fps - sim.time, callback=check)
    assert abs(sim.time - scene.output.duration) < 1e-9
    assert worst["inside"] == 0, worst  # no particle inside a body after any step
    assert worst["beyond"] < 0.5 * scene.spacing, worst  # no body through a wall (its surface particles lie h/2 inside)
    end = sim.bodies["position"]
    crates = [k for k, b in enumerate(scene.bodies) if b.density < 1000.0]
    assert np.all(end[crates, 1] > start[crates, 1] + 0.03)  # afloat: lifted off the floor
    assert np.all(end[:, 0] > start[:, 0] + 0.3)  # swept downstream, the block too


@pytest.mark.xfail(strict=True, raises=DivergenceError, reason="a film between a body and a tank wall blows up")
def test_flood_in_one_advance():
    """The same scene advanced in one call to its end (its steps landing on no frame; the step
    pattern matters: advanced to 0.9 s it passes) diverges at step 333, t = 0.845 s:
    crate0, pressed tilted against the side wall z = 0, traps a particle between its boundary
    particles and the wall's, whose speed then grows about 15 % a step (2 iterations a step, the
    pressure solve converged) until it passes the speed limit. The same scene in a 3 m channel with
    the bodies held to the x-y plane diverged the same way under the heavy block sliding on the
    floor (t = 1.62 s). Kept as a reproducer of the film instability (sph/, not the scene)."""
    scene = load_scene("flood")
    sim = Simulation(scene, "cpu", history=1)
    sim.advance(scene.output.duration)
