"""The bundled scenes of the features beyond the report, at their default resolution, do what
they are for: the wine ends in the glass, the post leaves a bow wave ahead and a trough behind."""

import numpy as np

from warp_iisph import Simulation
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
