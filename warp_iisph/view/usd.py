"""The whole run as one USD stage (the ``usd`` extra: usd-core's ``pxr``): the liquid's surface as
one mesh whose points, faces and normals are sampled at every frame, the obstacles, the camera
and optionally the particles; metres, y up, one time code per frame at the run's frame rate, so
that Blender's USD import, Houdini and Omniverse open it with every frame in place."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import __version__
from ..engine.signals import deferred
from ..run.atomic import atomic_write
from ..run.folder import MESHES, PARTICLES, USD, RunError, RunFolder, frame_index, select_frames
from ..run.formats import read_mesh, read_particles
from ..run.lock import writing_into
from ..run.progress import frame_bar
from .camera import camera_up, framing_box, run_camera
from .materials import IOR, material_color
from .out_file import view_file

EXTRA = "pip install 'warp_iisph[usd]'  (usd-core)"
SUFFIXES = (".usdc", ".usda", ".usd")  # binary crate, text, either (crate)
ASPECT = 16 / 9  # the camera's film: 16:9, as the render's default 640x360
FILM_WIDTH = 0.36  # horizontal aperture in tenths of a metre (USD's camera unit): a 36 mm film back
STONE = (0.55, 0.5, 0.45)  # the obstacles' colour, as in the Blender script


class UsdUnavailable(RuntimeError):
    """usd-core (``pxr``) is not installed; the message says what to install."""


def require_pxr() -> None:
    """``UsdUnavailable`` unless usd-core's ``pxr`` imports."""
    try:
        with deferred():  # Ctrl-C while it loads: raised once it has
            import pxr.Usd  # noqa: F401
    except ImportError:
        raise UsdUnavailable(f"usd-core is not installed: {EXTRA}") from None


def _vec3f(a):
    """(N, 3) numbers as a ``Vt.Vec3fArray``."""
    from pxr import Vt

    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(np.asarray(a, dtype=np.float32).reshape(-1, 3)))


def _ints(a):
    """Integers as a ``Vt.IntArray``."""
    from pxr import Vt

    return Vt.IntArray.FromNumpy(np.ascontiguousarray(np.asarray(a, dtype=np.int32).ravel()))


def _extent(vertices: np.ndarray):
    lo, hi = (vertices.min(0), vertices.max(0)) if len(vertices) else (np.zeros(3), np.zeros(3))
    return _vec3f([lo, hi])


def write_mesh_sample(mesh, vertices, faces, normals=None, time=None) -> None:
    """A ``UsdGeom.Mesh``'s points, triangles, extent and normals at one time code (``None``: the
    default value, for what does not change). ``normals`` per vertex, or ``"flat"`` for one normal
    per face (written per face corner), or ``None`` for none."""
    from pxr import Usd, UsdGeom

    t = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    vertices = np.asarray(vertices, dtype=np.float32).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
    mesh.GetPointsAttr().Set(_vec3f(vertices), t)
    mesh.GetFaceVertexCountsAttr().Set(_ints(np.full(len(faces), 3)), t)
    mesh.GetFaceVertexIndicesAttr().Set(_ints(faces), t)
    mesh.GetExtentAttr().Set(_extent(vertices), t)
    if isinstance(normals, str) and normals == "flat":
        e1, e2 = vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]
        n = np.cross(e1, e2)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
        mesh.GetNormalsAttr().Set(_vec3f(np.repeat(n, 3, axis=0)), t)
    elif normals is not None:
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        mesh.GetNormalsAttr().Set(_vec3f(normals), t)


def _define_mesh(stage, path: str):
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # triangles as they are, not a subdivision cage
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)  # counter-clockwise seen from outside
    mesh.CreateDoubleSidedAttr(False)
    return mesh


def _preview_material(stage, path: str, color, opacity: float = 1.0, roughness: float = 0.5, ior: float = 1.5):
    """A ``UsdPreviewSurface`` material, which every USD application understands."""
    from pxr import Gf, Sdf, UsdShade

    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(opacity)
    shader.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(ior)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def _bind(prim, material, color) -> None:
    from pxr import UsdGeom, UsdShade

    UsdShade.MaterialBindingAPI.Apply(prim.GetPrim()).Bind(material)
    UsdGeom.Gprim(prim).CreateDisplayColorAttr([tuple(float(c) for c in color)])


def add_obstacles(
    stage, mesh, transforms: dict | None = None, meshes: dict | None = None, path: str = "/World/Obstacles"
):
    """The obstacles as one ``UsdGeom.Mesh`` (flat-shaded, stone-coloured): ``mesh`` (a
    ``trimesh.Trimesh``) where they do not move. Moving obstacles are sampled per frame, either as
    rigid motion, ``transforms`` ``{frame: 4x4 matrix}`` (column vectors: the translation is the
    last column) applied to ``mesh``, or as ``meshes`` ``{frame: trimesh.Trimesh}``."""
    from pxr import Gf, UsdGeom

    prim = _define_mesh(stage, path)
    write_mesh_sample(prim, mesh.vertices, mesh.faces, "flat")
    for frame, m in sorted((meshes or {}).items()):
        write_mesh_sample(prim, m.vertices, m.faces, "flat", frame)
    if transforms:
        op = UsdGeom.Xformable(prim).MakeMatrixXform()
        for frame, matrix in sorted(transforms.items()):
            matrix = np.asarray(matrix, dtype=float).reshape(4, 4)
            op.Set(Gf.Matrix4d(matrix.T.tolist()), frame)  # USD's matrices act on row vectors
    _bind(prim, _preview_material(stage, "/World/Looks/Obstacle", STONE, roughness=0.7), STONE)
    return prim


def add_camera(stage, eye, target, fov: float, aspect: float = ASPECT, path: str = "/World/Camera"):
    """A ``UsdGeom.Camera`` at ``eye`` looking at ``target`` (y up) with a horizontal field of view
    of ``fov`` degrees on a film of ``aspect`` = width / height."""
    from pxr import Gf, UsdGeom

    eye, target = np.asarray(eye, float), np.asarray(target, float)
    distance = float(np.linalg.norm(target - eye))
    up = camera_up(eye, target)
    camera = Gf.Camera()
    camera.SetPerspectiveFromAspectRatioAndFieldOfView(aspect, fov, Gf.Camera.FOVHorizontal, FILM_WIDTH)
    camera.transform = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(*up)).GetInverse()
    camera.clippingRange = Gf.Range1f(max(1e-3, 0.01 * distance), 100.0 * distance + 10.0)
    prim = UsdGeom.Camera.Define(stage, path)
    prim.SetFromCamera(camera)
    return prim


def _add_particles(stage, files: dict, frames: list[int], h: float, progress: bool, path: str = "/World/Particles"):
    from pxr import Sdf, UsdGeom

    points = UsdGeom.Points.Define(stage, path)
    primvars = UsdGeom.PrimvarsAPI(points)
    density = primvars.CreatePrimvar("density", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
    pressure = primvars.CreatePrimvar("pressure", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
    points.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
    bar = frame_bar(len(frames), progress, "usd particles")
    try:
        for frame in frames:
            p = read_particles(files[frame])
            n = len(p["x"])
            points.GetPointsAttr().Set(_vec3f(p["x"]), frame)
            points.GetWidthsAttr().Set(np.full(n, h, dtype=np.float32), frame)  # a particle's diameter is the spacing
            points.GetExtentAttr().Set(_extent(p["x"]), frame)
            if p["v"] is not None:
                points.GetVelocitiesAttr().Set(_vec3f(p["v"]), frame)  # m/s: motion blur in renderers that use it
            if p["id"] is not None:
                points.GetIdsAttr().Set(np.asarray(p["id"], dtype=np.int64), frame)
            for primvar, key in ((density, "density"), (pressure, "pressure")):
                if p[key] is not None:
                    primvar.Set(np.asarray(p[key], dtype=np.float32), frame)
            bar.update(1)
    finally:
        bar.close()
    return points


def export_usd(
    run_dir,
    out=None,
    frames: str | None = None,
    particles: bool = False,
    material: str = "water",
    progress: bool = True,
) -> dict:
    """Write the run as one USD stage (default ``RUN_DIR/run.usdc``); needs its meshes. Returns the
    path, the frames written and the prims."""
    require_pxr()
    run = RunFolder.existing(run_dir)
    record = run.record()
    files = select_frames(run.frames(MESHES), frames)
    color = material_color(material)
    out = view_file(run, out, USD, SUFFIXES, "stage")
    with writing_into(run.path, out):  # one writer in the run folder (a stage put elsewhere reads it as it is)
        return _write_stage(run, record, files, color, out, particles, progress)


def _write_stage(run: RunFolder, record: dict, files: list, color, out: Path, particles: bool, progress: bool) -> dict:
    from pxr import Usd, UsdGeom

    particle_files = {}
    numbers = [frame_index(f) for f in files]
    if particles:
        particle_files = {frame_index(f): f for f in run.frames(PARTICLES)}
        missing = [k for k in numbers if k not in particle_files]
        if missing:
            raise RunError(
                f"{run.path / PARTICLES}: no particle frame {missing[0]} for --particles "
                f"(frames {numbers[0]}..{numbers[-1]})"
            )
    fps = run.fps(record)
    h = run.spacing(record) or 0.0
    if particles and not h > 0:
        raise RunError(f"{run.record_path}: has no particle spacing, which --particles needs for the points' widths")

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    stage.SetStartTimeCode(numbers[0])
    stage.SetEndTimeCode(numbers[-1])
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    UsdGeom.Scope.Define(stage, "/World/Looks")
    stage.GetRootLayer().customLayerData = {
        "warp_iisph": {
            "version": __version__,
            "run_id": str(record.get("run_id") or ""),
            "meshes": json.dumps(run.provenance(MESHES)),
            "frames": f"{numbers[0]}:{numbers[-1] + 1}",
        }
    }

    liquid = _define_mesh(stage, "/World/Liquid")
    _bind(liquid, _preview_material(stage, "/World/Looks/Liquid", color, opacity=0.25, roughness=0.0, ior=IOR), color)
    bar = frame_bar(len(files), progress, "usd")
    try:
        for frame, path in zip(numbers, files):
            mesh = read_mesh(path)
            vertices = np.asarray(mesh.vertices).reshape(-1, 3)
            normals = np.asarray(mesh.vertex_normals).reshape(-1, 3) if len(vertices) else vertices
            write_mesh_sample(liquid, vertices, np.asarray(mesh.faces).reshape(-1, 3), normals, frame)
            bar.update(1)
    finally:
        bar.close()

    obstacles = run.obstacle_mesh()
    if obstacles is not None:
        moving = {k: run.obstacle_mesh(k) for k in numbers if run.obstacle_frame(k).is_file()}
        add_obstacles(stage, obstacles, meshes=moving)
    eye, target, fov = run_camera(record, framing_box(run, record, files, obstacles), ASPECT, run.record_path)
    add_camera(stage, eye, target, fov)
    if particles:
        _add_particles(stage, particle_files, numbers, h, progress)

    def write(tmp):
        if not stage.GetRootLayer().Export(str(tmp)):
            raise OSError(f"{out}: USD could not write the stage")

    atomic_write(out, write)
    prims = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Gprim) or p.IsA(UsdGeom.Camera)]
    return {
        "path": out,
        "frames": len(files),
        "first": numbers[0],
        "last": numbers[-1],
        "fps": fps,
        "prims": prims,
        "camera": {"position": eye.tolist(), "target": np.asarray(target).tolist(), "fov": fov},
    }
