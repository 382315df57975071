"""Out-of-range parameters raise a ValueError naming the field and the allowed range."""

import os

import numpy as np
import pytest

from warp_iisph import Box, Scene, Simulation, scenes


def _scene(**kw):
    s = scenes.martin_moyce(spacing=0.02)
    for k, v in kw.items():
        setattr(s, k, v)
    return s


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda s: setattr(s, "spacing", 0.0), r"spacing = 0.0: must be > 0"),
        (lambda s: setattr(s, "spacing", -0.01), r"spacing = -0.01: must be > 0"),
        (lambda s: setattr(s.physics, "eta", 0.0), r"physics.eta = 0.0: must be in \(0, 0.5\]"),
        (lambda s: setattr(s.physics, "eta", -1e-3), r"physics.eta"),
        (lambda s: setattr(s.physics, "method", "pcisph"), r"physics.method = 'pcisph': must be one of iisph, wcsph"),
        (
            lambda s: setattr(s.physics, "max_iterations", 0),
            r"physics.max_iterations = 0: must be an integer in \[1, 100000\]",
        ),
        (lambda s: setattr(s.physics, "viscosity", -1.0), r"physics.viscosity = -1.0: must be in \[0, 1\]"),
        (lambda s: setattr(s.physics, "dt", 0.0), r"physics.dt = 0.0"),
        (
            lambda s: setattr(s.physics, "warm_start", "full"),
            r"physics.warm_start = 'full': must be one of hydrostatic, half, half_hydrostatic",
        ),
        (
            lambda s: (setattr(s.physics, "warm_start", "hydrostatic"), setattr(s.physics, "method", "dfsph")),
            r"physics.warm_start = 'hydrostatic': IISPH's only",
        ),
        (
            lambda s: (
                setattr(s.physics, "warm_start", "hydrostatic"),
                setattr(s.physics, "gravity", (1.0, -9.81, 0.0)),
            ),
            r"physics.warm_start = 'hydrostatic': needs physics.gravity along an axis",
        ),
        (
            lambda s: s.add_fluid_box((0.9, 0.0, 0.0), (1.2, 0.1, 0.1)),
            r"fluids\[1\]: fluid .* must lie inside the tank",
        ),
        (lambda s: s.add_fluid_box((0.1, 0.1, 0.0), (0.3, 0.3, 0.1)), r"fluids\[0\] and fluids\[1\] overlap"),
        (lambda s: s.add_fluid_sphere((0.25, 0.2, 0.1), 0.1), r"fluids\[0\] and fluids\[1\] overlap"),
        (lambda s: s.add_fluid_sphere((0.9, 0.5, 0.1), 0.2), r"fluids\[1\]: fluid .* must lie inside the tank"),
        (lambda s: setattr(s, "tank", Box((0, 0, 0), (1.0, -1.0, 1.0))), r"tank: upper .* must exceed lower"),
    ],
)
def test_bad_parameters_name_field_and_range(mutate, match):
    s = _scene()
    mutate(s)
    with pytest.raises(ValueError, match=match):
        Simulation(s, "cpu")


def test_touching_blocks_and_spheres_are_accepted():
    s = Scene(spacing=0.02, tank=Box((0, 0, 0), (1, 1, 1)))
    s.add_fluid_box((0, 0, 0), (0.5, 0.2, 1)).add_fluid_box((0.5, 0, 0), (1, 0.2, 1)).add_fluid_sphere(
        (0.5, 0.6, 0.5), 0.2
    )
    sim = Simulation(s, "cpu")
    assert sim.n_particles > 0
    assert abs(sim.n_particles * 0.02**3 - (0.2 + 4 / 3 * 3.14159 * 0.2**3)) < 0.01


def test_a_spacing_typed_to_a_few_digits_keeps_the_blocks_volume():
    """SPHERIC Test 2's column, 0.55 x 1 m across, at 0.016667 m (1/60 to six digits): the lattice
    holds 33 x 60 columns as at 1/60 exactly (it held 32 x 59 until 2026-12-05, 5 % of the water
    lost), and a spacing that really differs (0.0167) still fills only the whole layers it fits;
    an emitter's nozzle counts its columns alike."""
    from warp_iisph.setup.sampling import sample_fluid

    tank, column = Box((0, 0, 0), (3.22, 1, 1)), Box((1.992, 0, 0), (3.22, 0.55, 1))
    exact = sample_fluid([column], tank, 1 / 60)
    typed = sample_fluid([column], tank, 0.016667)
    assert len(exact) == len(typed) == 73 * 33 * 60
    assert np.all(typed[:, 2] <= 1.0 - 0.49 * 0.016667)  # the last column stays h/2 inside the tank's face
    assert len(sample_fluid([column], tank, 0.0167)) == 73 * 32 * 59
    # a nozzle's layer the same: 0.1 x 0.05 m at 0.016667 m is 6 x 3 particles, as at 1/60
    from warp_iisph.scene import Emitter

    nozzle = Emitter(center=(0.5, 0.5, 0.5), direction=(1.0, 0.0, 0.0), speed=1.0, shape="rectangle", size=(0.1, 0.05))
    assert nozzle.layer_size(0.016667) == len(nozzle.layer(0.016667)) == nozzle.layer_size(1 / 60) == 18


def test_a_misspelt_key_or_keys_beside_a_body_are_refused_not_ignored():
    """Setting a key a record does not have (``physics.etaa``) would be ignored without a word, as
    would keys given beside a ready Body: both refused, naming them."""
    from warp_iisph.scene import Body

    s = scenes.martin_moyce(spacing=0.02)
    with pytest.raises(AttributeError, match=r"Physics.etaa: no such key; the keys are .*\beta\b"):
        s.physics.etaa = 0.1
    with pytest.raises(AttributeError, match=r"Scene.spacng: no such key"):
        s.spacng = 0.01
    s.physics.eta = 0.002  # a real key as before
    body = Body(Box((0.3, 0.1, 0.05), (0.4, 0.2, 0.15)), density=500.0)
    with pytest.raises(ValueError, match=r"add_body: a Body carries its own keys; mass given beside it"):
        s.add_body(body, mass=3.0)


def test_a_mesh_file_edited_between_simulations_is_read_again(tmp_path):
    """A Scene whose obstacle mesh file is replaced on disk builds its next Simulation from the new
    file (it was read once and kept), checked again as a new one would be."""
    import trimesh

    from warp_iisph import MeshShape

    path = tmp_path / "rock.obj"
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(path)
    s = Scene(spacing=0.02, tank=Box((0, 0, 0), (0.6, 0.4, 0.3)), name="rock")
    s.add_fluid_box((0, 0, 0), (0.2, 0.2, 0.3))
    s.add_obstacle(MeshShape("rock.obj", translate=(0.4, 0.1, 0.15), base_dir=str(tmp_path)))
    small = Simulation(s, "cpu").model.n_boundary
    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(path)
    os.utime(path, ns=(1, 1))  # even with the old time stamp: the size and inode say it changed
    assert Simulation(s, "cpu").model.n_boundary > small
    open_box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    open_box.update_faces(np.arange(len(open_box.faces)) > 1)  # one side taken off: not closed
    open_box.export(path)
    with pytest.raises(ValueError, match=r"obstacles\[0\].path = 'rock.obj': .*closed"):
        Simulation(s, "cpu")
