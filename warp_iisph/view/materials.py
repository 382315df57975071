"""Liquids by their colour: what 5 cm of each looks like, shared by the renderer and the Blender script."""

from __future__ import annotations

from ..run.folder import RunError

# Colour seen through 5 cm of the liquid (linear RGB); absorption sigma_a = -ln(colour) / 0.05 m.
MATERIALS = {"water": (0.92, 0.97, 0.99), "wine": (0.45, 0.03, 0.08), "whisky": (0.80, 0.45, 0.12)}
THICKNESS = 0.05
IOR = 1.33


def material_color(spec: str) -> tuple[float, float, float]:
    """A preset name or ``r,g,b`` in (0, 1]: the colour of 5 cm of the liquid."""
    if spec in MATERIALS:
        return MATERIALS[spec]
    try:
        rgb = tuple(float(v) for v in spec.split(","))
    except ValueError:
        rgb = ()
    if len(rgb) != 3 or not all(0.0 < c <= 1.0 for c in rgb):
        raise RunError(f"--material {spec!r}: must be one of {', '.join(MATERIALS)} or r,g,b with each in (0, 1]")
    return rgb
