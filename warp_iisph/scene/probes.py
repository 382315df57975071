"""Probes: the sensors a scene places (``[[probes]]``), as plain data validated once.

- ``kind = "pressure"``: the pressure a flush-mounted sensor at ``position`` on a wall reads; the
  wall's ``normal`` points into the liquid.
- ``kind = "level"``: the height of the water column above ``bottom`` at the gauge's horizontal
  ``position = [x, z]``.
- ``kind = "force"``: the force and moment the liquid exerts on the obstacle named ``obstacle``
  (its name, or its index in ``obstacles``), the moment about ``point`` (default: the centre of
  the obstacle's bounds), pressure and viscous parts apart; or on the free body named ``body``
  (its name, ``body0``, ``body1``, ... unnamed, or its index in ``bodies``), the moment about its
  centre of mass where the step started: the very load that moved it that step.

How each is measured is the device's business (:mod:`warp_iisph.sph.probes`); what a probe writes
is :func:`probe_columns`. No Warp here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from .bodies import body_names
from .checks import Record, floats, in_range, position, shown, unit
from .shapes import MeshShape, contains, enclosed

PROBE_KINDS = ("pressure", "level", "force")
# the keys each kind takes besides name and kind
KIND_KEYS = {
    "pressure": ("position", "normal"),
    "level": ("position", "bottom"),
    "force": ("obstacle", "body", "point"),
}
REQUIRED = {"pressure": ("position", "normal"), "level": ("position",), "force": ()}  # a force: obstacle or body
# a probe's name heads columns of probes.csv: letters, digits, _ - . only
NAME = re.compile(r"[A-Za-z0-9_.\-]{1,64}")
# probes.csv's first column, the samples' time: no probe may take its name
TIME_COLUMN = "t"
# a force probe's columns, after its name: the pressure and viscous parts of the force and moment
FORCE_PARTS = ("Fp", "Fv", "Mp", "Mv")


@dataclass
class Probe(Record):
    """One sensor (see the module). ``position``: a point (m) for a pressure probe, ``[x, z]``
    (m) for a level gauge; ``bottom``: the height (m) a gauge measures from (default: the tank's
    floor); ``obstacle`` or ``body``: a name or an index; ``point``: an obstacle's moment's centre (m)."""

    name: str
    kind: str
    position: Optional[tuple] = None
    normal: Optional[tuple] = None
    bottom: Optional[float] = None
    obstacle: Optional[Union[str, int]] = None
    body: Optional[Union[str, int]] = None
    point: Optional[tuple] = None

    def validate(self, where: str, tank_bounds, obstacles: list, bodies: tuple = ()) -> None:
        """Check every value against the scene's tank, obstacles and bodies, and normalise it."""
        if not isinstance(self.name, str) or not NAME.fullmatch(self.name):
            raise ValueError(
                f"{where}.name = {self.name!r}: must be 1-64 letters, digits, '_', '-' or '.' (it heads a column)"
            )
        if self.name == TIME_COLUMN:
            raise ValueError(f"{where}.name = {self.name!r}: the time's column has that name; give the probe another")
        if self.kind not in PROBE_KINDS:
            raise ValueError(f"{where}.kind = {self.kind!r}: must be one of {', '.join(PROBE_KINDS)}")
        allowed = KIND_KEYS[self.kind]
        for key in ("position", "normal", "bottom", "obstacle", "body", "point"):
            if getattr(self, key) is not None and key not in allowed:
                raise ValueError(
                    f"{where}.{key}: not a key of a {self.kind} probe; it takes {', '.join(('name', 'kind') + allowed)}"
                )
        for key in REQUIRED[self.kind]:
            if getattr(self, key) is None:
                raise ValueError(f"{where}.{key}: required for kind = {self.kind!r}")
        lo, hi = (np.asarray(b, dtype=np.float64) for b in tank_bounds)
        if self.kind == "pressure":
            p = position(self.position, f"{where}.position")
            if np.any(p < lo) or np.any(p > hi):
                raise ValueError(
                    f"{where}.position = {list(floats(p))}: must lie inside the tank {floats(lo)}..{floats(hi)}"
                )
            n = unit(self.normal, f"{where}.normal", "the wall's normal, into the liquid")
            self.position, self.normal = floats(p), floats(n)
        elif self.kind == "level":
            xz = _pair(self.position, f"{where}.position")
            if not (lo[0] <= xz[0] <= hi[0] and lo[2] <= xz[1] <= hi[2]):
                raise ValueError(
                    f"{where}.position = {list(xz)}: [x, z] must lie inside the tank's "
                    f"[{lo[0]:g}, {hi[0]:g}] x [{lo[2]:g}, {hi[2]:g}]"
                )
            self.position = xz
            self.bottom = in_range(
                lo[1] if self.bottom is None else self.bottom,
                f"{where}.bottom",
                lo[1],
                hi[1],
                "m, a height in the tank",
            )
            if self.bottom >= hi[1]:
                raise ValueError(f"{where}.bottom = {self.bottom!r}: must lie below the tank's top {hi[1]:g}")
        elif (self.obstacle is None) == (self.body is None):
            raise ValueError(f"{where}: a force probe takes exactly one of obstacle and body (a name or an index)")
        elif self.body is not None:
            if self.point is not None:
                raise ValueError(f"{where}.point: a body's moment is about its centre of mass, which moves with it")
            body_index(self.body, bodies, f"{where}.body")
            if not isinstance(self.body, str):  # a NumPy integer from the API, stored as the file's
                self.body = int(self.body)
        else:
            k = obstacle_index(self.obstacle, obstacles, f"{where}.obstacle")
            if not isinstance(self.obstacle, str):
                self.obstacle = int(self.obstacle)
            if self.point is None:
                o_lo, o_hi = obstacles[k].bounds
                self.point = floats(0.5 * (o_lo + o_hi))
            else:
                self.point = floats(position(self.point, f"{where}.point"))


def _pair(value, name: str) -> tuple:
    try:
        if isinstance(value, (str, bytes, bool)) or any(isinstance(c, (bool, np.bool_, str)) for c in value):
            raise TypeError
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} = {value!r}: must be two numbers [x, z]") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} = {value!r}: must be two finite numbers [x, z]")
    return floats(arr)


def obstacle_index(ref, obstacles: list, name: str) -> int:
    """The index in ``obstacles`` of the obstacle ``ref`` names (its ``name``, or its index)."""
    names = [getattr(o, "name", None) for o in obstacles]
    known = ", ".join(repr(n) for n in names if n) or "none has a name"
    return _index(ref, names, "obstacle", f"named: {known}", name)


def body_index(ref, bodies: list, name: str) -> int:
    """The index in ``bodies`` of the free body ``ref`` names (its name, ``bodyK`` unnamed, or its index)."""
    names = body_names(bodies)
    return _index(ref, names, "body", "the bodies: " + (", ".join(names) or "none"), name)


def _index(ref, names: list, kind: str, known: str, name: str) -> int:
    """The index of what ``ref`` names among ``names`` (a name, or an index), else one line saying why."""
    if isinstance(ref, str):
        if ref in names:
            return names.index(ref)
        raise ValueError(f"{name} = {ref!r}: no {kind} has that name ({known})")
    if isinstance(ref, (int, np.integer)) and not isinstance(ref, bool) and 0 <= ref < len(names):
        return int(ref)
    plural = "bodies" if kind == "body" else f"{kind}s"
    raise ValueError(
        f"{name} = {ref!r}: must be {'an' if kind[0] in 'aeiou' else 'a'} {kind}'s name or its index in "
        f"[0, {len(names) - 1}]"
        if names
        else f"{name} = {ref!r}: the scene has no {plural}"
    )


def validate_probes(probes: list, tank, obstacles: list, bodies: tuple = (), spacing: float | None = None) -> None:
    """Every probe checked (``ValueError`` naming ``probes[k].key``), names unique, and so are the
    columns they head (a probe named ``a.Fp_x`` beside a force probe ``a`` is refused). With the
    ``spacing``, a sensor and a gauge must also reach the liquid's side of the walls (:func:`_reach`)."""
    seen, columns = set(), {}
    for k, p in enumerate(probes):
        where = f"probes[{k}]"
        if not isinstance(p, Probe):
            raise ValueError(f"{where} = {p!r}: must be a probe")
        p.validate(where, tank.bounds, obstacles, bodies)
        if spacing is not None:
            _reach(p, where, tank, obstacles, spacing)
        if p.name in seen:
            raise ValueError(f"{where}.name = {p.name!r}: another probe has that name")
        seen.add(p.name)
        for column, _ in probe_columns(p):
            if column in columns:
                raise ValueError(
                    f"{where}.name = {p.name!r}: probe {columns[column]!r} already writes a column {column!r}"
                )
            columns[column] = p.name


def _reach(p: Probe, where: str, tank, obstacles: list, h: float) -> None:
    """A pressure sensor reads the liquid around the point half a spacing ``h`` along its normal
    from its face (:mod:`warp_iisph.sph.probes`): that point must lie inside the tank (a mesh
    tank's surface, not only its box) and outside every still obstacle, else the sensor is buried
    in a wall or faces it (its normal turned into it) and reads nothing, ever. A
    level gauge's column must cross the tank's inside somewhere (a mesh tank's box holds columns
    beside its walls). Where an obstacle moves, it may uncover the point later: not checked."""
    lo, hi = tank.bounds
    mesh_tank = isinstance(tank, MeshShape)
    tank = enclosed(tank)
    if p.kind == "pressure":
        q = np.asarray(p.position) + 0.5 * h * np.asarray(p.normal)
        if np.any(q < lo - 1e-9) or np.any(q > hi + 1e-9) or (mesh_tank and not contains(tank, q)[0]):
            raise ValueError(
                f"{where}.position = {list(p.position)}: half a spacing along its normal {list(p.normal)} it "
                f"reads at {shown(q)}, outside the tank; a sensor sits on a wall's face with its normal into "
                "the liquid"
            )
        for k, o in enumerate(obstacles):
            if o.motion is None and contains(o, q)[0]:
                raise ValueError(
                    f"{where}.position = {list(p.position)}: half a spacing along its normal {list(p.normal)} it "
                    f"reads at {shown(q)}, inside obstacles[{k}]; a sensor sits on a wall's face with its normal "
                    "into the liquid"
                )
    elif p.kind == "level" and mesh_tank:
        ys = np.linspace(lo[1], hi[1], int(min(max((hi[1] - lo[1]) / h, 8), 256)) + 2)[1:-1]
        column = np.column_stack([np.full_like(ys, p.position[0]), ys, np.full_like(ys, p.position[1])])
        if not np.any(contains(tank, column)):
            raise ValueError(
                f"{where}.position = {list(p.position)}: the column at [x, z] misses the tank's mesh (it lies "
                "inside the tank's box only); a gauge stands where the liquid can be"
            )


def sampled_groups(probes) -> tuple[list[Probe], list[Probe], list[Probe], list[Probe]]:
    """The probes by what is sampled for them: pressure sensors, level gauges, forces on
    obstacles, forces on bodies, each in scene order."""
    probes = list(probes)
    force = [p for p in probes if p.kind == "force"]
    return (
        [p for p in probes if p.kind == "pressure"],
        [p for p in probes if p.kind == "level"],
        [p for p in force if p.body is None],
        [p for p in force if p.body is not None],
    )


def sampled_order(probes) -> list[Probe]:
    """The probes in the order their samples are laid out (``sim.probes``, probes.csv's columns):
    :func:`sampled_groups`, one after another."""
    return [p for group in sampled_groups(probes) for p in group]


def probe_columns(probe: Probe) -> list[tuple[str, str]]:
    """The columns a probe writes, as (name, unit): one for a pressure probe (Pa) or a level
    gauge (m); for a force probe ``NAME.Fp_x`` .. ``NAME.Mv_z``: the pressure (p) and viscous (v)
    parts of the force (N) and of the moment about its point or its body's centre of mass (N m),
    component by component."""
    if probe.kind == "pressure":
        return [(probe.name, "Pa")]
    if probe.kind == "level":
        return [(probe.name, "m")]
    return [(f"{probe.name}.{part}_{axis}", "N" if part[0] == "F" else "N m") for part in FORCE_PARTS for axis in "xyz"]
