"""What the user describes: shapes, settings and the scene (validated once), scene files, bundled scenes."""

from . import cases
from .bodies import Body
from .checks import SceneFileError
from .description import Scene
from .file import load_scene, scene_fingerprint, scene_from_dict, scene_to_dict
from .flows import Emitter, Sink
from .library import bundled_scenes, resolve_scene
from .motion import Motion
from .probes import Probe
from .settings import Camera, Output, Physics, SurfaceSettings
from .shapes import Box, MeshShape, Sphere, obstacles_mesh, shape_mesh

__all__ = [
    "Body",
    "Box",
    "Camera",
    "Emitter",
    "MeshShape",
    "Motion",
    "Sink",
    "Output",
    "Physics",
    "Probe",
    "Scene",
    "SceneFileError",
    "Sphere",
    "SurfaceSettings",
    "bundled_scenes",
    "cases",
    "load_scene",
    "scene_fingerprint",
    "scene_from_dict",
    "scene_to_dict",
    "obstacles_mesh",
    "resolve_scene",
    "shape_mesh",
]
