"""Scene description: plain Python data with validation, no Warp.

A scene is a tank (a closed box, or a closed triangle mesh used as a container), fluid blocks
(boxes and spheres), obstacles (boxes, spheres, triangle meshes), physics parameters and output
settings, all in SI units with y up. ``spacing`` is the particle diameter ``h``; the kernel support radius is
``2 h`` and each fluid particle weighs ``rho0 * h^3``. Validation raises ``ValueError`` naming
the field and its allowed range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np

METHODS = ("iisph", "wcsph")


def _vec3(value, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r}: must be three numbers [x, y, z]") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} = {value!r}: must be three finite numbers [x, y, z]")
    return arr


def _positive(value, name: str, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r}: must be a number > 0 ({unit})") from None
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} = {value!r}: must be > 0 ({unit})")
    return v


def _in_range(value, name: str, lo: float, hi: float, unit: str, lo_open=False, hi_open=False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r}: must be a number") from None
    lo_ok = v > lo if lo_open else v >= lo
    hi_ok = v < hi if hi_open else v <= hi
    if not (math.isfinite(v) and lo_ok and hi_ok):
        lb = "(" if lo_open else "["
        rb = ")" if hi_open else "]"
        raise ValueError(f"{name} = {value!r}: must be in {lb}{lo:g}, {hi:g}{rb} ({unit})")
    return v


@dataclass
class Box:
    """Axis-aligned box from ``lower`` to ``upper`` (metres)."""

    lower: tuple
    upper: tuple

    def validate(self, name: str) -> None:
        lo = _vec3(self.lower, f"{name}.lower")
        hi = _vec3(self.upper, f"{name}.upper")
        if np.any(hi <= lo):
            raise ValueError(f"{name}: upper {tuple(hi)} must exceed lower {tuple(lo)} on every axis")
        self.lower, self.upper = tuple(lo), tuple(hi)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.lower, dtype=np.float64), np.asarray(self.upper, dtype=np.float64)


@dataclass
class Sphere:
    """Ball of ``radius`` around ``center`` (metres)."""

    center: tuple
    radius: float

    def validate(self, name: str) -> None:
        self.center = tuple(_vec3(self.center, f"{name}.center"))
        self.radius = _positive(self.radius, f"{name}.radius", "metres")

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(self.center, dtype=np.float64)
        return c - self.radius, c + self.radius


@dataclass
class MeshShape:
    """A triangle mesh file (OBJ, STL, PLY, ... anything trimesh reads), transformed by ``scale``
    (a number or three), then ``rotate`` (degrees about x, then y, then z), then ``translate``
    (metres). A relative ``path`` is relative to ``base_dir`` (the scene file's folder)."""

    path: str
    translate: tuple = (0.0, 0.0, 0.0)
    rotate: tuple = (0.0, 0.0, 0.0)
    scale: Union[float, tuple] = 1.0
    base_dir: str = "."

    def validate(self, name: str) -> None:
        if not isinstance(self.path, str) or not self.path:
            raise ValueError(f"{name}.path = {self.path!r}: must be a mesh file path")
        self.translate = tuple(_vec3(self.translate, f"{name}.translate"))
        self.rotate = tuple(_vec3(self.rotate, f"{name}.rotate"))
        if isinstance(self.scale, (list, tuple, np.ndarray)):
            sc = _vec3(self.scale, f"{name}.scale")
            if np.any(sc <= 0):
                raise ValueError(f"{name}.scale = {list(self.scale)}: every factor must be > 0")
            self.scale = tuple(sc)
        else:
            self.scale = _positive(self.scale, f"{name}.scale", "a factor, or three")
        self._mesh = None
        self.load(name)

    def load(self, name: str = "mesh"):
        """The transformed ``trimesh.Trimesh`` (read once)."""
        if getattr(self, "_mesh", None) is not None:
            return self._mesh
        import trimesh
        from pathlib import Path

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
        mesh.apply_transform(t @ r @ m)
        self._mesh = mesh
        return mesh

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = self.load().bounds
        return np.asarray(b[0], dtype=np.float64), np.asarray(b[1], dtype=np.float64)


def shape_mesh(shape) -> "object":
    """A shape as a ``trimesh.Trimesh``: boxes and spheres are built, meshes loaded."""
    import trimesh

    if isinstance(shape, MeshShape):
        return shape.load()
    if isinstance(shape, Box):
        lo, hi = shape.bounds
        return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=shape.radius)
    mesh.apply_translation(shape.center)
    return mesh



def obstacles_mesh(shapes) -> "object":
    """Obstacles as one ``trimesh.Trimesh`` (their meshes side by side, not merged), for the
    viewers; ``None`` for none."""
    import trimesh

    meshes = [shape_mesh(s) for s in shapes]
    return trimesh.util.concatenate(meshes) if meshes else None


Fluid = Union[Box, Sphere]
Obstacle = Union[Box, Sphere, MeshShape]


SMOOTHING = ("laplacian", "taubin", "none")


@dataclass
class Surface:
    """Surface reconstruction settings, in particle spacings ``h``: ``cell`` the distance-field
    grid's cell (h/2), ``r0`` the particle radius of Zhu & Bridson's distance (h/2), ``radius``
    their kernel radius R (2h); ``smoothing`` ``laplacian`` (the report's), ``taubin`` (keeps
    droplets' volume) or ``none``, over ``passes`` passes with factors ``lam`` and ``mu``."""

    cell: float = 0.5
    r0: float = 0.5
    radius: float = 2.0
    smoothing: str = "laplacian"
    passes: int = 3
    lam: float = 0.5
    mu: float = -0.53

    def validate(self) -> "Surface":
        self.cell = _in_range(self.cell, "surface.cell", 0.05, 4.0, "particle spacings")
        self.r0 = _in_range(self.r0, "surface.r0", 0.0, 4.0, "particle spacings")
        self.radius = _in_range(self.radius, "surface.radius", 0.5, 8.0, "particle spacings")
        if self.smoothing not in SMOOTHING:
            raise ValueError(f"surface.smoothing = {self.smoothing!r}: must be one of {', '.join(SMOOTHING)}")
        if isinstance(self.passes, bool) or not isinstance(self.passes, (int, np.integer)) or not 0 <= self.passes <= 100:
            raise ValueError(f"surface.passes = {self.passes!r}: must be an integer in [0, 100]")
        self.lam = _in_range(self.lam, "surface.lam", 0.0, 1.0, "smoothing factor", lo_open=True)
        self.mu = _in_range(self.mu, "surface.mu", -1.0, 0.0, "Taubin's inflation factor", hi_open=True)
        return self


@dataclass
class Output:
    """What a run writes: ``fps`` frames per simulated second over ``duration`` seconds,
    particle files (``particles``) and surface meshes (``mesh``)."""

    fps: float = 30.0
    duration: float = 2.0
    particles: bool = True
    mesh: bool = False

    def validate(self) -> None:
        self.fps = _in_range(self.fps, "output.fps", 0.0, 10_000.0, "frames per simulated second", lo_open=True)
        self.duration = _in_range(self.duration, "output.duration", 0.0, 1.0e6, "simulated seconds", lo_open=True)
        for key in ("particles", "mesh"):
            if not isinstance(getattr(self, key), bool):
                raise ValueError(f"output.{key} = {getattr(self, key)!r}: must be true or false")


@dataclass
class Camera:
    """Where `warp-iisph render` looks from: ``position`` and ``target`` (m) and a horizontal
    field of view ``fov`` (degrees). Without a position the camera frames the liquid itself."""

    position: Optional[tuple] = None
    target: Optional[tuple] = None
    fov: float = 40.0

    def validate(self) -> None:
        if self.position is not None:
            self.position = tuple(float(c) for c in _vec3(self.position, "camera.position"))
        if self.target is not None:
            self.target = tuple(float(c) for c in _vec3(self.target, "camera.target"))
        if self.target is not None and self.position is None:
            raise ValueError("camera.target: needs camera.position too")
        if self.position is not None and self.target is not None and np.allclose(self.position, self.target):
            raise ValueError("camera.target: must differ from camera.position")
        self.fov = _in_range(self.fov, "camera.fov", 1.0, 170.0, "degrees", lo_open=False)


@dataclass
class Physics:
    """Physical and numerical parameters.

    - ``method``: ``"iisph"`` or ``"wcsph"``.
    - ``rho0``: rest density (kg/m^3).
    - ``viscosity``: the report's viscosity coefficient mu (m^2/s); 0 switches viscosity off.
    - ``boundary_viscosity``: the same coefficient against the walls (wall friction, m^2/s);
      0 leaves the walls free-slip.
    - ``gravity``: (m/s^2).
    - ``eta``: IISPH's target average density error, a fraction (0.001 = 0.1 %).
    - ``max_iterations``: cap on IISPH's relaxed Jacobi iterations; ``min_iterations`` its floor.
    - ``omega``: Jacobi relaxation factor.
    - ``stiffness``: WCSPH's k in p = k((rho/rho0)^7 - 1) (Pa).
    - ``dt``: fixed time step (s); ``None`` selects the CFL rule
      ``dt = cfl * h / (max|v| + c)`` clamped to ``[dt_min, dt_max]`` (``c`` is WCSPH's speed of
      sound sqrt(7 k / rho0), 0 for IISPH).
    - ``max_velocity``: a speed (m/s) beyond which the run counts as diverged; ``None`` derives
      one from the domain height (10 x the free-fall speed over it, at least 10 m/s).
    """

    method: str = "iisph"
    rho0: float = 1000.0
    viscosity: float = 0.0
    boundary_viscosity: float = 0.0
    gravity: tuple = (0.0, -9.81, 0.0)
    eta: float = 1.0e-3
    max_iterations: int = 100
    min_iterations: int = 2
    omega: float = 0.5
    stiffness: float = 50_000.0
    dt: Optional[float] = None
    cfl: float = 0.5
    dt_min: float = 1.0e-5
    dt_max: float = 5.0e-3
    max_velocity: Optional[float] = None

    def validate(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"physics.method = {self.method!r}: must be one of {', '.join(METHODS)}")
        self.rho0 = _positive(self.rho0, "physics.rho0", "kg/m^3")
        self.viscosity = _in_range(self.viscosity, "physics.viscosity", 0.0, 1.0, "m^2/s")
        self.boundary_viscosity = _in_range(self.boundary_viscosity, "physics.boundary_viscosity", 0.0, 1.0, "m^2/s")
        self.gravity = tuple(_vec3(self.gravity, "physics.gravity"))
        self.eta = _in_range(self.eta, "physics.eta", 0.0, 0.5, "fraction of rho0, e.g. 0.001", lo_open=True)
        for key in ("max_iterations", "min_iterations"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 100_000:
                raise ValueError(f"physics.{key} = {v!r}: must be an integer in [1, 100000]")
        if self.min_iterations > self.max_iterations:
            raise ValueError(
                f"physics.min_iterations = {self.min_iterations}: must be <= physics.max_iterations = {self.max_iterations}"
            )
        self.omega = _in_range(self.omega, "physics.omega", 0.0, 1.0, "Jacobi relaxation", lo_open=True)
        self.stiffness = _positive(self.stiffness, "physics.stiffness", "Pa")
        if self.dt is not None:
            self.dt = _in_range(self.dt, "physics.dt", 0.0, 1.0, "seconds", lo_open=True)
        self.cfl = _in_range(self.cfl, "physics.cfl", 0.0, 2.0, "Courant number", lo_open=True)
        self.dt_min = _in_range(self.dt_min, "physics.dt_min", 0.0, 1.0, "seconds", lo_open=True)
        self.dt_max = _in_range(self.dt_max, "physics.dt_max", self.dt_min, 1.0, "seconds, >= dt_min")
        if self.max_velocity is not None:
            self.max_velocity = _positive(self.max_velocity, "physics.max_velocity", "m/s")

    @property
    def speed_of_sound(self) -> float:
        """Signal speed the time step must resolve: WCSPH's sqrt(7 k / rho0); 0 for IISPH."""
        return math.sqrt(7.0 * self.stiffness / self.rho0) if self.method == "wcsph" else 0.0


@dataclass
class Scene:
    """A tank holding fluid blocks, with optional obstacles.

    Example::

        scene = Scene(spacing=0.02, tank=Box((0, 0, 0), (1.0, 0.6, 0.2)))
        scene.add_fluid_box((0, 0, 0), (0.2, 0.4, 0.2))
        scene.physics.viscosity = 1e-4
    """

    spacing: float
    tank: Union[Box, MeshShape]
    fluids: list = field(default_factory=list)
    obstacles: list = field(default_factory=list)
    physics: Physics = field(default_factory=Physics)
    output: Output = field(default_factory=Output)
    surface: Surface = field(default_factory=Surface)
    name: str = "scene"
    camera: Camera = field(default_factory=Camera)

    def add_fluid_box(self, lower, upper) -> "Scene":
        self.fluids.append(Box(tuple(lower), tuple(upper)))
        return self

    def add_fluid_sphere(self, center, radius) -> "Scene":
        self.fluids.append(Sphere(tuple(center), radius))
        return self

    def add_obstacle(self, shape: Obstacle) -> "Scene":
        self.obstacles.append(shape)
        return self

    def validate(self) -> "Scene":
        self.spacing = _positive(self.spacing, "spacing", "metres, the particle diameter")
        if not isinstance(self.tank, (Box, MeshShape)):
            raise ValueError(f"tank = {self.tank!r}: must be a box or a mesh")
        self.tank.validate("tank")
        if isinstance(self.tank, MeshShape) and not self.tank.load().is_watertight:
            raise ValueError(f"tank.path = {self.tank.path!r}: a container mesh must be closed (watertight)")
        tlo, thi = self.tank.bounds
        if np.any((thi - tlo) < self.spacing):
            raise ValueError(f"tank: every side must be at least spacing = {self.spacing} m long")
        if not self.fluids:
            raise ValueError("fluids: the scene needs at least one fluid block")
        for k, f in enumerate(self.fluids):
            name = f"fluids[{k}]"
            if not isinstance(f, (Box, Sphere)):
                raise ValueError(f"{name} = {f!r}: must be a Box or a Sphere")
            f.validate(name)
            lo, hi = f.bounds
            eps = 1e-9 * max(1.0, float(np.max(np.abs(thi))))
            if np.any(lo < tlo - eps) or np.any(hi > thi + eps):
                raise ValueError(
                    f"{name}: fluid {tuple(lo)}..{tuple(hi)} must lie inside the tank {tuple(tlo)}..{tuple(thi)}"
                )
        for a in range(len(self.fluids)):
            for b in range(a + 1, len(self.fluids)):
                if _overlap(self.fluids[a], self.fluids[b]):
                    raise ValueError(f"fluids[{a}] and fluids[{b}] overlap: fluid blocks must be disjoint")
        for k, o in enumerate(self.obstacles):
            if not isinstance(o, (Box, Sphere, MeshShape)):
                raise ValueError(f"obstacles[{k}] = {o!r}: must be a box, a sphere or a mesh")
            o.validate(f"obstacles[{k}]")
        self.physics.validate()
        self.output.validate()
        self.surface.validate()
        self.camera.validate()
        return self


def _overlap(a: Fluid, b: Fluid) -> bool:
    """True when two fluid blocks share a volume (touching faces are fine)."""
    if isinstance(a, Sphere) and isinstance(b, Box):
        a, b = b, a
    if isinstance(a, Box) and isinstance(b, Box):
        alo, ahi = a.bounds
        blo, bhi = b.bounds
        return bool(np.all(np.minimum(ahi, bhi) - np.maximum(alo, blo) > 1e-12))
    if isinstance(a, Box) and isinstance(b, Sphere):
        lo, hi = a.bounds
        c = np.asarray(b.center)
        nearest = np.clip(c, lo, hi)
        return float(np.linalg.norm(nearest - c)) < b.radius - 1e-12
    ca, cb = np.asarray(a.center), np.asarray(b.center)
    return float(np.linalg.norm(ca - cb)) < a.radius + b.radius - 1e-12
