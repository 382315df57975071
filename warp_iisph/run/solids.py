"""A run's files of its solids: ``obstacles.obj`` (the obstacles and the free bodies where the scene
places them), and when some move ``obstacles/frame_NNNNN.obj`` (all of them where they are at each
frame, what the viewers show) and, with free bodies, ``bodies.csv``.

``bodies.csv`` holds one row per frame, the time first and then, per body, its centre of mass,
orientation (unit quaternion x, y, z, w), velocity and angular velocity, each column headed
``name.quantity [unit]``. Rows are appended as the frames come and flushed with them; a resumed
run keeps the rows up to its checkpoint's time (as ``stats.jsonl`` keeps the steps up to it) and
appends to them.
"""

from __future__ import annotations

import numpy as np

from ..scene import obstacles_mesh
from ..scene.bodies import bodies_mesh, body_names
from .atomic import flush_to_disk
from .folder import BODIES, OBSTACLES
from .formats import write_obj
from .time_series import TimeSeriesWriter, read_time_series

# per body: (column suffix, unit) in the order of a row
QUANTITIES = (
    *((f"position.{a}", "m") for a in "xyz"),
    *((f"orientation.{a}", "1") for a in "xyzw"),
    *((f"velocity.{a}", "m/s") for a in "xyz"),
    *((f"angular_velocity.{a}", "rad/s") for a in "xyz"),
)


def header(names: list[str]) -> str:
    return ",".join(["t [s]"] + [f"{n}.{q} [{u}]" for n in names for q, u in QUANTITIES])


def row(t: float, bodies: dict) -> str:
    """A frame's row from ``Simulation.bodies`` (position, orientation, velocity, spin per body)."""
    parts = [bodies[k] for k in ("position", "orientation", "velocity", "spin")]
    values = [t] + [float(v) for f in range(len(parts[0])) for p in parts for v in p[f]]
    return ",".join(f"{v:.12g}" for v in values)


class BodyWriter(TimeSeriesWriter):
    """Appends frame rows to ``bodies.csv`` (see :class:`.time_series.TimeSeriesWriter`), each
    flushed with its frame."""

    def __init__(self, path, names: list[str], keep_until: float | None = None):
        super().__init__(path, header(names), keep_until)

    def write(self, line: str) -> None:
        self._f.write(line + "\n")
        flush_to_disk(self._f)
        self.rows += 1


def read_bodies(path) -> tuple[list[str], np.ndarray]:
    """``bodies.csv`` as (names, rows): rows an (frames, 1 + 13 bodies) array, time first, then per
    body the :data:`QUANTITIES`; an incomplete last row (a run cut off while writing it) is left out."""
    cells, rows = read_time_series(path, "bodies.csv")
    return list(dict.fromkeys(c.rsplit(".", 2)[0] for c in cells)), rows


def solids_move(scene) -> bool:
    """Whether a run of ``scene`` writes its solids at every frame (``obstacles/frame_NNNNN.obj``):
    it has free bodies or moving obstacles."""
    return bool(scene.bodies) or any(o.motion is not None for o in scene.obstacles)


def solids_mesh(scene, time: float, bodies: dict | None = None):
    """The obstacles (moving ones where their keyframes have them at ``time``) and the free bodies
    (where ``bodies``, ``Simulation.bodies``, has them; as placed without it) as one mesh, or None."""
    import trimesh

    poses = (bodies["position"], bodies["orientation"]) if bodies else (None, None)
    meshes = [m for m in (obstacles_mesh(scene.obstacles, time), bodies_mesh(scene.bodies, *poses)) if m is not None]
    return trimesh.util.concatenate(meshes) if len(meshes) > 1 else (meshes[0] if meshes else None)


class SolidFiles:
    """What a run writes of its solids (module docstring): ``start`` at a new run's first frame
    (the record's keys), ``jobs`` at every frame (callables the frame's writer runs), ``close`` at
    the end. ``keep_until``: a resumed run's time (``bodies.csv`` keeps its rows up to it)."""

    def __init__(self, run, scene, fps: float, keep_until: float | None = None):
        self.run, self.scene, self.fps = run, scene, fps
        self.moving = solids_move(scene)
        self.writer = BodyWriter(run.bodies, body_names(scene.bodies), keep_until) if scene.bodies else None

    def start(self) -> dict:
        """``obstacles.obj`` at t = 0 (for a scene with solids); the run record's keys for them."""
        if not (self.scene.obstacles or self.scene.bodies):
            return {}
        mesh = solids_mesh(self.scene, 0.0)
        write_obj(self.run.obstacles, np.asarray(mesh.vertices), np.asarray(mesh.faces))
        return {"obstacles": OBSTACLES, **({"bodies": BODIES} if self.writer else {})}

    def jobs(self, k: int, sim) -> list:
        """Frame ``k``'s files (the bodies' state is copied now, written later)."""
        if not self.moving:
            return []
        state = sim.bodies
        solid, path = solids_mesh(self.scene, k / self.fps, state), self.run.obstacle_frame(k)
        jobs = [lambda: write_obj(path, np.asarray(solid.vertices), np.asarray(solid.faces))]
        if self.writer is not None:
            line = row(sim.time, state)
            jobs.append(lambda: self.writer.write(line))
        return jobs

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
