"""Free bodies: their scene keys and validation, their sampling and mass properties, the liquid's
loads on them as the exact reaction of the step's forces, and the paths (plain, split over CPU
threads, graph, resumed) giving the same bits."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from warp_iisph import Body, Box, Scene, Simulation, Sphere
from warp_iisph.scene import SceneFileError, scene_from_dict, scene_to_dict
from warp_iisph.scene.file import load_scene


def pool(spacing=0.04, density=500.0, **keys) -> Scene:
    """A 0.4 m square pool 0.2 m deep with a 0.16 x 0.08 x 0.16 m box floating in its middle,
    placed at the draft its density gives (the level the box raises included)."""
    scene = Scene(spacing=spacing, tank=Box((0, 0, 0), (0.4, 0.4, 0.4)), name="pool")
    scene.add_fluid_box((0, 0, 0), (0.4, 0.2, 0.4))
    draft = density / 1000.0 * 0.08
    bottom = 0.2 - draft + draft * 0.16**2 / 0.4**2
    scene.add_body(Box((0.12, bottom, 0.12), (0.28, bottom + 0.08, 0.28)), density=density, **keys)
    return scene


NO_BOX = {"lower": None, "upper": None}  # a change that drops the box's keys


def test_body_keys_are_validated(tmp_path):
    base = {
        "spacing": 0.04,
        "tank": {"lower": [0, 0, 0], "upper": [0.4, 0.4, 0.4]},
        "fluids": [{"lower": [0, 0, 0], "upper": [0.4, 0.2, 0.4]}],
    }
    ok = {"shape": "box", "lower": [0.1, 0.1, 0.1], "upper": [0.2, 0.2, 0.2], "density": 500}
    scene = scene_from_dict({**base, "bodies": [ok]})
    assert scene.bodies[0].density == 500.0 and scene.bodies[0].fixed_axes == []
    bad = [
        ({"density": 500, "mass": 1.0}, "exactly one of density"),
        ({"density": None}, "exactly one of density"),
        ({"density": 0.5}, "bodies[0].density = 0.5: must be in [1, 100000]"),
        ({"fixed_axes": ["x", "q"]}, "bodies[0].fixed_axes"),
        ({"fixed_axes": ["x", "x"]}, "distinct"),
        ({"inertia": [1.0, 1.0, 3.0]}, "I1 + I2 >= I3"),
        ({"inertia": [1.0, -1.0, 1.0]}, "positive definite"),
        ({"inertia": [1.0, 1.0]}, "bodies[0].inertia"),
        ({"center_of_mass": [0.5, 0.15, 0.15]}, "within the body's bounds"),
        ({"velocity": [200.0, 0, 0]}, "at most 100 m/s"),
        ({"restitution": 1.5}, "bodies[0].restitution"),
        ({"friction": -1}, "bodies[0].friction"),
        ({"release_time": -0.1}, "bodies[0].release_time = -0.1: must be in [0, 1e+06]"),
        ({"release_time": 0.5, "velocity": [0.1, 0, 0]}, "bodies[0].release_time = 0.5: a held body starts from rest"),
        ({"motion": {"times": [0.0]}}, "bodies[0].motion: unknown key"),
        ({"upper": [0.2, 0.5, 0.2]}, "must lie inside the tank"),
        ({"lower": [0.1, 0.1, 0.1], "upper": [0.11, 0.11, 0.11]}, "smaller than two spacings"),
        ({"density": None, "mass": 1e-6}, "bodies[0].mass = 1e-06: gives the body a mean density of 0.001 kg/m^3"),
        ({"density": None, "mass": 1e8}, "outside [1, 100000] kg/m^3"),
        # a box of 0.1 m at 500 kg/m^3: 0.5 kg, moments 8.3e-4 kg m^2 (the least allowed 1.7e-6, the most 0.015)
        ({"inertia": [1e-9, 1e-9, 1e-9]}, "the shape at a uniform 1 kg/m^3"),
        ({"inertia": [1.0, 1.0, 1.0]}, "at most 0.015 (its mass 0.5 kg at its bounds' diagonal)"),
        ({"inertia": [True, True, True]}, "bodies[0].inertia"),
        ({"shape": "mesh", **NO_BOX, "path": 5}, "bodies[0].path = 5: must be a mesh file path"),
        ({"shape": "mesh", **NO_BOX, "path": "box.obj", "rotate": [1e300, 0, 0]}, "angles must stay within"),
        ({"name": "a b"}, "bodies[0].name"),
        ({"name": "caf\u00e9"}, "bodies[0].name"),  # bodies.csv's columns are ASCII
        (
            {"lower": [0.1, 0.2, 0.1], "upper": [0.2, 0.2 + 1e-9, 0.2]},
            "gives the body a mass of",
        ),  # a sheet below the least mass
        ({"inertia": [1e300, 1e300, 1e300], "angular_velocity": [0, 1, 0]}, "principal moments must lie in"),
        ({"colour": "red"}, "bodies[0].colour: unknown key"),
        ({"density": None, "mass": 0.0}, "bodies[0].mass"),
        ({"angular_velocity": [0.0, 2000.0, 0.0]}, "bodies[0].angular_velocity"),
        ({"shell": True}, "bodies[0].shell: a key of shape = 'mesh', not of 'box'"),
        ({"shape": "cone"}, "bodies[0].shape"),
        ({"shape": "sphere", **NO_BOX, "center": [0.2, 0.2, 0.2], "radius": -0.1}, "bodies[0].radius"),
        ({"shape": "mesh", **NO_BOX, "path": "missing.obj"}, "missing.obj"),
    ]
    for change, message in bad:
        table = {k: v for k, v in {**ok, **change}.items() if v is not None}
        path = tmp_path / "s.toml"
        path.write_text(_toml({**base, "bodies": [table]}))
        with pytest.raises(SceneFileError) as e:
            load_scene(path)
        assert message in str(e.value) and str(path) in str(e.value), (change, str(e.value))
        assert "\n" not in str(e.value), change  # one line
    from warp_iisph.cli import main

    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--no-progress"]) == 2  # the CLI's usage error
    assert not (tmp_path / "run").exists()
    two = {**base, "bodies": [ok, {**ok, "lower": [0.15, 0.15, 0.15], "upper": [0.25, 0.25, 0.25]}]}
    with pytest.raises(ValueError, match=r"bodies\[0\] and bodies\[1\] overlap"):
        scene_from_dict(two)
    crossing = {**ok, "lower": [0.12, 0.05, 0.12], "upper": [0.18, 0.35, 0.18]}  # through ok, no corner inside it
    with pytest.raises(ValueError, match=r"bodies\[0\] and bodies\[1\] overlap"):
        scene_from_dict({**base, "bodies": [ok, crossing]})
    held = {
        "lower": crossing["lower"],
        "upper": crossing["upper"],
        "motion": {"times": [0, 1], "translate": [[0.2, 0, 0], [0, 0, 0]]},
    }
    with pytest.raises(
        ValueError, match=r"bodies\[0\] and obstacles\[0\] overlap"
    ):  # where its keyframes put it at t = 0
        scene_from_dict(
            {**base, "bodies": [{**ok, "lower": [0.3, 0.1, 0.1], "upper": [0.36, 0.2, 0.2]}], "obstacles": [held]}
        )
    assert scene_from_dict({**base, "bodies": [ok], "obstacles": [held]})  # it has moved away from ok by then
    beside = {**base, "bodies": [ok, {**ok, "lower": [0.2, 0.1, 0.1], "upper": [0.3, 0.2, 0.2]}]}
    assert len(scene_from_dict(beside).bodies) == 2  # touching faces do not overlap
    with pytest.raises(ValueError, match=r"bodies\[1\]\.name = 'box': another body has that name"):
        scene_from_dict({**beside, "bodies": [{**b, "name": "box"} for b in beside["bodies"]]})
    with pytest.raises(ValueError, match=r"bodies\[1\]\.name = 'body1': another body has that name \(the default"):
        scene_from_dict({**beside, "bodies": [{**beside["bodies"][0], "name": "body1"}, beside["bodies"][1]]})
    named = {**beside, "probes": [{"name": "F", "kind": "force", "body": 0}]}
    named["bodies"] = [{**beside["bodies"][0], "name": 5}, beside["bodies"][1]]
    with pytest.raises(ValueError, match=r"bodies\[0\]\.name = 5"):  # the body's own key, before a probe reads it
        scene_from_dict(named)


def test_a_body_must_be_a_mesh_wound_outward_and_inside_a_mesh_tanks_walls(tmp_path):
    import trimesh

    trimesh.creation.box(extents=[0.1, 0.1, 0.1]).export(tmp_path / "cube.obj")
    inverted = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    inverted.invert()
    inverted.export(tmp_path / "inside_out.obj")
    base = {
        "spacing": 0.04,
        "tank": {"lower": [0, 0, 0], "upper": [0.4, 0.4, 0.4]},
        "fluids": [{"lower": [0, 0, 0], "upper": [0.4, 0.2, 0.4]}],
    }
    body = {"shape": "mesh", "path": "inside_out.obj", "translate": [0.2, 0.3, 0.2], "density": 500}
    with pytest.raises(ValueError, match=r"bodies\[0\]\.path = 'inside_out.obj': the mesh is inside out"):
        scene_from_dict({**base, "bodies": [body]}, tmp_path)
    # a cube tank turned 45 degrees about y: a body in a corner of its box but outside its walls
    tank = {"shape": "mesh", "path": "cube.obj", "scale": 6.0, "rotate": [0, 45, 0], "translate": [0.5, 0.3, 0.5]}
    corner = {"shape": "box", "lower": [0.1, 0.3, 0.1], "upper": [0.18, 0.38, 0.18], "density": 500}
    fluid = {"lower": [0.4, 0.05, 0.4], "upper": [0.6, 0.2, 0.6]}
    with pytest.raises(ValueError, match=r"bodies\[0\]: must lie inside the tank's mesh"):
        scene_from_dict({"spacing": 0.04, "tank": tank, "fluids": [fluid], "bodies": [corner]}, tmp_path)
    middle = {**corner, "lower": [0.46, 0.3, 0.46], "upper": [0.54, 0.38, 0.54]}
    assert scene_from_dict({"spacing": 0.04, "tank": tank, "fluids": [fluid], "bodies": [middle]}, tmp_path)
    shell = {**tank, "shell": True}  # a shell tank encloses as much as a closed one does
    assert scene_from_dict({"spacing": 0.04, "tank": shell, "fluids": [fluid], "bodies": [middle]}, tmp_path)


def test_a_body_thrown_in_fast_sets_the_first_step_and_one_gone_astray_stops_the_run():
    """A body's fastest point counts in the first step's CFL rule and in the derived divergence
    limit (a body at 20 m/s crossed two spacings in the first step, 5 ms, and the splash passed
    the 33 m/s limit in the second); a body whose state turns non-finite or leaves the domain
    ends the run as diverged."""
    from warp_iisph import DivergenceError

    scene = pool(velocity=(0.0, -20.0, 0.0))
    sim = Simulation(scene, "cpu")
    assert sim.loop.velocity_limit >= 60.0
    first = sim.step()
    assert first["dt"] * 20.0 <= 0.5 * scene.spacing * (1 + 1e-6)  # the CFL number 0.5 at the body's speed
    sim = Simulation(pool(), "cpu")
    sim.step()
    state = {k: v.copy() for k, v in sim.model.rigid.host().items() if k != "spin"}
    state["position"][0] = [0.2, -1.0, 0.2]  # below the floor: out of the domain
    sim.model.rigid.assign(state)
    with pytest.raises(DivergenceError, match="body body0 left the domain"):
        sim.step()
    state["position"][0] = [0.2, np.nan, 0.2]
    sim.model.rigid.assign(state)
    with pytest.raises(DivergenceError, match="body body0 has a non-finite"):
        sim.step()


def _toml(data: dict) -> str:
    """A scene table as TOML (the few kinds scene tables here hold)."""

    def value(v):
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + "}"
        return repr(v)

    lines = []
    for key, v in data.items():
        if not isinstance(v, (dict, list)) or (isinstance(v, list) and v and not isinstance(v[0], dict)):
            lines.append(f"{key} = {value(v)}")
    for key, v in data.items():
        if isinstance(v, dict):
            lines += [f"[{key}]"] + [f"{k} = {value(x)}" for k, x in v.items()]
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for item in v:
                lines += [f"[[{key}]]"] + [f"{k} = {value(x)}" for k, x in item.items()]
    return "\n".join(lines) + "\n"


def test_python_api_and_scene_file_round_trip():
    scene = pool(fixed_axes=["x", "rz"], velocity=(0.0, -0.1, 0.0), name="crate")
    scene.add_body(Sphere((0.32, 0.3, 0.32), 0.05), mass=0.1, release_time=0.25)
    scene.validate()
    again = scene_from_dict(scene_to_dict(scene))
    assert [b.name for b in again.bodies] == ["crate", None]
    assert again.bodies[0].fixed_axes == ["x", "rz"] and again.bodies[1].mass == 0.1
    assert again.bodies[1].release_time == 0.25
    assert "release_time" not in scene_to_dict(scene)["bodies"][0]  # free from the start: as before the key
    assert scene_to_dict(again) == scene_to_dict(scene)
    assert "bodies" not in scene_to_dict(
        Scene(spacing=0.04, tank=Box((0, 0, 0), (1, 1, 1))).add_fluid_box((0, 0, 0), (1, 1, 1))
    )


def test_a_body_thinner_than_two_spacings_is_warned_of(tmp_path, capsys):
    """A plate is allowed (the liquid keeps out of it) but the liquid pushes on it as on a body two
    spacings thick: the run says so before it starts. Its thickness is read whichever way a mesh
    is turned (the box of the same uniform inertia)."""
    import trimesh

    from warp_iisph import MeshShape
    from warp_iisph.cli import main
    from warp_iisph.scene.bodies import thin_bodies, thinnest

    trimesh.creation.box(extents=(0.2, 0.008, 0.16)).export(tmp_path / "plate.obj")
    turned = MeshShape("plate.obj", rotate=(30.0, 0.0, 20.0), base_dir=str(tmp_path))
    assert thinnest(turned) == pytest.approx(0.008, rel=1e-6)
    assert thinnest(Sphere((0, 0, 0), 0.05)) == 0.1 and thinnest(Box((0, 0, 0), (0.3, 0.1, 0.2))) == 0.1
    plate, block = (
        Body(Box((0.1, 0.1, 0.1), (0.3, 0.102, 0.3)), density=5000.0),
        Body(Box((0, 0, 0), (0.04, 0.04, 0.04)), density=500.0),
    )
    (warning,) = thin_bodies([block, plate], 0.02)
    assert warning.startswith("bodies[1]: 0.002 m thin, under two spacings (0.04 m)")
    assert thin_bodies([block], 0.02) == []  # two spacings exactly
    path = tmp_path / "plate.toml"
    path.write_text(
        _toml(
            {
                "spacing": 0.04,
                "tank": {"lower": [0, 0, 0], "upper": [0.4, 0.4, 0.4]},
                "fluids": [{"lower": [0, 0, 0], "upper": [0.4, 0.2, 0.4]}],
                "bodies": [{"lower": [0.1, 0.3, 0.1], "upper": [0.3, 0.31, 0.3], "density": 500}],
                "output": {"duration": 0.05, "fps": 20},
            }
        )
    )
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "warp-iisph: warning: bodies[0]: 0.01 m thin, under two spacings" in err
    assert "starts under the liquid" not in err  # it starts above it


def test_a_body_free_in_the_liquid_at_the_start_is_warned_of():
    """Free from t = 0 inside a block of liquid, a body starts in the set-up's holes beside its
    edges (docs/scenes.md, "Bodies"): warned of, unless held by release_time; the bundled scenes'
    bodies start dry (flood) or held (heave)."""
    from warp_iisph.scene.bodies import bodies_in_liquid

    scene = pool()  # floating at its draft, free from the start: most of its bottom's liquid kept
    assert bodies_in_liquid(scene.bodies, scene.fluids) == []
    scene.add_body(Box((0.02, 0.04, 0.02), (0.1, 0.12, 0.1)), density=500.0)  # under the surface
    (warning,) = bodies_in_liquid(scene.bodies, scene.fluids)
    assert warning.startswith("bodies[1] starts under the liquid of fluids[0], free") and "release_time" in warning
    scene.bodies[1].release_time = 0.2
    assert bodies_in_liquid(scene.bodies, scene.fluids) == []
    for name in ("flood", "heave"):
        bundled = load_scene(name)
        assert bodies_in_liquid(bundled.bodies, bundled.fluids) == [], name


def test_a_light_body_starting_in_the_liquid_at_a_wall_is_warned_of():
    """No particle of liquid fits in a gap under a spacing (a sphere's under half a spacing, its
    footprint a point): the liquid's pressure is missing there and a light body is held to the
    wall (docs/scenes.md, "Bodies": a box of 500 kg/m^3 stayed on the floor from a gap of h/2 and
    rose from h). Heavy bodies, dry ones a wave reaches and the bundled scenes are not warned of."""
    from warp_iisph.scene.bodies import bodies_at_walls

    h, tank, water = 0.025, Box((0, 0, 0), (0.4, 0.4, 0.4)), [Box((0, 0, 0), (0.4, 0.25, 0.4))]

    def warned(shape, density=500.0, fluids=water):
        body = Body(shape, density=density)
        body.validate("bodies[0]")
        return bodies_at_walls([body], fluids, tank, h, 1000.0)

    (warning,) = warned(Box((0.12, 0.0125, 0.12), (0.28, 0.1125, 0.28)))
    assert warning.startswith("bodies[0] starts in the liquid, lighter than it, 0.0125 m from the tank's lower y face")
    assert "under a spacing (0.025 m)" in warning
    (warning,) = warned(Box((0.0, 0.1, 0.12), (0.16, 0.2, 0.28)))  # against a side wall
    assert "0 m from the tank's lower x face" in warning and "presses the body against that face" in warning
    assert "does not lift the body off that face" in warned(Box((0.12, 0.0, 0.12), (0.28, 0.1, 0.28)))[0]
    tall = [Box((0, 0, 0), (0.4, 0.4, 0.4))]  # the liquid up to the lid: a light body pressed to it anyway
    assert warned(Box((0.12, 0.3, 0.12), (0.28, 0.4, 0.28)), fluids=tall) == []
    body = Body(Box((0.0, 0.1, 0.12), (0.16, 0.2, 0.28)), density=500.0, fixed_axes=["x"])
    body.validate("bodies[0]")
    assert bodies_at_walls([body], water, tank, h, 1000.0) == []  # it cannot move off that face
    assert warned(Box((0.12, 0.025, 0.12), (0.28, 0.125, 0.28))) == []  # a spacing clear
    assert warned(Box((0.12, 0.0, 0.12), (0.28, 0.1, 0.28)), density=2000.0) == []  # it sinks anyway
    assert warned(Box((0.12, 0.0, 0.12), (0.28, 0.1, 0.28)), fluids=[Box((0, 0, 0), (0.1, 0.2, 0.4))]) == []  # dry
    (warning,) = warned(Sphere((0.2, 0.09, 0.2), 0.08), density=900.0)
    assert "0.01 m from the tank's lower y face, under half a spacing (0.0125 m)" in warning
    assert warned(Sphere((0.2, 0.0925, 0.2), 0.08), density=900.0) == []
    for name in ("flood", "heave"):
        s = load_scene(name)
        assert bodies_at_walls(s.bodies, s.fluids, s.tank, s.spacing, s.physics.rho0) == [], name


def test_mass_properties_from_the_shape():
    box = Body(Box((0.0, 0.0, 0.0), (0.2, 0.1, 0.4)), density=500.0)
    box.validate("b")
    m, c, inertia = box.mass_properties()
    assert math.isclose(m, 500.0 * 0.008) and np.allclose(c, [0.1, 0.05, 0.2])
    assert np.allclose(np.diag(inertia), m / 12 * np.array([0.01 + 0.16, 0.04 + 0.16, 0.04 + 0.01]))
    ball = Body(Sphere((0, 0, 0), 0.1), mass=2.0)
    ball.validate("b")
    assert np.allclose(ball.mass_properties()[2], np.eye(3) * 0.4 * 2.0 * 0.01)
    # a centre of mass given alone moves the uniform inertia to it (parallel axes)
    low = Body(Box((0.0, 0.0, 0.0), (0.2, 0.1, 0.4)), density=500.0, center_of_mass=(0.1, 0.0, 0.2))
    low.validate("b")
    shifted = low.mass_properties()[2]
    assert np.isclose(shifted[0, 0], inertia[0, 0] + m * 0.05**2) and np.isclose(shifted[1, 1], inertia[1, 1])


def test_mesh_body_mass_properties_match_the_box(tmp_path):
    import trimesh

    from warp_iisph import MeshShape

    trimesh.creation.box(extents=(0.2, 0.1, 0.4)).export(tmp_path / "box.obj")
    mesh = Body(MeshShape("box.obj", translate=(0.1, 0.05, 0.2), base_dir=str(tmp_path)), density=500.0)
    mesh.validate("b")
    box = Body(Box((0.0, 0.0, 0.0), (0.2, 0.1, 0.4)), density=500.0)
    box.validate("b")
    for a, b in zip(mesh.mass_properties(), box.mass_properties()):
        assert np.allclose(a, b)


def test_a_mesh_of_overlapping_parts_is_the_solid_they_fill(tmp_path):
    """A mesh put together from closed parts that overlap (a cross of two bars, as modellers and
    CAD exports leave such solids) is the one solid they fill: a body's mass and centre from its
    volume (the overlap counted twice made it 20 % too heavy here), an obstacle's particles on
    its outer surface only (none about the faces the parts keep inside it)."""
    import trimesh

    from warp_iisph import MeshShape
    from warp_iisph.setup import build_model

    bars = [trimesh.creation.box(extents=e) for e in ((0.6, 0.2, 0.2), (0.2, 0.2, 0.6))]
    trimesh.util.concatenate(bars).export(tmp_path / "cross.obj")
    body = Body(MeshShape("cross.obj", translate=(0.5, 0.3, 0.5), base_dir=str(tmp_path)), density=500.0)
    body.validate("b")
    mass, com, _ = body.mass_properties()
    assert math.isclose(mass, 500.0 * (2 * 0.024 - 0.008), rel_tol=1e-6) and np.allclose(com, (0.5, 0.3, 0.5))
    h = 0.05
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (1.0, 0.6, 1.0)), name="cross")
    scene.add_fluid_box((0.0, 0.0, 0.0), (1.0, 0.15, 1.0))
    scene.add_obstacle(MeshShape("cross.obj", translate=(0.5, 0.3, 0.5), base_dir=str(tmp_path)))
    model, _ = build_model(scene, "cpu")
    xb = model.boundary_x.numpy()[model.boundary_owner.numpy() == 0] - (0.5, 0.3, 0.5)
    # the cross's outer surface: each bar's faces where they are not inside the other bar
    halves = [np.array([0.3, 0.1, 0.1]), np.array([0.1, 0.1, 0.3])]
    surface = []
    for e, other in (halves, halves[::-1]):
        grids = [np.arange(-e[k], e[k] + 1e-9, 0.0025) for k in range(3)]
        for axis in range(3):
            for side in (-1.0, 1.0):
                axes = [g if k != axis else np.array([side * e[axis]]) for k, g in enumerate(grids)]
                points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
                surface.append(points[~np.all(np.abs(points) < other - 1e-9, axis=1)])
    deep = cKDTree(np.concatenate(surface)).query(xb)[0]
    # every particle within its two layers of the outer surface (h sqrt(2) behind an edge): none
    # about the faces the parts keep inside the overlap
    assert len(xb) and deep.max() < np.sqrt(2.0) * h + 0.002, deep.max()


def test_box_particles_lie_half_a_spacing_inside_the_surface():
    """As a box tank's inner wall layer lies h/2 outside its faces: the liquid resting on a body
    then fills the space the body leaves exactly."""
    from warp_iisph.setup.bodies import sample_body

    h = 0.02
    body = Body(Box((0.1, 0.1, 0.1), (0.3, 0.22, 0.34)), density=500.0)
    body.validate("b")
    s = sample_body(body, h, 1000.0, "cpu")
    x = s["rest"] + s["com"]
    lo, hi = np.array([0.1, 0.1, 0.1]), np.array([0.3, 0.22, 0.34])
    depth = np.minimum(x - lo, hi - x).min(axis=1)
    outer = np.isclose(s["depth"], 0.5 * h)
    assert outer.sum() > 0.5 * len(x) and np.allclose(depth[outer], 0.5 * h)
    assert np.allclose(depth[~outer], h) and np.allclose(s["depth"][~outer], h)
    # every face is covered at about one particle per h^2
    top = outer & np.isclose(x[:, 1], hi[1] - 0.5 * h)
    assert top.sum() == 10 * 12


def swept(method="iisph", **physics) -> Scene:
    """A small dam break sweeping a floating crate into a heavy block resting on the floor."""
    scene = Scene(spacing=0.02, tank=Box((0, 0, 0), (0.6, 0.36, 0.2)), name="swept")
    scene.physics.method = method
    for key, value in physics.items():
        setattr(scene.physics, key, value)
    scene.add_fluid_box((0, 0, 0), (0.2, 0.3, 0.2))
    scene.add_body(Box((0.3, 0.0, 0.05), (0.38, 0.06, 0.15)), density=500.0, name="crate")
    scene.add_body(Box((0.46, 0.0, 0.04), (0.54, 0.08, 0.16)), density=2000.0, name="block")
    return scene


def _state(sim) -> bytes:
    b = sim.bodies
    return b"".join(np.ascontiguousarray(a).tobytes() for a in (sim.positions, sim.velocities, *b.values()))


@pytest.mark.parametrize("method", ["iisph", "dfsph", "wcsph"])
def test_plain_threads_and_graph_give_the_same_bits(method, monkeypatch):
    import warp_iisph.engine.launch as launch

    duration = 0.15 if method != "wcsph" else 0.04
    physics = {"boundary_viscosity": 0.003}
    launch.set_threads(1)
    plain = Simulation(swept(method, **physics), "cpu")
    plain.advance(duration)
    monkeypatch.setattr(launch, "MIN_CHUNK", 50)
    monkeypatch.setattr(launch, "SPLIT_WORTH", 0.0)  # split every launch, however light
    launch.set_threads(3)
    try:
        split = Simulation(swept(method, **physics), "cpu")
        split.advance(duration)
    finally:
        launch.set_threads(launch.available_cores())
    graph = Simulation(swept(method, **physics), "cpu", graph=True)
    graph.advance(duration)
    assert graph.graph.captures == 1 and graph.step_count == plain.step_count == split.step_count > 10
    assert _state(split) == _state(plain) and _state(graph) == _state(plain)
    if method != "wcsph":  # the wave reached the crate: the liquid moved it (WCSPH's short run ends before)
        assert np.linalg.norm(plain.bodies["velocity"][0]) > 0.01


def test_a_resumed_simulation_continues_bitwise():
    first = Simulation(swept(), "cpu")
    first.advance(0.08)
    saved = first.checkpoint()
    first.advance(0.06)
    again = Simulation(swept(), "cpu")
    again.restore(saved)
    again.advance(0.06)
    assert again.step_count == first.step_count and _state(again) == _state(first)
    broken = dict(saved)
    del broken["bodies_momentum"]
    with pytest.raises(ValueError, match="bodies_momentum"):
        Simulation(swept(), "cpu").restore(broken)


def test_a_held_body_stays_still_until_its_release_then_moves_and_resumes_bitwise():
    """A box placed 2 cm above its draft with ``release_time`` 0.1 s keeps its pose bit for bit and
    no speed while the liquid moves around it; released, it sinks; a checkpoint taken while it is
    held continues bitwise through the release, and the graph path gives the same bits."""

    def raised():
        scene = pool(release_time=0.1)
        b = scene.bodies[0].shape
        scene.bodies[0].shape = Box(np.add(b.lower, (0, 0.02, 0)), np.add(b.upper, (0, 0.02, 0)))
        return scene

    sim = Simulation(raised(), "cpu")
    start = {k: v.copy() for k, v in sim.bodies.items()}
    sim.advance(0.05)
    saved = sim.checkpoint()
    sim.advance(0.05)
    held = sim.bodies
    assert all(np.array_equal(held[k], start[k]) for k in ("position", "orientation"))
    assert not held["velocity"].any() and not held["spin"].any()
    assert np.abs(sim.velocities).max() > 0.01  # the liquid moved around it
    sim.advance(0.1)
    assert sim.bodies["position"][0][1] < start["position"][0][1] - 0.003  # released, it sinks
    again = Simulation(raised(), "cpu")
    again.restore(saved)
    for duration in (0.05, 0.1):  # the same calls, so the same steps landing on their ends
        again.advance(duration)
    assert again.step_count == sim.step_count and _state(again) == _state(sim)
    graph = Simulation(raised(), "cpu", graph=True)
    for duration in (0.05, 0.05, 0.1):
        graph.advance(duration)
    assert graph.step_count == sim.step_count and _state(graph) == _state(sim)


def test_a_force_probe_on_a_body_reads_the_load_that_moves_it():
    """A force probe on a free body reads the load its update used: floating at rest, its upward
    load averages to its weight (within 0.5 %) with nothing sideways; held 2 cm below that draft
    (``release_time`` past the run), the buoyancy of its wetted volume below the level a gauge
    reads, within 12 % (-0.3 % measured at h = 0.02, 2.5 spacings of draft; the same box placed by
    literal coordinates reads +7 %: there the fill's initial-compression rule leaves out a ring of
    28 particles beside its bottom edge, by float rounding at the threshold, and the liquid keeps
    that arrangement)."""
    from warp_iisph.scene.probes import Probe

    loads = {}
    for release in (0.0, 10.0):
        scene = pool(spacing=0.02, name="box", release_time=release)
        if release:
            b = scene.bodies[0].shape
            scene.bodies[0].shape = Box(np.add(b.lower, (0, -0.02, 0)), np.add(b.upper, (0, -0.02, 0)))
        scene.add_probe(Probe("F", "force", body="box"))
        scene.add_probe(Probe("level", "level", position=(0.06, 0.06)))
        sim = Simulation(scene, "cpu", history=1)
        sim.advance(1.2)
        late = sim.probes.time > 0.8
        force = {k: sim.probes[f"F.Fp_{k}"][late].mean() + sim.probes[f"F.Fv_{k}"][late].mean() for k in "xyz"}
        bottom = sim.bodies["position"][0][1] - 0.04
        buoyancy = 1000.0 * 9.81 * 0.16**2 * (sim.probes["level"][late].mean() - bottom)
        loads[release] = (force, buoyancy)
    weight = 500.0 * 0.16 * 0.16 * 0.08 * 9.81
    (free, _), (held, buoyancy) = loads[0.0], loads[10.0]
    assert free["y"] == pytest.approx(weight, rel=0.005)
    assert abs(free["x"]) < 1e-3 * weight and abs(free["z"]) < 1e-3 * weight
    assert held["y"] == pytest.approx(buoyancy, rel=0.12) and held["y"] > 1.2 * weight


def settled_draft(density: float) -> tuple:
    """The draft of ``pool``'s box (h = 0.02) over t = 1.0 .. 1.6 s, against the liquid's level by
    its rest volume (particles times h^3; the tank's walls lie h/2 outside its faces, so the liquid
    fills it from y = 0) with the box's submerged volume; the mean horizontal speed of the box and
    of the liquid within 4 cm of its sides (and under it) over the same time; and the simulation
    at its end."""
    scene = pool(spacing=0.02, density=density)
    sim = Simulation(scene, "cpu")
    area, a_box, drafts, heights, box_speed, water_speed = 0.4 * 0.4, 0.16 * 0.16, [], [], [], []
    while sim.time < 1.6 - 1e-9:
        sim.advance(0.05)
        if sim.time > 1.0:
            centre = sim.bodies["position"][0]
            bottom = centre[1] - 0.04
            level = (sim.n_particles * scene.spacing**3 - a_box * bottom) / (area - a_box)
            drafts.append(level - bottom)
            heights.append(bottom)
            box_speed.append(np.linalg.norm(sim.bodies["velocity"][0][[0, 2]]))
            near = np.all(np.abs(sim.positions[:, [0, 2]] - centre[[0, 2]]) < 0.08 + 0.04, axis=1)
            water_speed.append(np.linalg.norm(sim.velocities[near][:, [0, 2]], axis=1).mean())
    return float(np.mean(drafts)), float(np.ptp(heights)), float(np.mean(box_speed)), float(np.mean(water_speed)), sim


# measured (h = 0.02, the box 4 spacings tall, the walls completing the kernel gradient and the
# hydrostatic start, the free bodies' defaults): the drafts 2.5 % (500) and 8.6 % (250) short (from
# the half start 2.8 and 9.8 %), the 250 box's a spacing deep
# (with Akinci's walls 6.4 and 11.6 %; at h = 0.01 the gauges' level puts both within 0.2 %:
# benchmarks/bodies.py); these bounds hold what was measured, with a margin
DRAFT_TOLERANCE = {500.0: 0.05, 250.0: 0.13}


def test_archimedes_boxes_float_at_their_draft():
    """Boxes of density 500 and 250 float at half and a quarter of their height, upright, and stay
    where they were put: resting SPH water keeps currents of a few mm/s, which carry a floating
    box too, so it must move no faster than the water beside it (a force of the coupling's own
    would push it through the water) and stay within a tenth of a spacing of the pool's centre
    (measured from the default hydrostatic start: 0.8 and 1.2 mm off at 1.6 s, at 0.28 and 0.39 of
    the water's speed; over 1-3 s 0.45 of it, 0.12 from the half start: docs/physics.md 4.14)."""
    drafts = {}
    for density in (500.0, 250.0):
        draft, heave, box_speed, water_speed, sim = settled_draft(density)
        b = sim.bodies
        target = density / 1000.0 * 0.08
        assert abs(draft / target - 1) < DRAFT_TOLERANCE[density], (density, draft)
        # upright, not drifting, settled (what is left is the pool's slosh, a few per cent of h)
        assert np.abs(b["orientation"][0, :3]).max() < 0.005
        assert np.abs(b["position"][0][[0, 2]] - 0.2).max() < 0.1 * 0.02
        assert box_speed < water_speed, (box_speed, water_speed)
        assert heave < 0.001, heave
        drafts[density] = draft
    # the lighter box floats higher by about a quarter of the height (+3.5 % measured, +4.1 from the
    # half start: what is left at this spacing is the 250 box's draft of one spacing; with Akinci's
    # walls a share of the load that cancelled here, -1.2 %)
    assert abs((drafts[500.0] - drafts[250.0]) / 0.02 - 1) < 0.07, drafts


def test_a_resumed_run_keeps_its_bodies_bitwise(tmp_path):
    """A run with free bodies stopped after a checkpoint and resumed writes the same particles,
    bodies.csv and body frames as the run that never stopped."""
    from warp_iisph.run.formats import read_particles
    from warp_iisph.run.runner import resumed_scene, run_scene
    from warp_iisph.run.solids import read_bodies

    whole, cut = tmp_path / "whole", tmp_path / "cut"
    run_scene(swept(), whole, duration=0.1, fps=40, progress=False)
    run_scene(swept(), cut, duration=0.05, fps=40, progress=False)
    assert run_scene(resumed_scene(cut), cut, duration=0.1, fps=40, progress=False, resume=True)["ended"] == "completed"
    names, rows = read_bodies(whole / "bodies.csv")
    assert names == ["crate", "block"] and rows.shape == (5, 1 + 2 * 13)
    assert (cut / "bodies.csv").read_text() == (whole / "bodies.csv").read_text()
    for k in range(5):
        frame = f"frame_{k:05d}"
        assert (cut / "obstacles" / f"{frame}.obj").read_bytes() == (whole / "obstacles" / f"{frame}.obj").read_bytes()
        a, b = (read_particles(r / "particles" / f"{frame}.ply") for r in (whole, cut))
        assert all(np.array_equal(a[q], b[q]) for q in ("x", "v", "id"))
    assert np.linalg.norm(rows[-1, 1 + 7 : 1 + 10]) > 0.0  # the crate moves


@pytest.mark.parametrize("warm_start", [None, "half"])
def test_a_heavy_box_sinks_and_comes_to_rest_on_the_floor(warm_start):
    """A box of density 2,000 released in the liquid sinks onto the floor and rests there: upright,
    still, with no particle inside it, from the default warm start, the hydrostatic one (which
    keeps at least half the last pressure beside a body: from the column's estimate alone the film
    under it kept the box jittering at 0.10 m/s), and from the half start (the two cases). Its
    bottom rests on one trapped layer of liquid (measured 0.012 m, 0.6 h: a film thinner than a spacing does not drain
    at this resolution), and its velocity keeps a jitter of a few cm/s from that film (measured at
    most 0.039 m/s with Akinci's walls, mean -0.002 m/s over 1.0 .. 1.3 s; 0.083 m/s from the
    hydrostatic start with the walls completing the kernel gradient, the free bodies' default
    since 2026-12-06: the film's particles are held by the solve alone). Before the film particles' diagonal
    counted the walls on both sides (sph/solvers/iisph.py), this run diverged at t = 0.615 s."""
    from warp_iisph.scene.bodies import quaternion_matrix

    scene = Scene(spacing=0.02, tank=Box((0, 0, 0), (0.24, 0.4, 0.24)), name="sink")
    scene.add_fluid_box((0, 0, 0), (0.24, 0.2, 0.24))
    scene.add_body(Box((0.04, 0.06, 0.04), (0.2, 0.14, 0.2)), density=2000.0)
    scene.physics.warm_start = warm_start
    sim = Simulation(scene, "cpu")
    sim.advance(1.0)  # diverges (DivergenceError) if the solve blows up in the film
    half = np.array([0.08, 0.04, 0.08])
    bottoms, velocities = [], []
    while sim.time < 1.3 - 1e-9:
        sim.step()
        b = sim.bodies
        bottoms.append(b["position"][0][1] - half[1])
        velocities.append(b["velocity"][0].copy())
        local = (sim.positions - b["position"][0]) @ quaternion_matrix(b["orientation"][0])
        assert not np.any(np.all(np.abs(local) < half, axis=1)), sim.time  # no particle inside it
    bottoms, velocities = np.array(bottoms), np.array(velocities)
    assert np.all(bottoms < scene.spacing) and np.all(bottoms > 0.0), bottoms  # on the floor, within a spacing
    assert np.ptp(bottoms) < 0.1 * scene.spacing, np.ptp(bottoms)  # at rest: it stays where it is
    assert abs(velocities[:, 1].mean()) < 0.005 and np.linalg.norm(velocities, axis=1).max() < 0.1
    assert np.abs(sim.bodies["orientation"][0, :3]).max() < 0.02  # upright


def test_momentum_balances_in_a_closed_tank():
    """A box released 2 cm below its draft heaves in a closed pool. Per step, the body's change
    of momentum is (liquid's force + gravity) dt plus the added-mass term's
    ``M_a (a_last - a) dt`` (sph/rigid.py; no contact here), to float64 precision (1e-12 N s
    against momenta of 1e-2 N s); over the
    steps that term telescopes, so the body's momentum follows the liquid's force and gravity
    alone within the sum's two ends and what the step's dt, wetted share and pose change from one
    step to the next (summed by parts; the ends alone held by luck, within 1e-8 across the
    heave). The liquid and the body together change momentum by
    gravity plus the tank walls' impulse (sph/wall_forces.py on the tank's particles): measured
    within 1.0e-4 of the gravity impulse over 60 steps (the containment's corrections, 4 here,
    and the float32 particle sums included); bound 1e-3."""
    from warp_iisph.scene.bodies import quaternion_matrix
    from warp_iisph.sph.wall_forces import WallForces

    scene = pool(spacing=0.02)
    box = scene.bodies[0].shape
    scene.bodies[0].shape = Box(np.add(box.lower, (0, -0.02, 0)), np.add(box.upper, (0, -0.02, 0)))
    sim = Simulation(scene, "cpu")
    rig, loads = sim.loop.bodies.rigid, sim.loop.bodies.loads
    first, count = rig.first[0], rig.counts[0]
    assert first + count == sim.model.n_boundary  # the body's particles after the tank's
    tank = WallForces.of_ranges(sim.model, sim.solver, [(0, first)])
    m, M, g = float(sim.model.mass), float(rig.constants.mass.numpy()[0]), np.asarray(scene.physics.gravity)
    added = rig.constants.added_mass.numpy()[0]
    sim.advance(0.05)
    a_first = sim.bodies["coupled"][0].copy()
    liquid, body, expected_body, total, expected_total, weight = (np.zeros(3) for _ in range(6))
    scales, coupled = [], [a_first]  # each step's dt wet R M_a R^T and the coupled accelerations
    for _ in range(60):
        before = {k: v[0].copy() for k, v in sim.bodies.items()}
        before_v, before_c = before["velocity"], before["coupled"]
        before_p = m * sim.velocities.astype(np.float64).sum(axis=0)
        record = sim.step()
        tank.compute(sim.state)
        dt, b = record["dt"], sim.bodies
        assert not rig.contacts.active.numpy().any()
        F = loads.totals.numpy()[0]
        F = F[:3] + F[3:6]
        R = quaternion_matrix(before["orientation"])  # the pose the step's update used
        wet = loads.wetted.numpy()[0] / count
        extra = dt * wet * (R @ added @ R.T) @ (before_c - b["coupled"][0])  # the added-mass term
        change = M * (b["velocity"][0] - before_v)
        assert np.allclose(change, dt * (F + M * g) + extra, rtol=0, atol=1e-12), change - dt * (F + M * g) - extra
        body += change
        expected_body += dt * (F + M * g)
        scales.append(dt * wet * (R @ added @ R.T))
        coupled.append(b["coupled"][0].copy())
        T = tank.totals.numpy()[0]
        liquid_change = m * sim.velocities.astype(np.float64).sum(axis=0) - before_p
        total += liquid_change + change
        expected_total += dt * ((sim.n_particles * m + M) * g - T[:3] - T[3:6])
        weight += dt * (sim.n_particles * m + M) * np.abs(g)
    assert np.linalg.norm(sim.bodies["velocity"][0]) > 0.01  # it heaves
    # sum_k S_k (c_k-1 - c_k) = S_1 c_0 - S_N c_N + sum_k (S_k+1 - S_k) c_k (summation by parts): the
    # ends, and what the step's dt, wetted share and pose change between steps
    S, c = scales, coupled
    bound = np.abs(S[0]) @ np.abs(c[0]) + np.abs(S[-1]) @ np.abs(c[-1]) + 1e-12
    bound += sum(np.abs(S[k + 1] - S[k]) @ np.abs(c[k + 1]) for k in range(len(S) - 1))
    assert np.all(np.abs(body - expected_body) <= bound), (body, expected_body, bound)
    assert np.all(np.abs(total - expected_total) <= 1e-3 * weight[1]), (total, expected_total, weight)


def test_bodies_benchmark_quick_mode(tmp_path):
    """benchmarks/bodies.py --quick: the flood (coarse, short) with free and with fixed bodies (from
    the default and from the half warm start) and with the boxes moved along the free bodies'
    paths, the drafts (IISPH's and DFSPH's) and DFSPH's heave, and what sets the flood's step,
    into its JSON and chart; the liquid is never found past a wall."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    proc = subprocess.run(
        [sys.executable, str(root / "benchmarks" / "bodies.py"), "--quick", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    record = json.loads((tmp_path / "bodies_quick.json").read_text())
    assert record["versions"]["warp"] and record["date"] and (tmp_path / "bodies_quick.png").stat().st_size > 10_000
    runs = record["flood"]["runs"]
    assert [r["variant"] for r in runs] == ["free", "fixed", "replayed", "free_half", "fixed_half", "replayed_half"]
    # no centre past a wall, and none inside a free body's surface (a still box's wall is h/2 inside it)
    assert all(r["past_walls_at_frames"] == 0 and not r["body_left_tank"] and r["steps"] > 0 for r in runs)
    assert runs[0]["inside_bodies_at_frames"] == 0 and runs[3]["inside_bodies_at_frames"] == 0
    summary = record["flood"]["summary"]
    assert summary["cost_ratio"] > 0 and summary["cost_ratio_half_start"] > 0
    assert summary["cost_ratio_free_half_to_fixed"] > 0
    # the boxes moved along the free bodies' paths, from each start: the coupling's own cost
    assert summary["cost_ratio_free_to_replayed"] > 0 and summary["cost_ratio_free_half_to_replayed_half"] > 0
    # the other landing schedules (quick: in one call only) beside the timed runs' 30 fps
    schedules = summary["schedules"]
    assert set(schedules) == {"30", "0", "median_step_ratio", "median_cost_ratio"}, schedules
    assert [r["fps"] for r in record["flood"]["schedule_runs"]] == [0.0, 0.0]
    assert schedules["0"]["steps"][0] > 0 and schedules["median_step_ratio"] > 0
    (heave,) = record["heave"]["runs"]  # the fit found an oscillation, not a flat line
    assert 0.2 < heave["damped_period"] < 2.0 and 0.0 <= heave["damping_ratio"] < 0.95
    assert [(d["spacing"], d["density"]) for d in record["drafts"]] == [(0.04, 500.0), (0.04, 250.0)]
    assert [(d["method"], d["spacing"], d["density"]) for d in record["dfsph_drafts"]] == [
        ("dfsph", 0.04, 500.0),
        ("dfsph", 0.04, 250.0),
    ]
    for d in record["drafts"] + record["dfsph_drafts"]:  # below both levels: the rest volume's, the gauges'
        assert 0.0 < d["draft"] < 0.08 and 0.0 < d["draft_gauges"] < 0.08 and len(d["gauge_levels"]) == 6
    dfsph_heave = record["dfsph_heave"]  # DFSPH in the heave scene (coarse): a swing, fitted
    assert dfsph_heave["spacing"] == 0.04 and 0.2 < dfsph_heave["damped_period"] < 2.0
    # what sets the step: each flight over the threshold counted once, its steps adding up
    setters = record["step_setters"]["runs"]
    assert list(setters) == ["free", "replayed", "fixed"] and record["step_setters"]["speed"] == 1.0
    assert setters["free"]["fast_steps"] > 0 and setters["free"]["episodes"]
    for r in setters.values():
        assert r["steps"] > 0 and 0 <= r["lone_fast_steps"] <= r["fast_steps"] < r["steps"]
        assert sum(e["steps"] for e in r["episodes"]) == r["fast_steps"]
        assert len(r["t"]) == len(r["fastest"]) == r["steps"] and np.all(np.diff(r["t"]) > 0)
        assert r["fast_steps"] == sum(v > record["step_setters"]["speed"] for v in r["fastest"])
        assert r["steps_of_flights_from_between_two_boxes"] <= r["fast_steps"]
        assert 0.0 <= r["steps_lone_droplets_added"] <= r["lone_fast_steps"]
    assert set(record["part_dates"]) == {"flood", "drafts", "heave", "dfsph_drafts", "dfsph_heave", "step_setters"}


def plate_at_rest(box, n: int):
    """The containment of a free body at rest, a plate 2 mm thick and 0.1 m square centred at the
    origin (spacing 0.01 m), in the box tank ``box`` ((lower, upper), or None), with boundary lists
    in which each of ``n`` particles had a wall neighbour at the step's start."""
    import trimesh
    import warp as wp

    from warp_iisph.sph.bodies import Poses
    from warp_iisph.sph.containment import Containment
    from warp_iisph.sph.neighbors import NeighborListBuffer

    plate = trimesh.creation.box(extents=(0.1, 0.002, 0.1))
    walls = Containment("cpu", box, [(plate.vertices, plate.faces, 0, False)], spacing=0.01)
    poses = Poses()
    still = wp.array([wp.transform_identity()], dtype=wp.transform, device="cpu")
    poses.start, poses.end, poses.before = still, still, still
    poses.free = wp.array([1], dtype=wp.int32, device="cpu")
    for name in ("velocity", "spin", "acceleration", "angular_acceleration"):
        setattr(poses, name, wp.zeros(1, dtype=wp.vec3, device="cpu"))
    walls.poses = poses
    near = NeighborListBuffer(n, "cpu", capacity=n)
    near.lists.count.fill_(1)
    return walls, near


def test_a_particle_put_back_where_its_path_entered_a_body_keeps_only_the_motion_it_kept():
    """The containment's path test (sph/containment.py): a particle whose step carried it through
    a free body thinner than the step (a plate 2 mm thick, at rest) is put back where its path
    entered, and its velocity is the motion it kept over the step, not the velocity that carried
    it through: the fraction of the step before the entry, along the plate only. Keeping the
    tangential velocity instead let a particle pinned in a film between a crate and a tank wall
    keep every step's pressure kick, still where it stood, until its speed ran away (the bundled
    ``flood`` advanced in one call diverged so at t = 0.845 s)."""
    import warp as wp

    from warp_iisph.sph.containment import CLEARANCE

    walls, near = plate_at_rest((np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])), 1)
    dt, v0 = 0.01, np.array([1.0, -1.0, 0.0])  # from 6 mm above the plate's middle to 4 mm below it
    end = np.array([0.0, 0.006, 0.0]) + dt * v0
    x = wp.array([end], dtype=wp.vec3, device="cpu")
    v = wp.array([v0], dtype=wp.vec3, device="cpu")
    walls.apply(x, v, near.lists, 1, wp.array([dt], dtype=wp.float64, device="cpu"))
    kept = 0.005 / 0.01  # the path enters the plate's top face (y = 1 mm) halfway through the step
    assert walls.corrections.numpy().tolist() == [0, 1]
    np.testing.assert_allclose(x.numpy()[0], [kept * dt, 0.001 + CLEARANCE * 0.01, 0.0], atol=1e-6)
    # along the plate half its speed (it was kept whole), across it the clearance's step off the face
    np.testing.assert_allclose(v.numpy()[0], [kept * v0[0], CLEARANCE * 0.01 / dt, 0.0], atol=1e-5)


def test_the_path_test_traces_every_path_that_could_cross_a_body():
    """The containment traces a particle's path through a free body only where it could cross it:
    where the body's surface is within the reach (2 spacings) of the path's end, or the path is at
    least that long (sph/containment.py). A path from 3 cm above a 2 mm plate to 2.6 cm below it
    (longer than the reach, its end beyond it) is still put back where it entered, and one 1 cm
    long ending 2.5 cm from the plate is left alone."""
    import warp as wp

    from warp_iisph.sph.containment import CLEARANCE

    walls, near = plate_at_rest(None, 2)
    dt = 0.01
    v0 = np.array([[0.0, -5.6, 0.0], [0.0, -1.0, 0.0]])  # through the plate; towards it, short of it
    end = np.array([[0.0, 0.03, 0.0], [0.02, 0.036, 0.0]]) + dt * v0
    x = wp.array(end, dtype=wp.vec3, device="cpu")
    v = wp.array(v0, dtype=wp.vec3, device="cpu")
    walls.apply(x, v, near.lists, 2, wp.array([dt], dtype=wp.float64, device="cpu"))
    assert walls.corrections.numpy().tolist() == [0, 1]
    np.testing.assert_allclose(x.numpy()[0], [0.0, 0.001 + CLEARANCE * 0.01, 0.0], atol=1e-6)
    np.testing.assert_allclose(x.numpy()[1], end[1], atol=1e-7)


@pytest.mark.parametrize("fixed_step", [False, True], ids=["cfl", "fixed 4 ms"])
@pytest.mark.parametrize("body", ["thin mesh plate", "fast sphere"])
def test_fast_impacts_leave_no_particle_inside_a_body(body, fixed_step, tmp_path):
    """The liquid never passes through a body: a mesh plate 8 mm thick (0.4 spacings: one layer
    of boundary particles) slapping flat onto a pool at 4 m/s (6 m/s with the fixed step), and a
    dense sphere hitting it at 5 m/s, checked after every step in the body's frame (deeper than
    1 micrometre: a particle on a face reads a float32 rounding inside), under the CFL rule and
    with a fixed 4 ms step taken as it is (the sphere then moves 2 cm, a spacing, a step).
    Measured: the pressure alone keeps the liquid out of the plate in both and of the sphere
    under the CFL rule; with the fixed step the sphere's impact leaves one particle inside it
    without the last line (sph/containment.py), which puts it back."""
    import trimesh

    from warp_iisph import MeshShape
    from warp_iisph.scene.bodies import quaternion_matrix

    scene = Scene(spacing=0.02, tank=Box((0, 0, 0), (0.4, 0.5, 0.4)), name="impact")
    scene.add_fluid_box((0, 0, 0), (0.4, 0.2, 0.4))
    if body == "thin mesh plate":
        half = np.array([0.08, 0.004, 0.08])
        trimesh.creation.box(extents=2 * half).export(tmp_path / "plate.obj")
        shape = MeshShape("plate.obj", translate=(0.2, 0.25, 0.2), base_dir=str(tmp_path))
        scene.add_body(shape, density=900.0, velocity=(0.0, -6.0 if fixed_step else -4.0, 0.0))

        def inside(local):
            return np.all(np.abs(local) < half - 1e-6, axis=1)
    else:
        radius = 0.05
        scene.add_body(Sphere((0.2, 0.28, 0.2), radius), density=2000.0, velocity=(0.0, -5.0, 0.0))
        # the containment's sphere is its icosphere (scene/shapes.py): inside that, its faces' nearest
        # points (the tessellation lies up to 3e-5 m inside the sphere)
        sphere = trimesh.creation.icosphere(subdivisions=4, radius=radius)
        inscribed = np.abs(np.einsum("ij,ij->i", sphere.face_normals, sphere.triangles_center)).min()

        def inside(local):
            return np.linalg.norm(local, axis=1) < inscribed - 1e-6

    if fixed_step:  # a step the body crosses its own thickness in: the pressure cannot keep up
        scene.physics.dt, scene.physics.substeps = 0.004, False
    sim = Simulation(scene, "cpu")
    worst, put_back, speeds = 0, 0, []
    while sim.time < 0.15 - 1e-9:
        record = sim.step()
        b = sim.bodies
        local = (sim.positions - b["position"][0]) @ quaternion_matrix(b["orientation"][0])
        worst = max(worst, int(inside(local).sum()))
        put_back += record["obstacle_corrections"]
        speeds.append(abs(b["velocity"][0][1]))
    assert speeds[0] > 3.5 and min(speeds) < 0.5 * speeds[0]  # it hit the water fast, and the water slowed it
    assert worst == 0, (worst, put_back)


def test_a_body_spinning_freely_keeps_its_angular_momentum_and_its_energy():
    """No liquid touches it and gravity is off: its angular momentum is exact, and its kinetic
    energy too, to the midpoint turn's accuracy (turning at the start's angular velocity it gained
    2.4 % in 4 s at 3.7 rad/s and 4.1 % in 2 s at 8 rad/s about its middle axis); the start's spin
    about a fixed axis is dropped at once, as every step drops it."""
    scene = Scene(spacing=0.05, tank=Box((0, 0, 0), (1.2, 1.2, 1.2)))
    scene.add_fluid_box((0, 0, 0), (0.1, 0.1, 0.1))
    scene.physics.gravity = (0.0, 0.0, 0.0)
    scene.add_body(Box((0.45, 0.5, 0.55), (0.75, 0.7, 0.65)), density=500.0, angular_velocity=(0.5, 8.0, 0.5))
    sim = Simulation(scene, "cpu")

    def energy_and_momentum():
        b = sim.bodies
        return 0.5 * float(np.dot(b["spin"][0], b["momentum"][0])), b["momentum"][0].copy()

    e0, l0 = energy_and_momentum()
    sim.advance(2.0)
    e1, l1 = energy_and_momentum()
    assert np.allclose(l1, l0, rtol=0.0, atol=1e-12)
    assert abs(e1 / e0 - 1.0) < 1e-4
    assert np.abs(sim.bodies["orientation"][0][:3]).max() > 0.1  # it did turn

    held = Scene(spacing=0.05, tank=Box((0, 0, 0), (1.2, 1.2, 1.2)))
    held.add_fluid_box((0, 0, 0), (0.1, 0.1, 0.1))
    held.add_body(
        Box((0.45, 0.5, 0.55), (0.75, 0.7, 0.65)),
        density=500.0,
        angular_velocity=(1.0, 2.0, 3.0),
        velocity=(0.1, 0.2, 0.3),
        fixed_axes=["x", "rx", "rz"],
    )
    b = Simulation(held, "cpu").bodies
    assert b["velocity"][0][0] == 0.0 and np.allclose(b["spin"][0], (0.0, 2.0, 0.0))
    assert b["momentum"][0][0] == 0.0 and b["momentum"][0][2] == 0.0


def test_contacts_query_only_the_solids_a_body_can_reach():
    """A body's samples query a solid only where the spheres holding them and the solid lie within
    a sample's reach (sph.contacts.near_partners): the gaps and normals are bitwise those of
    querying every solid, with the far ones (the post, the crates downstream) ruled out."""
    import warp as wp

    from warp_iisph.sph.contacts import near_partners, sample_gaps

    sim = Simulation(load_scene("flood", ["spacing=0.03"]), "cpu")
    sim.advance(0.3)
    model = sim.model
    rigid, solids, poses = model.rigid, model.containment.solids, model.bodies.poses
    cs, n = rigid.contacts, rigid.n_samples

    def gaps():
        cs.gap.zero_()
        cs.normal.zero_()
        wp.launch(sample_gaps, dim=n, inputs=[0, cs, solids, poses, model.boundary_x, n], device="cpu")
        return cs.gap.numpy().copy(), cs.normal.numpy().copy()

    wp.launch(
        near_partners, dim=(rigid.n, solids.count), inputs=[cs, solids, poses, rigid.constants.radius], device="cpu"
    )
    near = cs.near.numpy()[: rigid.n * solids.count].reshape(rigid.n, solids.count).copy()
    culled = gaps()
    cs.near.fill_(1)
    every = gaps()
    assert np.array_equal(culled[0], every[0]) and np.array_equal(culled[1], every[1])
    assert (culled[0] < 1.0e29).sum() > 0  # some samples touch something
    assert near.sum() < near.size and near.sum() > 0
    post = 0  # the scene's own obstacle comes first among the solids
    assert near[:, post].sum() == 0  # no crate near the post at 0.3 s
