"""warp_iisph: Implicit Incompressible SPH liquids on NVIDIA Warp.

The package is laid out by pipeline stage: ``scene`` (what the user describes) -> ``setup``
(particles on a device) -> ``stepping`` (time steps of the ``sph`` method) -> ``surface`` (meshes)
-> ``run`` (files of a run) -> ``view`` (videos, renders, Blender); ``engine`` holds what every
stage shares (devices, CPU thread launches, timing), ``analysis`` the checks against experiments.
"""

__version__ = "0.1.0"

# Everything is imported when first asked for, so that importing the package costs nothing: the
# command line (warp_iisph.cli) takes over Ctrl-C first, and starts (or reports bad input) before
# NumPy and Warp load.
_SCENE = (
    "Body",
    "Box",
    "Camera",
    "Emitter",
    "MeshShape",
    "Motion",
    "Output",
    "Physics",
    "Probe",
    "Scene",
    "Sink",
    "Sphere",
    "load_scene",
)
_STEPPING = ("Simulation", "DivergenceError", "LiquidFullWarning")


def __getattr__(name: str):
    if name in _SCENE:
        from . import scene

        return getattr(scene, name)
    if name == "scenes":
        from .scene import cases

        return cases
    if name in _STEPPING:
        from . import stepping

        return getattr(stepping, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [*_SCENE, "scenes", *_STEPPING, "__version__"]
