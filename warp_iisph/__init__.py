"""warp_iisph: Implicit Incompressible SPH liquids on NVIDIA Warp."""

__version__ = "0.1.0"

from . import scenes
from .scene import Box, Physics, Scene, Sphere
from .simulation import DivergenceError, Simulation

__all__ = ["Box", "Physics", "Scene", "Sphere", "Simulation", "DivergenceError", "scenes", "__version__"]
