"""Sampling a scene's probes inside the loop over steps: the schedule, the device reads and a log
of samples beside the time loop's step log, all preallocated and decided on the device, so the
sampling sits in a captured graph as the steps do.

A step ends with :meth:`ProbeSampler.sample`: whether a sample is due (every step, or the first
step ending at or after each multiple of ``output.probe_interval``), and if so every probe's
reading in the step's row of the log (row = the time loop's slot; its first column is the time,
or -1 where the step took no sample). The host reads the rows the loop filled
(:meth:`ProbeSampler.rows`) into :class:`ProbeSamples`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch
from ..scene.probes import FORCE_PARTS, body_index, obstacle_index, probe_columns, sampled_groups, sampled_order
from ..sph.probes import Reach, gauge_levels, gauge_support, occupancy, pressure_probes
from ..sph.wall_forces import WallForces

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

# a step ending this close (a fraction of the interval) before a multiple of it reaches it
SCHEDULE_SLACK = wp.constant(wp.float64(1.0e-9))


@wp.kernel
def sample_due(
    time: wp.array(dtype=wp.float64),
    dt: wp.array(dtype=wp.float64),
    interval: wp.float64,
    slot: wp.array(dtype=wp.int32),
    due: wp.array(dtype=wp.int32),
    log: wp.array2d(dtype=wp.float64),
):
    """Whether the step from ``time`` to ``time + dt`` samples: every step, or where it reaches
    a multiple of the interval it had not reached at its start (nothing to keep between steps,
    so a resumed run or a redone replay samples as the run that never stopped); the row's time."""
    t0 = time[0]
    t = t0 + dt[0]
    d = int(1)
    if interval > wp.float64(0.0):
        slack = wp.float64(SCHEDULE_SLACK)
        d = wp.where(wp.floor(t / interval + slack) > wp.floor(t0 / interval + slack), 1, 0)
    due[0] = d
    log[slot[0], 0] = wp.where(d != 0, t, wp.float64(-1.0))


@wp.kernel
def force_columns(
    totals: wp.array2d(dtype=wp.float64),
    slot_of_probe: wp.array(dtype=wp.int32),
    shift: wp.array(dtype=wp.vec3d),
    slot: wp.array(dtype=wp.int32),
    column: int,
    log: wp.array2d(dtype=wp.float64),
):
    """Force probe k's twelve columns: its obstacle's totals, the moments moved from the
    obstacle's reference point to the probe's (``shift`` = reference - point: M' = M + shift x F)."""
    k = wp.tid()
    s = slot_of_probe[k]
    row = slot[0]
    base = column + 12 * k
    d = shift[k]
    for part in range(2):
        f = wp.vec3d(totals[s, 3 * part], totals[s, 3 * part + 1], totals[s, 3 * part + 2])
        m = wp.vec3d(totals[s, 6 + 3 * part], totals[s, 7 + 3 * part], totals[s, 8 + 3 * part]) + wp.cross(d, f)
        for a in range(3):
            log[row, base + 3 * part + a] = f[a]
            log[row, base + 6 + 3 * part + a] = m[a]


class ProbeSampler:
    """The device side of a scene's probes on ``model`` (see the module); ``capacity`` rows, one
    per step of a loop (the time loop's log capacity). Columns: ``t`` then :attr:`columns`, the
    probes' own in scene order within each kind: pressure probes, level gauges, force probes on
    obstacles, then on bodies (``body_loads``: the free bodies' :class:`.wall_forces.WallForces`
    the step moved them with, summed before the probes read)."""

    def __init__(self, scene, model, solver, capacity: int, body_loads=None):
        self.model = model
        dev = model.device
        h, H = model.spacing, model.support_radius
        self.interval = float(scene.output.probe_interval)
        self.pressure, self.levels, self.forces, self.body_forces = sampled_groups(scene.probes)
        self.probes = sampled_order(scene.probes)  # probes.csv's order: those groups, one after another
        self.columns = [c for p in self.probes for c in probe_columns(p)]
        self.log = wp.zeros((int(capacity), 1 + len(self.columns)), dtype=wp.float64, device=dev)
        self.due = wp.zeros(1, dtype=wp.int32, device=dev)
        self.gravity = wp.vec3(*model.physics.gravity)
        # a sensor reads half a spacing into the liquid, where the first layer of particles sits
        moved = [np.add(p.position, 0.5 * h * np.asarray(p.normal)) for p in self.pressure]
        self.points = wp.array(np.array(moved, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=dev)
        top = float(model.domain_upper[1])
        self.dy = 0.5 * h
        self.samples = max(1, int(np.ceil(max(top - min((g.bottom for g in self.levels), default=top), 0.0) / self.dy)))
        self.gauges = wp.array(
            np.array([(g.position[0], g.bottom, g.position[1]) for g in self.levels], dtype=np.float32).reshape(-1, 3),
            dtype=wp.vec3,
            device=dev,
        )
        self.phi = wp.zeros(max(1, len(self.levels) * self.samples), dtype=wp.float64, device=dev)
        # each gauge point's share of the kernel's support on the liquid's side of the walls (0: solid)
        heights = (np.arange(self.samples) + 0.5) * self.dy
        share = [gauge_support(scene.tank, scene.obstacles, *g.position, g.bottom + heights, H) for g in self.levels]
        self.support = wp.array(np.concatenate(share) if share else np.ones(1), dtype=wp.float64, device=dev)
        index = {p.name: obstacle_index(p.obstacle, scene.obstacles, p.name) for p in self.forces}
        obstacles = list(dict.fromkeys(index.values()))  # each measured obstacle once
        refs = {}  # an obstacle's moments are summed about its first probe's point
        for p in self.forces:
            refs.setdefault(index[p.name], p.point)
        self.loads = None
        if self.forces:  # each measured obstacle's boundary particles a group of the wall-force sums
            owner = model.boundary_owner.numpy()[: model.n_boundary]
            group = np.full(len(owner), -1, dtype=np.int32)
            for g, k in enumerate(obstacles):
                group[owner == k] = g
            points = np.array([refs[k] for k in obstacles], dtype=np.float64).reshape(-1, 3)
            self.loads = WallForces(model, solver, group, wp.array(points, dtype=wp.vec3d, device=dev))
        self.slot_of_probe = wp.array(
            np.array([obstacles.index(index[p.name]) for p in self.forces], dtype=np.int32),
            dtype=wp.int32,
            device=dev,
        )
        self.shift = wp.array(
            np.array([np.subtract(refs[index[p.name]], p.point) for p in self.forces], dtype=np.float64).reshape(-1, 3),
            dtype=wp.vec3d,
            device=dev,
        )
        self.body_loads = body_loads
        self.body_of_probe = wp.array(
            np.array([body_index(p.body, scene.bodies, p.name) for p in self.body_forces], dtype=np.int32),
            dtype=wp.int32,
            device=dev,
        )
        self.no_shift = wp.zeros(max(1, len(self.body_forces)), dtype=wp.vec3d, device=dev)
        self.H, self.h = H, h
        self._around = None  # the Reach of the loop's dt and top speed, made once (see _reach)

    def __bool__(self) -> bool:
        return bool(self.probes)

    def sample(self, state, solver, time: wp.array, dt: wp.array, max_speed2: wp.array, slot: wp.array) -> None:
        """At a step's end, before the clock moves: the row ``slot`` of the log."""
        launch(
            sample_due,
            dim=1,
            inputs=[time, dt, wp.float64(self.interval), slot, self.due, self.log],
            device=self.model.device,
        )
        wp.capture_if(self.due, lambda: self.read(state, solver, dt, max_speed2, slot))

    def _reach(self, dt: wp.array, max_speed2: wp.array) -> Reach:
        """The probes' :class:`Reach` around the loop's ``dt`` and top speed (the same arrays every
        step: made on the first reading, again only if the arrays change)."""
        key = (id(dt), id(max_speed2))
        if self._around is None or self._around[0] != key:
            around = Reach()
            around.H, around.h, around.dt, around.max_speed2 = self.H, self.h, dt, max_speed2
            self._around = (key, around)
        return self._around[1]

    def read(self, state, solver, dt: wp.array, max_speed2: wp.array, slot: wp.array) -> None:
        """Every probe's reading into the log's row ``slot``."""
        model, dev = self.model, self.model.device
        grid = solver.search.grid.grid
        around = self._reach(dt, max_speed2)
        column = 1
        if self.pressure:
            launch(
                pressure_probes,
                dim=len(self.pressure),
                inputs=[
                    grid,
                    state.x,
                    state.p,
                    state.rho,
                    self.points,
                    self.gravity,
                    model.mass,
                    around,
                    slot,
                    column,
                    self.log,
                ],
                device=dev,
            )
            column += len(self.pressure)
        if self.levels:
            launch(
                occupancy,
                dim=(len(self.levels), self.samples),
                inputs=[
                    grid,
                    state.x,
                    self.gauges,
                    self.samples,
                    self.dy,
                    model.mass / model.physics.rho0,
                    around,
                    self.support,
                    self.phi,
                ],
                device=dev,
            )
            launch(
                gauge_levels,
                dim=len(self.levels),
                inputs=[self.phi, self.samples, self.dy, self.H, slot, column, self.log],
                device=dev,
            )
            column += len(self.levels)
        if self.forces:
            self.loads.compute(state)
            launch(
                force_columns,
                dim=len(self.forces),
                inputs=[self.loads.totals, self.slot_of_probe, self.shift, slot, column, self.log],
                device=dev,
            )
            column += 12 * len(self.forces)
        if self.body_forces:  # the loads the bodies' update summed this step, about their centres of mass
            launch(
                force_columns,
                dim=len(self.body_forces),
                inputs=[self.body_loads.totals, self.body_of_probe, self.no_shift, slot, column, self.log],
                device=dev,
            )

    def rows(self, k: int) -> np.ndarray:
        """The samples among the first ``k`` rows of the log: (samples, 1 + columns)."""
        rows = self.log.numpy()[:k]
        return rows[rows[:, 0] >= 0.0].copy()


class ProbeSamples:
    """A run's probe samples on the host: ``time`` (s) and one array per column (``names``,
    ``units``), by name: ``sim.probes["P1"]``; the last ``history`` samples (``None``: all).
    ``listen(fn)`` calls ``fn(rows)`` with every batch of new rows (time first) as they arrive, as
    a run's writer does."""

    def __init__(self, columns: list[tuple[str, str]], history: int | None = None):
        self.names = [n for n, _ in columns]
        self.units = [u for _, u in columns]
        self.history = history
        self._chunks: list[np.ndarray] = []
        self._listeners = []
        self._array = None

    def __len__(self) -> int:
        return int(sum(len(c) for c in self._chunks))

    def __bool__(self) -> bool:
        return bool(self.names)

    def add(self, rows: np.ndarray) -> None:
        if len(rows):
            self._chunks.append(rows)
            self._array = None
            if self.history is not None and len(self) > self.history:
                self._chunks = [self._all()[-max(1, int(self.history)) :].copy()]
                self._array = None
            for fn in self._listeners:
                fn(rows)

    def listen(self, fn) -> None:
        self._listeners.append(fn)

    def clear(self) -> None:
        """Forget every sample (a restored simulation's timeline starts anew)."""
        self._chunks, self._array = [], None

    def array(self) -> np.ndarray:
        """Every sample so far: (samples, 1 + columns), time first (a copy: writing into it
        changes nothing kept here)."""
        return self._all().copy()

    def _all(self) -> np.ndarray:
        """The samples kept, as one array (not to be handed out: callers get copies)."""
        if self._array is None:
            self._array = (
                np.concatenate(self._chunks) if self._chunks else np.zeros((0, 1 + len(self.names)), dtype=np.float64)
            )
            self._chunks = [self._array] if len(self._array) else []
        return self._array

    @property
    def time(self) -> np.ndarray:
        return self._all()[:, 0].copy()

    def __getitem__(self, name: str) -> np.ndarray:
        """A column's samples, or a force probe's twelve (``NAME``: samples x 12, in the columns'
        order ``NAME.Fp_x .. NAME.Mv_z``)."""
        if name in self.names:
            return self._all()[:, 1 + self.names.index(name)].copy()
        of_probe = self._probe_columns(name) if isinstance(name, str) else []
        if not of_probe:
            raise KeyError(f"{name!r}: no such probe or probe column ({', '.join(self.names)})")
        return self._all()[:, of_probe]  # fancy indexing: a copy

    def _probe_columns(self, name) -> list[int]:
        """The log's columns of a force probe ``name`` (its twelve), or none."""
        force = {f"{name}.{part}_{axis}" for part in FORCE_PARTS for axis in "xyz"}
        return [1 + k for k, n in enumerate(self.names) if n in force]

    def __contains__(self, name) -> bool:
        """Whether ``name`` is a column or a force probe's name (``sim.probes[name]`` then reads it)."""
        return isinstance(name, str) and (name in self.names or bool(self._probe_columns(name)))

    def keys(self) -> list[str]:
        """The columns' names, as probes.csv's header has them (without ``t``)."""
        return list(self.names)

    def __iter__(self):
        """The columns' names (as a table's columns; ``len`` counts the samples)."""
        return iter(self.keys())

    def as_dict(self) -> dict[str, np.ndarray]:
        """``{"t": times, name: values, ...}`` (copies)."""
        a = self.array()
        return {"t": a[:, 0], **{n: a[:, 1 + k] for k, n in enumerate(self.names)}}
