"""Standard cases built in Python: the validation and benchmark scenes the tests and benchmarks use
(the bundled scene files are what the command line runs)."""

from __future__ import annotations

from .description import Scene
from .settings import Physics
from .shapes import Box


def martin_moyce(
    spacing: float = 0.02, a: float = 0.2, depth: float = 0.2, length: float = 1.0, height: float = 0.6, **physics
) -> Scene:
    """Martin & Moyce (1952) geometry: a water column of width ``a`` and height ``2a`` against
    the x = 0 wall of a closed ``length x height x depth`` tank (metres)."""
    scene = Scene(
        spacing=spacing,
        tank=Box((0.0, 0.0, 0.0), (length, height, depth)),
        physics=Physics(**physics),
        name="martin_moyce",
    )
    scene.add_fluid_box((0.0, 0.0, 0.0), (a, 2.0 * a, depth))
    return scene


def dam_break_cube(spacing: float = 0.03, particles: int | None = None, **physics) -> Scene:
    """The benchmark dam break: a 0.96 m cube of water (32^3 particles at 3 cm) in a
    4 x 3 x 1.5 m tank, as in SPlisHSPlasH's comparison runs. With ``particles``, the cube
    keeps its 0.96 m side and the spacing is chosen to hold about that many particles."""
    side = 32 * spacing
    if particles is not None:
        if isinstance(particles, bool) or not isinstance(particles, int) or not 1 <= particles <= 10**9:
            raise ValueError(f"particles = {particles!r}: must be a whole number in [1, 1e9]")
        side = 0.96
        spacing = side / round(particles ** (1.0 / 3.0))
    scene = Scene(
        spacing=spacing, tank=Box((0.0, 0.0, 0.0), (4.0, 3.0, 1.5)), physics=Physics(**physics), name="dam_break_cube"
    )
    scene.add_fluid_box((0.0, 0.0, 0.0), (side, side, side))
    return scene


def hydrostatic_tank(
    spacing: float = 0.02, width: float = 0.2, depth: float = 0.2, water_height: float = 0.4, **physics
) -> Scene:
    """Water at rest filling the bottom of a closed tank."""
    scene = Scene(
        spacing=spacing,
        tank=Box((0.0, 0.0, 0.0), (width, water_height + 4 * spacing, depth)),
        physics=Physics(**physics),
        name="hydrostatic_tank",
    )
    scene.add_fluid_box((0.0, 0.0, 0.0), (width, water_height, depth))
    return scene
