"""Scene files: bundled scenes load and run; every bad input is one clear line and exit 2."""

import pytest

from warp_iisph import Simulation
from warp_iisph.cli import main
from warp_iisph.scene import SceneFileError, bundled_scenes, load_scene, scene_to_dict

REPORT_SCENES = ("dam_break", "drop_splash", "fluid_flow")


def test_bundled_scenes_include_the_reports_three():
    assert set(REPORT_SCENES) | {"martin_moyce", "dam_break_cube"} <= set(bundled_scenes())


COARSE = {"dam_break_cube": ["spacing=0.12"], "pour": []}  # pour: its glass needs its own spacing


@pytest.mark.parametrize("name", sorted(bundled_scenes()))
def test_bundled_scene_runs_a_few_steps_coarse(name):
    scene = load_scene(name, COARSE.get(name, ["spacing=0.04"]))
    sim = Simulation(scene, "cpu")
    assert sim.n_particles > 50 or scene.emitters
    for _ in range(5):
        rec = sim.step()
    assert sim.n_particles > 0 and rec["escaped"] == 0 and rec["non_finite"] == 0
    # from rest (or a nozzle's stream), a few steps in: nothing fast
    assert rec["max_velocity"] < 1.0 + max((e.speed for e in scene.emitters), default=0.0) * 1.5


def test_obstacles_are_built_and_fluid_kept_out_of_them():
    with_mesh = Simulation(load_scene("dam_break", ["spacing=0.05"]), "cpu")
    without = Simulation(load_scene("dam_break", ["spacing=0.05", "obstacles=[]"]), "cpu")
    assert with_mesh.model.n_boundary > without.model.n_boundary
    assert with_mesh.n_particles == without.n_particles  # the column does not touch the submarine


def test_overrides_reach_the_scene():
    scene = load_scene(
        "drop_splash", ["spacing=0.05", "physics.eta=0.0005", "fluids.1.radius=0.08", "output.mesh=false"]
    )
    assert scene.spacing == 0.05 and scene.physics.eta == 0.0005 and scene.fluids[1].radius == 0.08


def _write(tmp_path, text, name="s.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


GOOD = """
spacing = 0.05
[tank]
lower = [0, 0, 0]
upper = [1, 1, 1]
[[fluids]]
lower = [0, 0, 0]
upper = [0.5, 0.5, 0.5]
"""

BAD = {
    "unknown top key": (GOOD + "colour = 3\n", "colour: unknown key"),
    "unknown physics key": (GOOD + "[physics]\netta = 0.01\n", "physics.etta: unknown key"),
    "wrong type": (GOOD.replace("spacing = 0.05", 'spacing = "fine"'), "spacing = 'fine': must be a number"),
    "zero spacing": (GOOD.replace("spacing = 0.05", "spacing = 0"), "spacing = 0: must be > 0"),
    "negative spacing": (GOOD.replace("spacing = 0.05", "spacing = -0.1"), "spacing = -0.1: must be > 0"),
    "fluid outside tank": (GOOD.replace("upper = [0.5, 0.5, 0.5]", "upper = [0.5, 1.5, 0.5]"), "fluids[0]: fluid"),
    "eta out of range": (GOOD + "[physics]\neta = 2.0\n", "physics.eta = 2.0: must be in (0, 0.5]"),
    "missing mesh": (
        GOOD + '[[obstacles]]\nshape = "mesh"\npath = "nope.obj"\n',
        "obstacles[0].path = 'nope.obj': file not found",
    ),
    "unreadable mesh": (
        GOOD + '[[obstacles]]\nshape = "mesh"\npath = "junk.obj"\n',
        "obstacles[0].path = 'junk.obj': ",
    ),
    "bad shape": (
        GOOD + '[[obstacles]]\nshape = "cone"\n',
        "obstacles[0].shape = 'cone': must be one of box, sphere, mesh",
    ),
    "missing key": (
        GOOD + '[[obstacles]]\nshape = "sphere"\ncenter = [0.7, 0.7, 0.7]\n',
        "obstacles[0].radius: required",
    ),
    "a key of another shape": (
        GOOD + '[[obstacles]]\nshape = "sphere"\ncenter = [0.7, 0.7, 0.7]\nradius = 0.1\nupper = [1, 1, 1]\n',
        "obstacles[0].upper: a key of shape = 'box', not of 'sphere'",
    ),
    "rest density too small": (GOOD + "[physics]\nrho0 = 1e-200\n", "physics.rho0 = 1e-200: must be in [1, 100000]"),
    "gravity too strong": (
        GOOD + "[physics]\ngravity = [0, -1e300, 0]\n",
        "physics.gravity = [0.0, -1e+300, 0.0]: its magnitude must be at most 1000 m/s^2",
    ),
    "max_particles below the start": ("max_particles = 5\n" + GOOD, "max_particles = 5: below the"),
    "bad toml": ("spacing = = 1\n", "not valid TOML"),
    "too many particles": (
        GOOD.replace("spacing = 0.05", "spacing = 0.0002"),
        "spacing = 0.0002: the scene would need about",
    ),
    "more than memory holds": (GOOD.replace("spacing = 0.05", "spacing = 0.0005"), "GiB but"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_scene_file_is_one_line_exit_2(case, tmp_path, capsys):
    text, expected = BAD[case]
    (tmp_path / "junk.obj").write_text("v 0 0\nf 1 2 3 4\nthis is not a mesh\n")
    path = _write(tmp_path, text)
    code = main(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress", "--duration", "0.05"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(path) in err and expected in err, err
    assert not (tmp_path / "out" / "particles").exists()


def test_bad_override_is_clear(tmp_path):
    path = _write(tmp_path, GOOD)
    with pytest.raises(SceneFileError, match=r"s\.toml, --set physics\.cfl=9: physics\.cfl = 9: must be in"):
        load_scene(path, ["physics.eta=0.01", "physics.cfl=9"])  # the value named where it came from
    with pytest.raises(SceneFileError, match=r"--set fluids\.0\.lower=\[5,5,5\]: fluids\[0\]: upper"):
        load_scene(path, ["fluids.0.lower=[5,5,5]"])
    with pytest.raises(SceneFileError, match=r"--set fluids\.0\.upper=\[1e9,1,1\]: fluids\[0\]\.upper"):
        load_scene(path, ["fluids.0.lower=[0,0,0]", "fluids.0.upper=[1e9,1,1]"])  # the key named, not its entry
    with pytest.raises(SceneFileError, match="must be KEY=VALUE"):
        load_scene(path, ["spacing"])
    with pytest.raises(SceneFileError, match=r"s\.toml, --set fluids\.3\.radius: fluids\.3 must index one of"):
        load_scene(path, ["fluids.3.radius=1"])  # the file named, as for every other bad value
    assert load_scene(path, "spacing=0.05").spacing == 0.05  # one string is one override
    with pytest.raises(
        SceneFileError, match=r"--set fluids\.\u00b2\.radius: fluids\.\u00b2 must index one of the 1 items"
    ):
        load_scene(path, ["fluids.\u00b2.radius=1"])  # a superscript two is a digit to str.isdigit, not an index
    with pytest.raises(SceneFileError, match=r"--set fluids\.\uff10\.radius: fluids\.\uff10 must index"):
        load_scene(path, ["fluids.\uff10.radius=1"])  # nor a full-width zero (int() reads it as 0)
    with pytest.raises(SceneFileError, match=r"--set probes\.0\.name: the scene has no probes to index"):
        load_scene(path, ["probes.0.name=x"])
    big = "1" + "0" * 400  # TOML integers have no size limit; float() of this one overflows
    with pytest.raises(SceneFileError, match=rf"--set physics\.eta={big}: physics\.eta = {big}: must be a number in"):
        load_scene(path, [f"physics.eta={big}"])
    with pytest.raises(SceneFileError, match=r"fluids\[0\]\.lower = .*: must be three numbers"):
        load_scene(path, [f"fluids.0.lower=[{big},0,0]"])


def test_an_emitter_switched_to_the_other_nozzle_by_set_drops_the_old_key():
    """--set can add or replace a key, never remove one: the disc's radius is left out of a
    rectangle (and recorded so), not refused."""
    scene = load_scene("pour", ['emitters.0.shape="rectangle"', "emitters.0.size=[0.01,0.02]"])
    e = scene.emitters[0]
    assert (e.shape, e.radius, e.size) == ("rectangle", None, (0.01, 0.02))
    assert "radius" not in scene_to_dict(scene)["emitters"][0]
