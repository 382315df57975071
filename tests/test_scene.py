"""Out-of-range parameters raise a ValueError naming the field and the allowed range."""

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
