"""Emitters and sinks: a stream that keeps the spacing, sinks that remove, the particle count
changing between frames through the outputs, the surface and the viewers."""

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from warp_iisph import Box, Scene, Simulation, load_scene
from warp_iisph.cli import main
from warp_iisph.run.formats import read_particles
from warp_iisph.run.runner import run_scene
from warp_iisph.scene import Emitter, Sink

H = 0.02


def jet_scene(duration=0.5, **physics) -> Scene:
    """A horizontal jet (disc, 3 cm, 1 m/s) into a 0.8 m tank, a sink box at its far floor."""
    scene = Scene(spacing=H, tank=Box((0, 0, 0), (0.8, 0.5, 0.3)), name="jet")
    scene.physics.__dict__.update(physics)
    scene.add_emitter(Emitter(center=(0.1, 0.3, 0.15), direction=(1.0, 0.0, 0.0), speed=1.0, radius=0.03, end=0.4))
    scene.add_sink(Sink((0.6, 0.0, 0.0), (0.8, 0.1, 0.3)))
    scene.output.duration = duration
    return scene


def test_an_emitter_keeps_the_spacing_without_a_pressure_shock():
    # inviscid: the report's viscosity turns the layers' different fall speeds into forces along
    # their pairs; without it nothing but pressure could change a layer's speed along the jet
    sim = Simulation(jet_scene(viscosity=0.0), "cpu")
    layer = len(jet_scene().emitters[0].layer(H))
    sim.advance(0.1)
    # one layer per spacing travelled (every 0.02 s at 1 m/s): at 0, 0.02, ..., 0.08 s; the one due
    # at 0.1 s comes when the run goes on
    assert sim.n_particles == 5 * layer
    x = sim.positions
    d, _ = cKDTree(x).query(x, k=2)
    assert d[:, 1].min() > 0.9 * H  # no overlap where a new layer meets the last
    # the new particles join at rest density: no particle compressed, no pressure kick
    assert max(s["compression"] for s in sim.stats) < 1e-3 and sim.densities.max() < 1.01 * 1000
    assert np.all(np.abs(sim.velocities[:, 0] - 1.0) < 0.01)  # still flying at the nozzle speed: no pressure kick
    ids = sim.state.id.numpy()[: sim.n_particles]
    assert len(np.unique(ids)) == len(ids)


def test_sinks_remove_and_ids_stay_unique():
    sim = Simulation(jet_scene(duration=1.5), "cpu")
    counts = []
    for _ in range(15):
        sim.advance(0.1)
        counts.append(sim.n_particles)
    assert sim.flows.removed > 0 and counts[-1] < max(counts)  # the stream stopped at 0.4 s; the sink drains
    x = sim.positions
    assert not np.any(np.all((x >= (0.6, 0.0, 0.0)) & (x <= (0.8, 0.1, 0.3)), axis=1))
    ids = sim.state.id.numpy()[: sim.n_particles]
    assert len(np.unique(ids)) == len(ids) and ids.max() < sim.state.next_id


def test_a_run_with_a_changing_count_writes_meshes_and_previews(tmp_path):
    out = tmp_path / "jet"
    scene = jet_scene(duration=0.5)
    scene.output.mesh = True
    record = run_scene(scene, out, progress=False)
    assert record["ended"] == "completed" and record["totals"]["emitted"] > 0
    counts = [len(read_particles(f)["x"]) for f in sorted((out / "particles").glob("*.ply"))]
    assert counts[0] == len(scene.emitters[0].layer(H)) and counts[-1] > counts[0]
    assert all(f.stat().st_size > 0 for f in (out / "mesh").glob("*.obj"))
    assert main(["preview", str(out), "--no-progress", "--resolution", "64x36"]) == 0
    assert main(["preview", str(out), "--source", "mesh", "--no-progress", "--resolution", "64x36"]) == 0


def test_a_full_liquid_refuses_more_with_a_warning(tmp_path, capsys):
    path = tmp_path / "jet.toml"
    path.write_text("""
spacing = 0.02
max_particles = 40
[tank]
lower = [0, 0, 0]
upper = [0.8, 0.5, 0.3]
[[emitters]]
center = [0.1, 0.3, 0.15]
direction = [1, 0, 0]
speed = 1.0
radius = 0.03
""")
    assert main(["run", str(path), "--duration", "0.2", "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "could not add" in err and "capacity of 40" in err
    totals = json.loads((tmp_path / "out" / "run.json").read_text())["totals"]
    assert totals["particles"] <= 40 and totals["not_emitted"] > 0


def test_graph_and_plain_emit_alike():
    plain, graph = Simulation(jet_scene(), "cpu"), Simulation(jet_scene(), "cpu", graph=True)
    for sim in (plain, graph):
        sim.advance(0.15)
    assert graph.n_particles == plain.n_particles
    np.testing.assert_array_equal(graph.positions, plain.positions)


def test_a_run_with_emitters_resumes_bitwise(tmp_path):
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    run_scene(jet_scene(duration=0.6), whole, progress=False)
    run_scene(jet_scene(duration=0.6), cut, duration=0.2, progress=False)
    assert main(["run", "--resume", str(cut), "--duration", "0.6", "--no-progress"]) == 0
    a, b = (read_particles(r / "particles" / "frame_00018.ply") for r in (whole, cut))
    assert len(a["x"]) == len(b["x"]) and np.array_equal(a["x"], b["x"]) and np.array_equal(a["id"], b["id"])


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"speed": 0.0}, "emitters[0].speed = 0.0"),
        ({"direction": [0, 0, 0]}, "emitters[0].direction = [0, 0, 0]: must be non-zero (the way the nozzle points)"),
        ({"shape": "rectangle"}, "emitters[0].size: required"),
        ({"center": [5, 0.3, 0.15]}, "emitters[0].center = [5.0, 0.3, 0.15]: must lie inside the tank"),
        ({"end": -1.0}, "emitters[0].end = -1.0"),
    ],
)
def test_emitter_errors_are_one_line(bad, message):
    scene = jet_scene()
    e = scene.emitters[0]
    for k, v in bad.items():
        setattr(e, k, v)
    with pytest.raises(ValueError) as err:
        scene.validate()
    assert message in str(err.value)


def test_particle_frames_hold_each_particles_own_id(tmp_path):
    """Once a sink has removed particles the ids have gaps: a frame's rows are the particles in
    the order of their ids, each with its own id (not its row number)."""
    run_scene(jet_scene(duration=1.5), tmp_path / "r", progress=False)
    frame = read_particles(tmp_path / "r" / "particles" / "frame_00045.ply")
    sim = Simulation(jet_scene(duration=1.5), "cpu")
    for _ in range(45):  # frame by frame, as the run (sinks act at frame ends)
        sim.advance(1 / 30)
    ids = np.sort(sim.state.id.numpy()[: sim.n_particles])
    assert sim.flows.removed > 0 and ids[-1] > len(ids) - 1  # gaps
    np.testing.assert_array_equal(frame["id"], ids)
    # the same particle on each row (the two advance the clock in sums of different rounding)
    np.testing.assert_allclose(frame["x"], sim.positions, atol=1e-4)


def test_an_emitter_under_the_liquid_pours_from_a_wall_and_is_blocked_in_open_water():
    """A layer is never forced into the liquid (the pressure solve would blow the two apart): one
    due where liquid sits is skipped and counted. The liquid just in front of a pouring nozzle moves
    with its stream, so a nozzle in a wall under the surface pushes the liquid away and pours every
    layer but its first (where the liquid starts); one in open water, the liquid behind it flowing
    into its mouth, stays blocked and, liquid lying behind its mouth when its first layer is due,
    never drives, so the water stays still (no pump that moves liquid without pouring any; with a
    start-up drive for its first layers it moved the water at 0.62 m/s). Above the water a nozzle
    pours every layer."""

    def tank(nozzle, direction=(0.0, -1.0, 0.0)):
        scene = Scene(spacing=H, tank=Box((0, 0, 0), (0.3, 0.4, 0.2)), name="submerged")
        scene.add_fluid_box((0, 0, 0), (0.3, 0.2, 0.2))
        scene.add_emitter(Emitter(center=nozzle, direction=direction, speed=0.5, radius=0.03, end=0.2))
        return scene

    def run(scene):
        sim = Simulation(scene, "cpu")
        n0 = sim.n_particles
        sim.advance(0.4)
        late = [s["max_velocity"] for s in sim.stats if s["t"] > 0.3]
        return sim, n0, max(s["max_velocity"] for s in sim.stats), max(late)

    wall, n0, fastest, _ = run(tank((0.01, 0.1, 0.1), direction=(1.0, 0.0, 0.0)))
    layer, due = wall.flows.layers[0].shape[0], round(0.2 / (H / 0.5))
    assert wall.flows.blocked == layer and wall.flows.emitted == (due - 1) * layer
    assert wall.n_particles == n0 + wall.flows.emitted and fastest < 2.0 * 0.5  # no burst
    under, n0, fastest, late = run(tank((0.15, 0.1, 0.1)))
    assert under.n_particles == n0 and under.flows.emitted == 0 and under.flows.blocked == due * layer
    assert fastest < 0.15 and late < 0.15  # never driven: still from the start
    above = Simulation(tank((0.15, 0.35, 0.1)), "cpu")
    above.advance(0.2)
    assert above.flows.blocked == 0 and above.flows.emitted > 0


def test_a_thin_sink_catches_a_fast_jet():
    """A 3 m/s jet through a sink 4 cm thick: at 30 frames/s a particle moves 10 cm per frame,
    so a check once per frame lets most of the jet through; the checks come often enough that
    none passes (the fastest particle moves at most half the sink's thickness between them)."""
    scene = Scene(spacing=H, tank=Box((0, 0, 0), (1.0, 0.6, 0.3)), name="through")
    scene.add_emitter(Emitter(center=(0.1, 0.4, 0.15), direction=(1.0, 0.0, 0.0), speed=3.0, radius=0.03, end=0.3))
    scene.add_sink(Sink((0.4, 0.0, 0.0), (0.44, 0.6, 0.3)))
    sim = Simulation(scene, "cpu")
    for _ in range(15):  # frame by frame, as a run
        sim.advance(1 / 30)
        assert sim.n_particles == 0 or sim.positions[:, 0].max() < 0.44
    assert sim.flows.removed > 100


def test_a_jet_at_the_top_of_its_allowed_speed_is_not_taken_for_a_divergence():
    """An emitter may shoot at up to 100 m/s (scenes.md); the derived divergence limit is at least
    3 times the fastest stream where it lands (with a body's start speed), so a 40 m/s jet into a
    0.5 m tank (limit 31 m/s from the tank alone) runs; a set physics.max_velocity still rules."""
    scene = jet_scene(duration=0.01)
    scene.emitters[0].speed = 40.0
    sim = Simulation(scene, "cpu")
    fall = np.sqrt(40.0**2 + 2.0 * 9.81 * 0.3)
    assert sim.loop.velocity_limit == pytest.approx(3.0 * fall, rel=1e-3)  # from the domain's floor
    sim.advance(0.01)
    assert sim.n_particles > 0 and np.abs(sim.velocities).max() < 41.0
    scene.physics.max_velocity = 35.0
    assert Simulation(scene, "cpu").loop.velocity_limit == 35.0


def test_a_full_liquid_warns_a_python_caller_once_and_until_is_checked():
    """Through the Python API an emitter that finds no room says so once (LiquidFullWarning), as a
    run says so in run.json; ``until`` (the run's length the room is sized for) is a number of
    seconds in [0, 1e6], and the other arguments are checked alike."""
    import warnings

    from warp_iisph import LiquidFullWarning

    scene = jet_scene(duration=0.05)
    scene.emitters[0].end = None
    sim = Simulation(scene, "cpu")
    with pytest.warns(LiquidFullWarning, match=r"emitters\[0\]: no room for its layer due at t = 0.06 s") as caught:
        sim.advance(0.1)
    assert len(caught) == 1 and sim.flows.refused > 0 and caught[0].filename == __file__  # the caller's line
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Simulation(scene, "cpu", until=0.2).advance(0.1)  # room for it: no warning
    for bad, says in [
        ({"until": -1.0}, r"until = -1.0: must be in \[0, 1e\+06\]"),
        ({"until": float("nan")}, r"until = nan"),
        ({"until": "x"}, r"until = 'x'"),
        ({"history": 0}, r"history = 0: must be None"),
        ({"probe_history": "x"}, r"probe_history = 'x'"),
        ({"device": "gpu"}, r"device gpu: unknown device; choose one of cpu, cuda"),
    ]:
        with pytest.raises(ValueError, match=says):
            Simulation(scene, **bad)
    with pytest.raises(TypeError, match=r"scene: a Scene \(or load_scene\(path\) of a scene file\), not str"):
        Simulation("jet.toml")


def test_an_emitter_whose_layer_misses_its_nozzles_area_is_warned_of():
    """An emitter pours its layer's particles each spacing, so a nozzle only a few spacings wide
    pours its lattice's share of area x speed: said before the run, with a nozzle size that pours
    what it declares (the bundled scenes' nozzles are within 10 %)."""
    from warp_iisph.scene import scene_to_dict
    from warp_iisph.scene.library import bundled_scenes
    from warp_iisph.setup.fill import nozzle_flows, nozzle_share

    def disc(radius):
        return {"center": [0, 0, 0], "direction": [0, -1, 0], "speed": 1.0, "radius": radius}

    rectangle = {"center": [0, 0, 0], "direction": [1, 0, 0], "speed": 1.0, "shape": "rectangle", "size": [0.1, 0.05]}
    one, wide, rect = nozzle_flows({"spacing": 0.03, "emitters": [disc(0.03), disc(0.045), rectangle]})
    assert one.startswith("emitters[0]: its layer of 5 particles at spacing = 0.03 m carries 159 %")
    assert "pours 4.5 l/s, not the 2.83 l/s" in one and "five spacings" in one
    assert rect.startswith("emitters[2]: its layer of 3 particles") and "54 %" in rect and "(0.09 x 0.06 m)" in rect
    assert wide.startswith("emitters[1]:") and "a radius of " in wide
    better = float(wide.split("a radius of ")[1].split(" m")[0])
    share, _ = nozzle_share(Emitter(center=(0, 0, 0), direction=(0, -1, 0), speed=1.0, radius=better), 0.03)
    assert abs(share - 1.0) <= 0.011 and abs(better - 0.045) <= 0.0113
    assert nozzle_flows({"spacing": 0.03, "emitters": [disc(0.15)]}) == []  # 5 spacings: 98 %
    for name in bundled_scenes():
        assert nozzle_flows(scene_to_dict(load_scene(name))) == [], name


def test_layers_blocked_at_the_nozzle_are_warned_of():
    """A nozzle its own liquid covers pours part of its layers or none: the run's warnings say
    how much, and why."""
    from warp_iisph.run.run_record import run_warnings
    from warp_iisph.scene import scene_to_dict

    record = {"scene": scene_to_dict(jet_scene()), "particles": {"capacity": 1000}}
    record["totals"] = {"steps": 10, "mean_compression": 0.0, "unconverged_steps": 0, "emitted": 30, "blocked": 90}
    (warning,) = [w for w in run_warnings(record) if "blocked" in w]
    assert warning.startswith("the emitters poured 25 % of the particles due: 90 were blocked")
    assert "under the liquid's surface" in warning
    record["totals"]["blocked"] = 0
    assert not [w for w in run_warnings(record) if "blocked" in w]


def test_a_restore_keeps_which_nozzles_drive():
    """A nozzle in open water under the surface stops driving once three layers due have not come
    in; a restored state keeps that (a restore that took every nozzle as pouring would drive the
    liquid again, and the runs would part), and a state whose record of it makes no sense is
    refused whole."""
    scene = Scene(spacing=H, tank=Box((0, 0, 0), (0.3, 0.4, 0.2)), name="submerged")
    scene.add_fluid_box((0, 0, 0), (0.3, 0.2, 0.2))
    scene.add_emitter(Emitter(center=(0.15, 0.1, 0.1), direction=(0.0, -1.0, 0.0), speed=0.5, radius=0.03))
    whole = Simulation(scene, "cpu")
    whole.advance(0.2)
    assert whole.flows.nozzles.pouring.numpy()[0] == 0 and whole.flows.emitted == 0
    state = whole.checkpoint()
    whole.advance(0.1)
    resumed = Simulation(scene, "cpu")
    resumed.restore(state)
    resumed.advance(0.1)
    assert np.array_equal(resumed.positions, whole.positions)
    for bad in (np.array([8]), np.array([-1]), np.array([1, 1]), np.array([1.0])):
        other = Simulation(scene, "cpu")
        with pytest.raises(ValueError, match="flows_poured_recently"):
            other.restore({**state, "flows_poured_recently": bad})
        assert other.time == 0.0
