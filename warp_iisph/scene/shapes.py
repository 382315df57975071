"""Shapes a scene is made of: boxes, spheres and triangle meshes read from files (SI units)."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np

from .checks import MAX_COORDINATE, Record, box_corners, flag, floats, in_range, position, positive, vec3
from .motion import MAX_ANGLE, Motion


def _check_motion(shape, name: str) -> None:
    if shape.motion is None:
        return
    if isinstance(shape.motion, dict):
        unknown = sorted(set(shape.motion) - {"times", "translate", "rotate", "pivot", "interpolation"})
        if unknown:
            raise ValueError(
                f"{name}.motion.{unknown[0]}: unknown key; allowed: interpolation, pivot, rotate, times, translate"
            )
        if "times" not in shape.motion:
            raise ValueError(f"{name}.motion.times: required (the key times, seconds)")
        shape.motion = Motion(**shape.motion)
    if not isinstance(shape.motion, Motion):
        raise ValueError(f"{name}.motion = {shape.motion!r}: must be a table of keyframes")
    shape.motion.validate(f"{name}.motion")


# A length holds the whole layers of the spacing that fit in it; one that falls short of another
# layer by at most this fraction of a spacing gets it: a spacing typed to a few digits (0.016667
# for 1/60 in a 0.55 m column) keeps the length instead of losing a layer (3 % of it there).
LAYER_TOLERANCE = 0.01


def whole_layers(length: float, h: float) -> int:
    """How many layers of spacing ``h`` a block or a nozzle ``length`` long holds (see
    :data:`LAYER_TOLERANCE`)."""
    return int(math.floor(length / h + LAYER_TOLERANCE))


# obstacles[k].sampling of a box: boundary particles in the cells its faces cross, or in layers
# inside its faces (the default; see Box)
BOX_SAMPLING = ("cells", "faces")


@dataclass
class Box(Record):
    """Axis-aligned box from ``lower`` to ``upper`` (metres); an obstacle may move (``motion``),
    have a ``name`` (probes refer to it) and be sampled (``sampling``) as the tank's walls are,
    inside out (``"faces"``, the default: two staggered layers h/2 and h inside its faces, so that
    the liquid rests against the faces themselves; a box thinner than 3 spacings as a closed mesh
    is, its layers meeting at its middle where it is thinner than one), or as an open mesh shell
    is, one boundary particle per grid cell its faces cross (``"cells"``: the liquid then rests
    about h/2 beyond the faces, and a force probe on it reads a buoyancy 25 % high)."""

    lower: tuple
    upper: tuple
    motion: Optional[Motion] = None
    name: Optional[str] = None
    sampling: str = "faces"

    def validate(self, name: str) -> None:
        self.lower, self.upper = box_corners(self.lower, self.upper, name)
        if self.sampling not in BOX_SAMPLING:
            raise ValueError(f"{name}.sampling = {self.sampling!r}: must be one of {', '.join(BOX_SAMPLING)}")
        _check_motion(self, name)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.lower, dtype=np.float64), np.asarray(self.upper, dtype=np.float64)

    def too_thin_for_faces(self, h: float) -> bool:
        """Whether a side is shorter than the 3 spacings ``sampling = "faces"`` needs (two
        staggered layers inside each face, apart from the opposite face's)."""
        lo, hi = self.bounds
        return bool(np.any(hi - lo < 3.0 * h - 1e-9))


@dataclass
class Sphere(Record):
    """Ball of ``radius`` around ``center`` (metres); an obstacle may move (``motion``) and have a
    ``name``."""

    center: tuple
    radius: float
    motion: Optional[Motion] = None
    name: Optional[str] = None

    def validate(self, name: str) -> None:
        self.center = floats(position(self.center, f"{name}.center"))
        self.radius = in_range(self.radius, f"{name}.radius", 0.0, MAX_COORDINATE, "metres", lo_open=True)
        _check_motion(self, name)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(self.center, dtype=np.float64)
        return c - self.radius, c + self.radius


@dataclass
class MeshShape(Record):
    """A triangle mesh file (OBJ, STL, PLY, ... anything trimesh reads), transformed by ``scale``
    (a number or three), then ``rotate`` (degrees about x, then y, then z), then ``translate``
    (metres). A relative ``path`` is relative to ``base_dir`` (the scene file's folder). An obstacle
    mesh must be closed, unless ``shell`` says it is a thin wall on purpose (a cup, a tray): fluid
    is then kept one spacing from its surface, but may start inside what it encloses."""

    path: str
    translate: tuple = (0.0, 0.0, 0.0)
    rotate: tuple = (0.0, 0.0, 0.0)
    scale: Union[float, tuple] = 1.0
    base_dir: str = "."
    shell: bool = False
    motion: Optional[Motion] = None
    name: Optional[str] = None

    def validate(self, name: str) -> None:
        if not isinstance(self.path, str) or not self.path:
            raise ValueError(f"{name}.path = {self.path!r}: must be a mesh file path")
        self.translate = floats(position(self.translate, f"{name}.translate"))
        self.rotate = floats(vec3(self.rotate, f"{name}.rotate"))
        if max(abs(a) for a in self.rotate) > MAX_ANGLE:
            raise ValueError(f"{name}.rotate = {list(self.rotate)}: angles must stay within {MAX_ANGLE:g} degrees")
        if isinstance(self.scale, (list, tuple, np.ndarray)):
            sc = vec3(self.scale, f"{name}.scale")
            if np.any(sc <= 0):
                raise ValueError(f"{name}.scale = {list(self.scale)}: every factor must be > 0")
            self.scale = floats(sc)
        else:
            self.scale = positive(self.scale, f"{name}.scale", "a factor, or three")
        self.shell = flag(self.shell, f"{name}.shell")
        _check_motion(self, name)
        mesh = self.load(name)
        if not np.all(np.isfinite(mesh.bounds)) or float(np.max(np.abs(mesh.bounds))) > MAX_COORDINATE:
            raise ValueError(f"{name}.scale = {self.scale!r}: puts the mesh beyond {MAX_COORDINATE:g} m of the origin")

    def stamp(self) -> tuple | None:
        """The mesh file's modification time, size and inode, so that a file edited or replaced
        since it was read is read again; ``None`` where it cannot be read or the path is no string
        (:meth:`validate` names that)."""
        try:
            st = os.stat(Path(self.base_dir) / self.path)
        except (OSError, ValueError, TypeError):
            return None
        return (st.st_mtime_ns, st.st_size, st.st_ino)

    def load(self, name: str = "mesh"):
        """The transformed ``trimesh.Trimesh``, read once per file (as it is on disk) and transform."""
        key = (self.path, self.base_dir, self.translate, self.rotate, self.scale, self.stamp())
        if getattr(self, "_loaded", (None, None))[0] == key:
            return self._loaded[1]
        import trimesh

        path = Path(self.base_dir) / self.path
        if not path.is_file():
            raise ValueError(f"{name}.path = {self.path!r}: file not found ({path})")
        try:
            mesh = trimesh.load(str(path), force="mesh")
        except Exception as e:  # trimesh raises many kinds for a bad file
            raise ValueError(f"{name}.path = {self.path!r}: cannot read the mesh ({type(e).__name__}: {e})") from None
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise ValueError(f"{name}.path = {self.path!r}: holds no triangles")
        m = np.diag(np.append(np.broadcast_to(np.asarray(self.scale, dtype=float), (3,)), 1.0))
        r = trimesh.transformations.euler_matrix(*np.radians(self.rotate), axes="sxyz")
        t = trimesh.transformations.translation_matrix(self.translate)
        with np.errstate(all="ignore"):  # an absurd scale overflows: validate() refuses the bounds
            mesh.apply_transform(t @ r @ m)
        if not self.shell and np.all(np.abs(mesh.vertices) <= MAX_COORDINATE):  # else validate() refuses it
            mesh = solid_union(mesh)
        self._loaded = (key, mesh)
        return mesh

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = self.load().bounds
        return np.asarray(b[0], dtype=np.float64), np.asarray(b[1], dtype=np.float64)


def solid_union(mesh):
    """A closed mesh made of closed parts that overlap (primitives put together, as modellers and
    CAD exports often leave them) as the one surface of the solid they fill (manifold3d's union):
    inside the overlaps the parts' own faces are no surface, and counted twice the overlap made a
    body's volume, so its mass, too large and misled every nearest-face test near them. Anything
    else (one part, parts apart, an inner part wound inwards: a cavity) is returned as it is."""
    if not mesh.is_watertight or mesh.body_count < 2:
        return mesh
    import trimesh

    parts = mesh.split(only_watertight=True)
    if len(parts) < 2 or any(part.volume <= 0.0 for part in parts):
        return mesh
    lo, hi = np.array([part.bounds[0] for part in parts]), np.array([part.bounds[1] for part in parts])
    meet = np.all((lo[:, None] < hi[None]) & (lo[None] < hi[:, None]), axis=2)
    if not np.any(np.triu(meet, 1)):
        return mesh
    union = trimesh.boolean.union(parts, engine="manifold")
    return union if union.is_watertight and union.volume > 0.0 else mesh


def shape_mesh(shape) -> "object":
    """A shape as a ``trimesh.Trimesh``: boxes and spheres are built, meshes loaded."""
    import trimesh

    if isinstance(shape, MeshShape):
        return shape.load()
    if isinstance(shape, Box):
        lo, hi = shape.bounds
        return trimesh.creation.box(
            extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2)
        )
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=shape.radius)
    mesh.apply_translation(shape.center)
    return mesh


def placement(shape, time: float) -> np.ndarray:
    """The 4x4 rigid transform a moving shape's keyframes give at ``time`` (about its pivot, by
    default its box's centre)."""
    lo, hi = shape.bounds
    pivot = shape.motion.pivot if shape.motion.pivot is not None else 0.5 * (lo + hi)
    return shape.motion.matrix(time, np.asarray(pivot, dtype=np.float64))


def enclosed(shape):
    """The shape as a closed surface: an open ``shell`` mesh (a container) as the closed mesh it
    is made of, so that :func:`contains` finds what its walls hold; any other shape as it is."""
    return dataclasses.replace(shape, shell=False) if getattr(shape, "shell", False) else shape


def contains(shape, points, time: float = 0.0) -> np.ndarray:
    """Which ``points`` ((P, 3), metres) lie inside ``shape`` where its motion has it at ``time``:
    boxes and spheres exactly, closed meshes by their winding number (an open ``shell`` mesh
    encloses nothing). NumPy only, for checks while a scene is validated."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if shape.motion is not None:  # into the shape's own placement: the inverse of its rigid motion
        m = placement(shape, time)
        p = (p - m[:3, 3]) @ m[:3, :3]
    if isinstance(shape, Box):
        lo, hi = shape.bounds
        return np.all((p > lo) & (p < hi), axis=1)
    if isinstance(shape, Sphere):
        return np.linalg.norm(p - np.asarray(shape.center), axis=1) < shape.radius
    if shape.shell:
        return np.zeros(len(p), dtype=bool)
    mesh = shape.load()
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    inside = np.zeros(len(p), dtype=bool)
    for k, q in enumerate(p):  # the solid angle of every triangle seen from q (van Oosterom & Strackee)
        a, b, c = (tri[:, j] - q for j in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        div = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
        div += np.einsum("ij,ij->i", b, c) * la
        inside[k] = abs(np.arctan2(det, div).sum() / (2.0 * np.pi)) > 0.5
    return inside


def obstacles_mesh(shapes, time: float = 0.0) -> "object":
    """Obstacles as one ``trimesh.Trimesh`` (their meshes side by side, not merged), moving ones
    where their motion has them at ``time``, for the viewers; ``None`` for none."""
    import trimesh

    meshes = []
    for s in shapes:
        m = shape_mesh(s)
        if s.motion is not None:
            m = m.copy()
            m.apply_transform(s.motion.matrix(time, np.asarray(s.motion.pivot)))
        meshes.append(m)
    return trimesh.util.concatenate(meshes) if meshes else None


Fluid = Union[Box, Sphere]
Obstacle = Union[Box, Sphere, MeshShape]
