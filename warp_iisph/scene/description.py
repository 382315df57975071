"""Scene: a tank, fluid blocks, obstacles and settings, as plain Python data validated once.

A scene is a tank (a closed box, or a closed triangle mesh used as a container), fluid blocks
(boxes and spheres), obstacles (boxes, spheres, triangle meshes), free bodies the liquid moves
(:mod:`.bodies`), physics parameters and output
settings, all in SI units with y up. ``spacing`` is the particle diameter ``h``; the kernel support radius is
``2 h`` and each fluid particle weighs ``rho0 * h^3``. Validation raises ``ValueError`` naming
the field and its allowed range. No Warp here.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np

from .bodies import Body, check_bodies
from .checks import MAX_ITEMS, MAX_PARTICLES, Record, floats, folder_name, freeze, positive
from .flows import Emitter, Sink
from .probes import validate_probes
from .settings import Camera, Output, Physics, SurfaceSettings
from .shapes import Box, Fluid, MeshShape, Obstacle, Sphere, contains


def _corner(value, name: str) -> tuple:
    """A point given to a builder, as a tuple (validation checks its numbers later); a scalar or a
    string is refused here, naming the argument."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise TypeError(f"{name} = {value!r}: must be three numbers [x, y, z]")
    return tuple(value)


@dataclass
class Scene(Record):
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
    surface: SurfaceSettings = field(default_factory=SurfaceSettings)
    name: str = "scene"
    camera: Camera = field(default_factory=Camera)
    emitters: list = field(default_factory=list)
    sinks: list = field(default_factory=list)
    probes: list = field(default_factory=list)  # sensors (scene.probes.Probe), sampled as output.probe_interval says
    max_particles: Optional[int] = (
        None  # fluid particles at most (with emitters); None: what they emit over output.duration
    )
    bodies: list = field(default_factory=list)

    def add_fluid_box(self, lower, upper) -> "Scene":
        self.fluids.append(Box(_corner(lower, "lower"), _corner(upper, "upper")))
        return self

    def add_fluid_sphere(self, center, radius) -> "Scene":
        self.fluids.append(Sphere(_corner(center, "center"), radius))
        return self

    def add_obstacle(self, shape: Obstacle) -> "Scene":
        self.obstacles.append(shape)
        return self

    def add_body(self, shape, **keys) -> "Scene":
        """A free rigid body of ``shape`` (a Box, Sphere or closed MeshShape) with ``density`` or
        ``mass`` and the optional keys of :class:`~warp_iisph.scene.bodies.Body`, or a ``Body``
        (with no keys: its own are used)."""
        if isinstance(shape, Body) and keys:
            raise ValueError(f"add_body: a Body carries its own keys; {', '.join(sorted(keys))} given beside it")
        self.bodies.append(shape if isinstance(shape, Body) else Body(shape, **keys))
        return self

    def add_emitter(self, emitter: Emitter) -> "Scene":
        self.emitters.append(emitter)
        return self

    def add_sink(self, sink: Sink) -> "Scene":
        self.sinks.append(sink)
        return self

    def add_probe(self, probe) -> "Scene":
        self.probes.append(probe)
        return self

    def validate(self) -> "Scene":
        """Check every value (``ValueError`` naming the key and its range) and normalise it. A
        scene validated before and not changed since is trusted as it is."""
        if getattr(self, "_validated", None) == self._fingerprint():
            return self
        self.name = folder_name(self.name, "name")
        self.spacing = positive(self.spacing, "spacing", "metres, the particle diameter")
        if not isinstance(self.tank, (Box, MeshShape)):
            raise ValueError(f"tank = {self.tank!r}: must be a box or a mesh")
        self.tank.validate("tank")
        if getattr(self.tank, "motion", None) is not None:
            raise ValueError("tank.motion: the tank stays put; give an obstacle the motion")
        if isinstance(self.tank, MeshShape) and not self.tank.load().is_watertight:
            raise ValueError(f"tank.path = {self.tank.path!r}: a container mesh must be closed (watertight)")
        tlo, thi = self.tank.bounds
        if np.any((thi - tlo) < self.spacing):
            raise ValueError(f"tank: every side must be at least spacing = {self.spacing} m long")
        for key in ("fluids", "obstacles", "emitters", "sinks", "probes", "bodies"):
            items = getattr(self, key)
            if not isinstance(items, (list, tuple)) or len(items) > MAX_ITEMS:
                raise ValueError(f"{key}: must be a list of at most {MAX_ITEMS} items")
        if not self.fluids and not self.emitters:
            raise ValueError("fluids: the scene needs at least one fluid block or an emitter")
        for k, f in enumerate(self.fluids):
            name = f"fluids[{k}]"
            if not isinstance(f, (Box, Sphere)):
                raise ValueError(f"{name} = {f!r}: must be a Box or a Sphere")
            f.validate(name)
            if f.motion is not None:
                raise ValueError(f"{name}.motion: fluid blocks do not move; give an obstacle the motion")
            lo, hi = f.bounds
            eps = 1e-9 * max(1.0, float(np.max(np.abs(thi))))
            if np.any(lo < tlo - eps) or np.any(hi > thi + eps):
                raise ValueError(
                    f"{name}: fluid {floats(lo)}..{floats(hi)} must lie inside the tank {floats(tlo)}..{floats(thi)}"
                )
        for a in range(len(self.fluids)):
            for b in range(a + 1, len(self.fluids)):
                if _overlap(self.fluids[a], self.fluids[b]):
                    raise ValueError(f"fluids[{a}] and fluids[{b}] overlap: fluid blocks must be disjoint")
        for k, o in enumerate(self.obstacles):
            name = f"obstacles[{k}]"
            if not isinstance(o, (Box, Sphere, MeshShape)):
                raise ValueError(f"{name} = {o!r}: must be a box, a sphere or a mesh")
            o.validate(name)
            lo, hi = o.bounds
            if o.motion is not None and o.motion.pivot is None:
                o.motion.pivot = tuple(float(c) for c in 0.5 * (lo + hi))  # about its own centre
            if np.any(hi <= tlo) or np.any(lo >= thi):
                raise ValueError(f"{name}: lies entirely outside the tank {floats(tlo)}..{floats(thi)}")
            if isinstance(o, MeshShape) and not o.shell and not o.load().is_watertight:
                raise ValueError(
                    f"{name}.path = {o.path!r}: the mesh is not closed ({_unclosed(o.load())}), so "
                    f"its inside is undefined; close it, or set {name}.shell = true to use it as a thin wall"
                )
        _check_obstacle_names(self.obstacles)
        check_bodies(self.bodies, self.obstacles, self.tank, self.spacing)  # before the probes name them
        validate_probes(self.probes, self.tank, self.obstacles, self.bodies, self.spacing)
        for k, e in enumerate(self.emitters):
            name = f"emitters[{k}]"
            if not isinstance(e, Emitter):
                raise ValueError(f"{name} = {e!r}: must be an emitter")
            e.validate(name)
            self._check_nozzle(e, name, tlo, thi)
        for k, s in enumerate(self.sinks):
            name = f"sinks[{k}]"
            if not isinstance(s, Sink):
                raise ValueError(f"{name} = {s!r}: must be a box")
            s.validate(name)
            lo, hi = s.bounds
            if np.any(hi <= tlo) or np.any(lo >= thi):
                raise ValueError(f"{name}: lies entirely outside the tank {floats(tlo)}..{floats(thi)}")
            # particles are checked against sinks whenever the fastest could have crossed half the
            # thinnest: a sink much thinner than a spacing would need a check every few nanoseconds
            if float(np.min(hi - lo)) < 0.5 * self.spacing:
                raise ValueError(
                    f"{name}: {float(np.min(hi - lo)):g} m thin; every side must be at least half the "
                    f"spacing ({0.5 * self.spacing:g} m)"
                )
        if self.max_particles is not None:
            m = self.max_particles
            if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or not 1 <= m <= MAX_PARTICLES:
                raise ValueError(f"max_particles = {m!r}: must be a whole number in [1, {MAX_PARTICLES}]")
        for key, kind in (("physics", Physics), ("output", Output), ("surface", SurfaceSettings), ("camera", Camera)):
            if not isinstance(getattr(self, key), kind):
                raise ValueError(f"{key} = {getattr(self, key)!r:.60}: must be a {kind.__name__}")
        self.output.validate()  # before the counts: the emitters' particles follow output.duration
        self._check_particle_counts()
        self.physics.validate()
        gx, gy, gz = self.physics.gravity
        for k, p in enumerate(self.probes):  # a gauge's column stands along y (scene coordinates are y up)
            if p.kind == "level" and (gx != 0.0 or gz != 0.0 or gy > 0.0):
                raise ValueError(
                    f"probes[{k}]: a level gauge reads the water's height along y; physics.gravity = "
                    f"{list(self.physics.gravity)} must point along -y (or be zero) for it"
                )
        self.surface.validate()
        self.camera.validate()
        self._validated = self._fingerprint()
        return self

    def _check_nozzle(self, e: Emitter, name: str, tlo: np.ndarray, thi: np.ndarray) -> None:
        """An emitter's nozzle lies inside the tank, and not inside an obstacle (where it stands at
        the start)."""
        c, half = np.asarray(e.center), e.half_extent()
        eps = 1e-9 * max(1.0, float(np.max(np.abs(thi))))
        if np.any(c < tlo) or np.any(c > thi):
            raise ValueError(f"{name}.center = {list(e.center)}: must lie inside the tank {floats(tlo)}..{floats(thi)}")
        if np.any(c - half < tlo - eps) or np.any(c + half > thi + eps):
            raise ValueError(
                f"{name}: the nozzle {floats(c - half)}..{floats(c + half)} (centre and "
                f"{'radius' if e.shape == 'disc' else 'size'}) must lie inside the tank {floats(tlo)}..{floats(thi)}"
            )
        rim = e.rim()
        for k, o in enumerate(self.obstacles):
            if np.any(contains(o, rim)):
                raise ValueError(f"{name}: the nozzle at {list(e.center)} lies inside obstacles[{k}]; move it out")
        for k, b in enumerate(self.bodies):
            if np.any(contains(b.shape, rim)):
                raise ValueError(f"{name}: the nozzle at {list(e.center)} lies inside bodies[{k}]; move it out")

    def frozen_copy(self) -> "Scene":
        """A validated deep copy of this scene that refuses changes (``AttributeError``): what a
        ``Simulation`` keeps, so that later changes to this scene, or to its copy, never reach a
        run unvalidated. Meshes already read are shared, not copied. The copy is validated, not
        this scene: the defaults validation fills in (a moving obstacle's pivot, a force probe's
        point, from the shape's bounds) stay unset here, so a later change of the shape moves them."""
        memo = {}
        for shape in [self.tank, *self.obstacles, *(b.shape for b in self.bodies)]:
            loaded = getattr(shape, "_loaded", None)
            if loaded is not None:
                memo[id(loaded[1])] = loaded[1]
        scene = copy.deepcopy(self, memo)
        scene.validate()
        freeze(scene)
        return scene

    def particle_estimate(self) -> tuple[float, float]:
        """About how many fluid and boundary particles the scene makes (from volumes and areas,
        without sampling; ``inf`` when the spacing is absurdly small for the sizes)."""
        with np.errstate(over="ignore"):  # NumPy floats: overflow gives inf, which the check refuses
            return self._estimate(np.float64(self.spacing))

    def _estimate(self, h: np.float64) -> tuple[float, float]:
        fluid = 0.0
        for f in self.fluids:
            lo, hi = f.bounds
            fluid += float(np.prod((hi - lo) / h)) if isinstance(f, Box) else 4.0 / 3.0 * np.pi * (f.radius / h) ** 3
        fluid = max(fluid, self.capacity_estimate(h, fluid)) if self.emitters else fluid
        walls = 0.0
        for shape in [self.tank, *self.obstacles, *(b.shape for b in self.bodies)]:
            if isinstance(shape, Box):
                e = (shape.bounds[1] - shape.bounds[0]) / h
                walls += 2.0 * float(e[0] * e[1] + e[1] * e[2] + e[0] * e[2])
            elif isinstance(shape, Sphere):
                walls += 4.0 * np.pi * (shape.radius / h) ** 2
            else:
                walls += float(shape.load().area) / h / h
        return fluid, 2.0 * walls  # walls: two layers

    def capacity_estimate(self, h: float, initial: float, until: Optional[float] = None) -> float:
        """Fluid particles the scene holds at most: ``max_particles``, or ``initial`` plus what its
        emitters inject until ``until`` (default ``output.duration``)."""
        if self.max_particles is not None:
            return float(self.max_particles)
        until = self.output.duration if until is None else until
        return initial + sum(float(e.particles(float(h), until)) for e in self.emitters)

    def _check_particle_counts(self) -> None:
        fluid, boundary = self.particle_estimate()
        if not fluid + boundary <= MAX_PARTICLES:
            raise ValueError(
                f"spacing = {self.spacing:g}: the scene would need about "
                f"{fluid:.3g} fluid and {boundary:.3g} boundary particles "
                f"(at most {MAX_PARTICLES:,}); increase spacing"
            )

    def _fingerprint(self) -> str:
        """The scene's values and its mesh files' stamps: an edited mesh file is validated again."""
        shapes = [self.tank, *self.obstacles, *(getattr(b, "shape", None) for b in self.bodies)]
        return repr((dataclasses.asdict(self), [s.stamp() for s in shapes if isinstance(s, MeshShape)]))


def _check_obstacle_names(obstacles: list) -> None:
    """Obstacle names (optional) are non-empty strings, each used once."""
    seen = set()
    for k, o in enumerate(obstacles):
        name = getattr(o, "name", None)
        if name is None:
            continue
        if not isinstance(name, str) or not name.strip():
            raise ValueError(f"obstacles[{k}].name = {name!r}: must be a non-empty string")
        if name in seen:
            raise ValueError(f"obstacles[{k}].name = {name!r}: another obstacle has that name")
        seen.add(name)


def _unclosed(mesh) -> str:
    """Why a triangle mesh is not closed: its edges used by one face only, and those used by more
    than two (parts that touch along an edge or a face without being one solid)."""
    edges = np.sort(np.asarray(mesh.edges), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    said = f"{int(np.sum(counts == 1))} open edges"
    shared = int(np.sum(counts > 2))
    if shared:
        said += f", {shared} edges shared by more than two faces: parts that touch without being one solid"
    return said


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
