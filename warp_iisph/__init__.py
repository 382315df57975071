"""warp_iisph: Implicit Incompressible SPH liquids on NVIDIA Warp."""

__version__ = "0.1.0"

from . import scenes
from .scene import Box, Camera, MeshShape, Output, Physics, Scene, Sphere
from .scenefile import load_scene
from .simulation import DivergenceError, Simulation

__all__ = [
    "Box", "Camera", "MeshShape", "Output", "Physics", "Scene", "Sphere", "Simulation", "DivergenceError",
    "load_scene", "scenes", "__version__",
]
