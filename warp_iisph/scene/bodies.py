"""Free rigid bodies: shapes the liquid moves and that push back (their keys, validated once, and
their mass properties).

A body is a box, a sphere or a closed mesh, placed as an obstacle would be. Its mass is given as
a ``density`` (uniform) or a ``mass``; its centre of mass and inertia tensor (about that centre,
in the world's axes as the scene places the shape) come from the shape at uniform density unless
given: a ``center_of_mass`` alone moves the uniform body's inertia to that point (parallel axes),
as ballast would. It starts with ``velocity`` (m/s) and ``angular_velocity`` (rad/s, about its
centre of mass); ``fixed_axes`` holds translations (``x``, ``y``, ``z``) or rotations (``rx``,
``ry``, ``rz``, about world axes through the centre of mass) still. ``restitution`` and
``friction`` are its contact's (against the tank, obstacles and other bodies). ``release_time``
holds the whole body still where the scene places it until that time (s), as a hand or a clamp
would, while the liquid settles around it; from then on it is free, from rest: a free-decay
test's release, or a crate dropped once the water has calmed.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np

from .checks import MAX_COORDINATE, Record, floats, in_range, magnitude, position, shown, vec3
from .shapes import Box, MeshShape, Sphere, contains, enclosed, placement, shape_mesh

AXES = ("x", "y", "z", "rx", "ry", "rz")
NAME = re.compile(r"[A-Za-z0-9_]{1,64}")  # a body's name: bodies.csv's columns and force probes' ``body``
# Densities (kg/m^3) and masses (kg) a body may have: from expanded polystyrene to osmium, and
# a few grams to a small ship.
DENSITY_RANGE = (1.0, 1.0e5)
MASS_RANGE = (1.0e-6, 1.0e9)
# Principal moments of inertia (kg m^2) a given inertia may have: the mass range's bodies at sizes
# from a millimetre to the scene's extent (float64 state; 1e300 turned a body's spin into NaN).
INERTIA_RANGE = (1.0e-15, 1.0e15)
MAX_SPEED = 100.0  # m/s: the fastest a body may start
MAX_SPIN = 1000.0  # rad/s


@dataclass
class Body(Record):
    """A free rigid body: ``shape`` (a :class:`Box`, :class:`Sphere` or closed :class:`MeshShape`)
    with ``density`` (kg/m^3) or ``mass`` (kg), and the optional keys of the module's docstring.

    Example::

        scene.add_body(Box((0.4, 0.2, 0.1), (0.6, 0.3, 0.3)), density=500.0, fixed_axes=["x", "z"])
    """

    shape: Union[Box, Sphere, MeshShape]
    density: Optional[float] = None
    mass: Optional[float] = None
    center_of_mass: Optional[tuple] = None
    inertia: Optional[tuple] = None  # [Ixx, Iyy, Izz] or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (kg m^2)
    velocity: tuple = (0.0, 0.0, 0.0)
    angular_velocity: tuple = (0.0, 0.0, 0.0)
    fixed_axes: list = field(default_factory=list)
    restitution: float = 0.0
    friction: float = 0.5
    release_time: float = 0.0
    name: Optional[str] = None

    def validate(self, name: str) -> None:
        if not isinstance(self.shape, (Box, Sphere, MeshShape)):
            raise ValueError(f"{name}.shape = {self.shape!r}: must be a box, a sphere or a mesh")
        if getattr(self.shape, "motion", None) is not None:
            raise ValueError(f"{name}.motion: a body is moved by the liquid; give an obstacle the keyframes")
        self.shape.validate(name)
        if isinstance(self.shape, MeshShape):
            if self.shape.shell:
                raise ValueError(f"{name}.shell: a body must be closed; an open mesh has no volume to float")
            mesh = self.shape.load()
            if not mesh.is_watertight:
                raise ValueError(f"{name}.path = {self.shape.path!r}: a body's mesh must be closed (watertight)")
            if not mesh.volume > 0.0:
                raise ValueError(
                    f"{name}.path = {self.shape.path!r}: the mesh is inside out (its volume is {mesh.volume:.3g} m^3); "
                    "its faces must wind counter-clockwise seen from outside"
                )
        if (self.density is None) == (self.mass is None):
            raise ValueError(f"{name}: give exactly one of density (kg/m^3) and mass (kg)")
        if self.density is not None:
            self.density = in_range(self.density, f"{name}.density", *DENSITY_RANGE, "kg/m^3")
            volume = _uniform(self.shape)[0]
            mass = self.density * volume
            if not MASS_RANGE[0] <= mass <= MASS_RANGE[1]:
                raise ValueError(
                    f"{name}.density = {self.density:g}: gives the body a mass of {mass:.3g} kg, outside "
                    f"[{MASS_RANGE[0]:g}, {MASS_RANGE[1]:g}] kg (its volume is {volume:.3g} m^3)"
                )
        else:
            self.mass = in_range(self.mass, f"{name}.mass", *MASS_RANGE, "kg")
            volume = _uniform(self.shape)[0]
            density = self.mass / volume
            if not DENSITY_RANGE[0] <= density <= DENSITY_RANGE[1]:
                raise ValueError(
                    f"{name}.mass = {self.mass:g}: gives the body a mean density of {density:.3g} kg/m^3, outside "
                    f"[{DENSITY_RANGE[0]:g}, {DENSITY_RANGE[1]:g}] kg/m^3 (its volume is {volume:.3g} m^3)"
                )
        lo, hi = self.shape.bounds
        if self.center_of_mass is not None:
            c = position(self.center_of_mass, f"{name}.center_of_mass")
            if np.any(c < lo) or np.any(c > hi):
                raise ValueError(
                    f"{name}.center_of_mass = {list(floats(c))}: must lie within the body's bounds "
                    f"{floats(lo)}..{floats(hi)}"
                )
            self.center_of_mass = floats(c)
        if self.inertia is not None:
            self.inertia = _inertia(self.inertia, f"{name}.inertia")
            _plausible_inertia(self, f"{name}.inertia")
        self.velocity = floats(_bounded(self.velocity, f"{name}.velocity", MAX_SPEED, "m/s"))
        self.angular_velocity = floats(_bounded(self.angular_velocity, f"{name}.angular_velocity", MAX_SPIN, "rad/s"))
        axes = self.fixed_axes
        if not isinstance(axes, (list, tuple)) or any(a not in AXES for a in axes) or len(set(axes)) != len(axes):
            raise ValueError(f"{name}.fixed_axes = {axes!r}: must be a list of distinct names among {', '.join(AXES)}")
        self.fixed_axes = [a for a in AXES if a in axes]
        self.restitution = in_range(self.restitution, f"{name}.restitution", 0.0, 1.0, "kept share of the speed")
        self.friction = in_range(self.friction, f"{name}.friction", 0.0, 10.0, "Coulomb's coefficient")
        self.release_time = in_range(self.release_time, f"{name}.release_time", 0.0, 1.0e6, "s held still")
        if self.release_time > 0.0 and (any(self.velocity) or any(self.angular_velocity)):
            raise ValueError(
                f"{name}.release_time = {self.release_time:g}: a held body starts from rest; give it no "
                "velocity or angular_velocity"
            )
        if self.name is not None and (not isinstance(self.name, str) or not NAME.fullmatch(self.name)):
            raise ValueError(
                f"{name}.name = {self.name!r}: must be a plain name of 1-64 letters, digits or _ (ASCII), bodies.csv's"
            )

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.shape.bounds

    def mesh(self):
        """The body's surface as a ``trimesh.Trimesh``, where the scene places it."""
        return shape_mesh(self.shape)

    def mass_properties(self) -> tuple[float, np.ndarray, np.ndarray]:
        """``(mass kg, centre of mass m, inertia tensor kg m^2)``: the inertia about the centre of
        mass, in the world's axes as the scene places the body."""
        volume, centroid, unit = _uniform(self.shape)
        mass = self.mass if self.mass is not None else self.density * volume
        inertia = mass * unit
        com = centroid
        if self.center_of_mass is not None:  # the uniform body's inertia moved to the given centre
            com = np.asarray(self.center_of_mass, dtype=np.float64)
            d = com - centroid
            inertia = inertia + mass * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
        if self.inertia is not None:
            inertia = _tensor(self.inertia)
        return float(mass), com, inertia


def body_names(bodies: list) -> list[str]:
    """The bodies' names (``bodies.csv``'s, a force probe's ``body``): their own, else ``body0``,
    ``body1``, ... by their place in the scene."""
    return [b.name or f"body{k}" for k, b in enumerate(bodies)]


def _uniform(shape) -> tuple[float, np.ndarray, np.ndarray]:
    """Volume, centroid and inertia per unit mass about the centroid of a uniform ``shape``."""
    if isinstance(shape, Box):
        lo, hi = shape.bounds
        e = hi - lo
        return (
            float(np.prod(e)),
            0.5 * (lo + hi),
            np.diag([e[1] ** 2 + e[2] ** 2, e[0] ** 2 + e[2] ** 2, e[0] ** 2 + e[1] ** 2]) / 12.0,
        )
    if isinstance(shape, Sphere):
        r = shape.radius
        return 4.0 / 3.0 * np.pi * r**3, np.asarray(shape.center, dtype=np.float64), np.eye(3) * (0.4 * r * r)
    m = shape.load()
    volume = float(m.volume)
    inertia = np.asarray(m.moment_inertia, dtype=np.float64) / (m.density * volume)
    return volume, np.asarray(m.center_mass, dtype=np.float64), inertia


def _bounded(value, name: str, most: float, unit: str) -> np.ndarray:
    v = vec3(value, name)
    if magnitude(v) > most:
        raise ValueError(f"{name} = {list(value)}: must be at most {most:g} {unit} in magnitude")
    return v


def _inertia(value, name: str) -> tuple:
    """Three principal moments or six components, a symmetric positive-definite tensor whose
    moments meet the triangle inequality (a real body's)."""
    try:
        if isinstance(value, (str, bytes)) or any(isinstance(c, (bool, np.bool_, str)) for c in value):
            raise TypeError
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(
            f"{name} = {value!r}: must be [Ixx, Iyy, Izz] or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (kg m^2)"
        ) from None
    if arr.shape not in ((3,), (6,)) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} = {value!r}: must be [Ixx, Iyy, Izz] or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (kg m^2)")
    moments = np.linalg.eigvalsh(_tensor(arr))
    if moments[0] <= 0.0 or moments[0] + moments[1] < moments[2] * (1.0 - 1.0e-9):
        raise ValueError(
            f"{name} = {list(floats(arr))}: must be positive definite with principal moments meeting "
            "I1 + I2 >= I3 (a rigid body's)"
        )
    if moments[0] < INERTIA_RANGE[0] or moments[2] > INERTIA_RANGE[1]:
        raise ValueError(
            f"{name} = {list(floats(arr))}: principal moments must lie in [{INERTIA_RANGE[0]:g}, "
            f"{INERTIA_RANGE[1]:g}] kg m^2"
        )
    return floats(arr)


def _plausible_inertia(body: Body, name: str) -> None:
    """A given inertia that some mass distribution of the body's mass within its shape's bounds
    could have, not lighter than the shape at the least density a body may have: each principal
    moment at least that shape's (uniform, ``DENSITY_RANGE[0]``) in the same order, and at most
    the whole mass at the bounds' diagonal from the centre of mass. Below, the coupling's explicit
    step meets a body far lighter than the liquid it moves (a 1e-15 kg m^2 box diverged in one
    step); above, no body of that mass and size exists."""
    volume, _, unit = _uniform(body.shape)
    mass = body.mass if body.mass is not None else body.density * volume
    moments = np.linalg.eigvalsh(_tensor(body.inertia))
    least = DENSITY_RANGE[0] * volume * np.linalg.eigvalsh(unit)
    lo, hi = body.shape.bounds
    most = mass * float(np.sum((hi - lo) ** 2))
    if np.any(moments < least * (1.0 - 1.0e-9)) or moments[-1] > most:
        raise ValueError(
            f"{name} = {list(body.inertia)}: principal moments {shown(moments, 3)} kg m^2 must be at least "
            f"{shown(least, 3)} (the shape at a uniform {DENSITY_RANGE[0]:g} kg/m^3, the least density a body may "
            f"have) and at most {most:.3g} (its mass {mass:.3g} kg at its bounds' diagonal)"
        )


def thin_bodies(bodies: list, spacing: float) -> list[str]:
    """One sentence for each body thinner than two spacings: the liquid keeps out of it (thin
    plates are bodies users ask for, and the containment holds them), but its two layers of
    boundary particles meet inside it, so the liquid pushes on it as on a body about two spacings
    thick: its buoyancy and drag are the thicker body's (a 2 mm plate of 5,000 kg/m^3 at
    h = 0.02 m floated, the water's force on it 8.8 N against its weight of 3.9 N)."""
    out = []
    for k, b in enumerate(bodies):
        thin = thinnest(b.shape)
        if thin < 2.0 * spacing * (1.0 - 1.0e-6):
            out.append(
                f"bodies[{k}]: {thin:.3g} m thin, under two spacings ({2.0 * spacing:g} m): the liquid keeps out "
                "of it but pushes on it as on a body about two spacings thick, so its buoyancy and drag are "
                "that body's; where its load matters, make it thicker or the spacing finer"
            )
    return out


def bodies_in_liquid(bodies: list, fluids: list) -> list[str]:
    """One sentence for each body free from t = 0 whose box lies within a block of liquid's (under
    the liquid, not floating in its surface): the set-up leaves out the liquid's lattice sites its
    edges make denser than rest (the holes of docs/physics.md 6.2), and until the liquid fills them
    it hardly holds the body (a submerged box felt -4 N against its 30 N buoyancy, then a 169 N
    kick; docs/scenes.md, "Bodies"). A body floating at its draft keeps most of its bottom face's
    liquid and settles (the drafts' tests)."""
    out = []
    for k, b in enumerate(bodies):
        if b.release_time > 0.0:
            continue
        lo, hi = b.bounds
        for j, f in enumerate(fluids):
            f_lo, f_hi = f.bounds
            if np.all(lo >= f_lo - 1e-9) and np.all(hi <= f_hi + 1e-9):
                out.append(
                    f"bodies[{k}] starts under the liquid of fluids[{j}], free: the liquid beside its edges is left "
                    "out at the start, and until it fills those holes it hardly holds the body, which sinks into "
                    "them and is then kicked; hold it with a release_time of 0.1-0.3 s (docs/scenes.md, Bodies)"
                )
                break
    return out


def bodies_at_walls(
    bodies: list, fluids: list, tank, spacing: float, rho0: float, gravity=(0.0, -9.81, 0.0)
) -> list[str]:
    """One sentence for each body lighter than the liquid that starts in a block of liquid with its
    surface closer to a box tank's face than a spacing (a sphere's than half a spacing): no particle
    of liquid fits in the gap, so the liquid's pressure is missing over that part of its surface:
    still liquid never lifts it off the face below it, and presses it to a side face (docs/scenes.md,
    "Bodies": a box of 500 kg/m^3 stayed on the floor from gaps of 0 and h/2 and rose from h; a
    sphere of 900 stayed from 0, felt half its buoyancy, and rose from h/2). The face above it
    (where its buoyancy takes it anyway) and faces across a fixed axis are left out; a dry body that
    a wave reaches (the flood's crates) is not warned of: the flow lifts and tilts it."""
    if not isinstance(tank, Box):
        return []
    g = np.asarray(gravity, dtype=np.float64)
    t_lo, t_hi = tank.bounds
    out = []
    for k, b in enumerate(bodies):
        lo, hi = b.bounds
        if not any(np.all(lo < f.bounds[1]) and np.all(hi > f.bounds[0]) for f in fluids):
            continue  # dry
        volume = _uniform(b.shape)[0]
        if (b.mass if b.mass is not None else b.density * volume) >= rho0 * volume:
            continue
        reach = (0.5 if isinstance(b.shape, Sphere) else 1.0) * spacing
        near = []
        for axis in range(3):
            if "xyz"[axis] in b.fixed_axes:
                continue
            for side, sign, gap in (("lower", -1.0, lo[axis] - t_lo[axis]), ("upper", 1.0, t_hi[axis] - hi[axis])):
                if gap >= reach * (1.0 - 1.0e-6) or sign * g[axis] < 0.0:
                    continue  # clear of it, or the face its buoyancy takes it to
                below = sign * g[axis] > 0.0
                near.append((gap, f"the tank's {side} {'xyz'[axis]} face", below))
        if near:
            gap, face, below = min(near)
            held = "does not lift the body off that face" if below else "presses the body against that face"
            out.append(
                f"bodies[{k}] starts in the liquid, lighter than it, {max(gap, 0.0):.3g} m from {face}, under "
                f"{'half a spacing' if reach < spacing else 'a spacing'} ({reach:g} m): no liquid fits between, "
                f"so its pressure is missing there and the liquid {held}; start it at least that far from "
                "the walls (docs/scenes.md, Bodies)"
            )
    return out


def thinnest(shape) -> float:
    """The shape's least thickness (m): a box's shortest side, a sphere's diameter, a mesh's
    shortest side of the box of the same uniform inertia (its principal extents; a thin plate's
    thickness whichever way it is turned)."""
    if isinstance(shape, Box):
        lo, hi = shape.bounds
        return float(np.min(hi - lo))
    if isinstance(shape, Sphere):
        return 2.0 * float(shape.radius)
    moments = np.linalg.eigvalsh(_uniform(shape)[2])
    return float(np.sqrt(12.0 * max(0.5 * moments.sum() - moments[-1], 0.0)))


def _tensor(inertia) -> np.ndarray:
    a = np.asarray(inertia, dtype=np.float64)
    if a.shape == (3,):
        return np.diag(a)
    xx, yy, zz, xy, xz, yz = a
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def check_bodies(bodies: list, obstacles: list, tank, spacing: float) -> None:
    """Bodies lie inside the tank, span at least two spacings, and overlap no obstacle and no
    other body where the scene places them (``ValueError`` naming the first that does)."""
    tlo, thi = tank.bounds
    for k, b in enumerate(bodies):
        name = f"bodies[{k}]"
        if not isinstance(b, Body):
            raise ValueError(f"{name} = {b!r}: must be a Body")
        b.validate(name)
        lo, hi = b.bounds
        if np.any(lo < tlo) or np.any(hi > thi):
            raise ValueError(
                f"{name}: {floats(lo)}..{floats(hi)} must lie inside the tank {floats(tlo)}..{floats(thi)}"
            )
        if float(np.max(hi - lo)) < 2.0 * spacing:
            raise ValueError(
                f"{name}: smaller than two spacings ({2.0 * spacing:g} m) on every side; the liquid cannot see it"
            )
        if np.any(np.abs(lo) > MAX_COORDINATE) or np.any(np.abs(hi) > MAX_COORDINATE):
            raise ValueError(f"{name}: must lie within {MAX_COORDINATE:g} m of the origin")
    names = body_names(bodies)  # bodies.csv's columns and force probes' body: each its own
    for k, n in enumerate(names):
        if n in names[:k]:
            raise ValueError(
                f"bodies[{k}].name = {n!r}: another body has that name"
                + ("" if bodies[k].name else " (the default of an unnamed body: bodyK, K its place)")
            )
    if not isinstance(tank, Box):  # a container mesh: the body inside its walls, not only its box
        closed = enclosed(tank)
        for k, b in enumerate(bodies):
            if not np.all(contains(closed, _samples(b.shape))):
                raise ValueError(f"bodies[{k}]: must lie inside the tank's mesh where the scene places it")
    named = [(f"bodies[{k}]", b.shape) for k, b in enumerate(bodies)]
    named += [(f"obstacles[{k}]", o) for k, o in enumerate(obstacles)]
    pair = _first_overlap([s for _, s in named], len(bodies))
    if pair is not None:
        raise ValueError(
            f"{named[pair[0]][0]} and {named[pair[1]][0]} overlap where the scene places them at t = 0; move one"
        )


def _first_overlap(shapes: list, count: int) -> tuple[int, int] | None:
    """The first pair ``(i, j)``, ``i < j`` and ``i < count``, of ``shapes`` that overlap at t = 0
    (:func:`_overlap`), or None: each shape's sample points taken once, and only pairs whose
    points' boxes overlap tested (1,000 bodies were half a million pairs of Python)."""
    points = [_samples(s) for s in shapes]
    if not points:
        return None
    lo = np.array([p.min(axis=0) for p in points])
    hi = np.array([p.max(axis=0) for p in points])
    for i in range(count):
        j = np.arange(i + 1, len(shapes))
        near = np.all(np.minimum(hi[i], hi[j]) - np.maximum(lo[i], lo[j]) > 1e-9, axis=1)
        for k in j[near]:
            if _overlap(shapes[i], shapes[k], points[i], points[k]):
                return i, int(k)
    return None


# Points per axis of the grid that probes where two shapes' boxes overlap (crossing shapes have
# no vertex inside each other).
OVERLAP_GRID = 10


def _samples(s) -> np.ndarray:
    """Points of a shape where the scene places it at t = 0 (a moving obstacle's keyframes applied),
    pulled a millionth of its size towards its centre: a box's corners and centre, a sphere's or a
    mesh's vertices (at most about 200) and centroid."""
    if isinstance(s, Box):
        lo, hi = s.bounds
        points = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        centre = 0.5 * (lo + hi)
    else:
        m = shape_mesh(s)
        points, centre = np.asarray(m.vertices)[:: max(1, len(m.vertices) // 200)], np.asarray(m.centroid)
    points = np.vstack([centre + (1.0 - 1e-6) * (points - centre), centre])
    if getattr(s, "motion", None) is not None:
        m = placement(s, 0.0)
        points = points @ m[:3, :3].T + m[:3, 3]
    return points


def _overlap(a, b, pa: np.ndarray | None = None, pb: np.ndarray | None = None) -> bool:
    """Whether two shapes share a volume at t = 0: their boxes there overlap, and a sample point of
    one lies inside the other or a point of a grid over the boxes' common part lies inside both
    (two boxes that cross, neither's corner inside the other). ``pa``, ``pb``: their
    :func:`_samples`, where already taken."""
    pa = _samples(a) if pa is None else pa
    pb = _samples(b) if pb is None else pb
    if isinstance(a, Box) and isinstance(b, Box):  # axis-aligned: the sample points' boxes are theirs
        pa, pb = pa[:-1], pb[:-1]
    lo = np.maximum(pa.min(axis=0), pb.min(axis=0))
    hi = np.minimum(pa.max(axis=0), pb.max(axis=0))
    if not np.all(hi - lo > 1e-9):
        return False
    if np.any(contains(b, pa)) or np.any(contains(a, pb)):
        return True
    axes = [lo[d] + (np.arange(OVERLAP_GRID) + 0.5) * (hi[d] - lo[d]) / OVERLAP_GRID for d in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if isinstance(b, (Box, Sphere)) and not isinstance(a, (Box, Sphere)):  # the exact test first
        a, b = b, a
    inside = grid[contains(a, grid)]  # the mesh's winding numbers only where the other shape is
    return bool(len(inside)) and bool(np.any(contains(b, inside)))


def quaternion_matrix(q) -> np.ndarray:
    """The rotation of a unit quaternion ``(x, y, z, w)`` (Warp's order)."""
    x, y, z, w = (float(c) for c in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def bodies_mesh(bodies: list, positions=None, orientations=None):
    """The bodies as one ``trimesh.Trimesh`` (side by side, not merged), each with its centre of
    mass at ``positions[k]`` and turned by ``orientations[k]`` (unit quaternions x, y, z, w) from
    where the scene places it (default: as placed); ``None`` for none."""
    import trimesh

    meshes = []
    for k, b in enumerate(bodies):
        m = b.mesh().copy()
        if positions is not None:
            com = b.mass_properties()[1]
            R = quaternion_matrix(orientations[k])
            m.vertices = (np.asarray(m.vertices) - com) @ R.T + np.asarray(positions[k], np.float64)
        meshes.append(m)
    return trimesh.util.concatenate(meshes) if meshes else None
