"""warp_iisph: Implicit Incompressible SPH liquids on NVIDIA Warp.

The package is laid out by pipeline stage: ``scene`` (what the user describes) -> ``setup``
(particles on a device) -> ``stepping`` (time steps of the ``sph`` method) -> ``surface`` (meshes)
-> ``run`` (files of a run) -> ``view`` (videos, renders, Blender); ``engine`` holds what every
stage shares (devices, CPU thread launches, timing), ``analysis`` the checks against experiments.
"""

__version__ = "0.1.0"

from .scene import Box, Camera, MeshShape, Output, Physics, Probe, Scene, Sphere, load_scene
from .scene import cases as scenes


def __getattr__(name: str):
    # the simulation imports Warp: only when asked for, so that `warp-iisph` starts (and can be
    # interrupted, or report bad input) before Warp loads
    if name in ("Simulation", "DivergenceError"):
        from . import stepping

        return getattr(stepping, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "Box",
    "Camera",
    "MeshShape",
    "Output",
    "Physics",
    "Probe",
    "Scene",
    "Sphere",
    "Simulation",
    "DivergenceError",
    "load_scene",
    "scenes",
    "__version__",
]
