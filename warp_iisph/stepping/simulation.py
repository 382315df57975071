"""Simulation: a scene on a device, stepped in time with statistics and divergence checks."""

from __future__ import annotations

import math
from collections import deque
from typing import Callable, Optional

import numpy as np
import warp as wp

from ..engine.devices import checked_device, init_warp
from ..scene import Scene
from ..scene.bodies import body_names
from ..scene.checks import in_range
from ..scene.settings import MAX_DURATION, MIN_STEP
from ..setup import build_model
from ..sph.solvers import make_solver
from .flows import Flows
from .graph import LoopGraph
from .probing import ProbeSampler, ProbeSamples
from .state_check import check_state
from .time_loop import TimeLoop

# The derived velocity limit is at least this many times the fastest point of a body at its start
# and the fastest emitted stream where it lands (a body or a jet thrown into the liquid: its splash
# may outrun it).
START_SPEED_MARGIN = 3.0


MAX_RECORDS = 10**9  # the most records history or probe_history may keep (a deque's maxlen is a C long)


def _count(value, name: str) -> int | None:
    """A record count (``history``, ``probe_history``): ``None`` (all) or a whole number >= 1."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= MAX_RECORDS:
        raise ValueError(
            f"{name} = {value!r}: must be None (keep every record) or a whole number in [1, {MAX_RECORDS:g}]"
        )
    return int(value)


class DivergenceError(RuntimeError):
    """The simulation blew up; ``step`` and ``time`` say when, ``reason`` why."""

    def __init__(self, step: int, time: float, reason: str):
        super().__init__(f"simulation diverged at step {step}, t = {time:.5f} s: {reason}")
        self.step = step
        self.time = time
        self.reason = reason


class Simulation:
    """Runs a :class:`~warp_iisph.scene.Scene` with IISPH, DFSPH or WCSPH on one Warp device.

    Example::

        from warp_iisph import Simulation, scenes
        sim = Simulation(scenes.martin_moyce(spacing=0.02), device="cpu")
        sim.advance(0.5)                  # simulate half a second (graph=True: replay a captured step)
        x = sim.positions                 # (N, 3) NumPy array, in particle-id order
        print(sim.stats[-1]["density_error"])
    """

    def __init__(
        self,
        scene: Scene,
        device: str = "cpu",
        graph: bool = False,
        history: Optional[int] = None,
        until: Optional[float] = None,
        probe_history: Optional[int] = None,
    ):
        """``history``: how many step records ``stats`` keeps (``None``: every one; a long run that
        writes them to disk keeps the last few, so memory stays flat); ``probe_history`` the same
        for the probes' samples (``probes``). ``until``: how long it will run (s), for the room
        emitters need (default: the scene's ``output.duration``)."""
        if not isinstance(scene, Scene):
            raise TypeError(f"scene: a Scene (or load_scene(path) of a scene file), not {type(scene).__name__}")
        if not isinstance(graph, (bool, np.bool_)):
            raise TypeError(f"graph = {graph!r}: must be True or False")
        history, probe_history = (
            _count(n, name) for n, name in ((history, "history"), (probe_history, "probe_history"))
        )
        if until is not None:
            until = in_range(until, "until", 0.0, MAX_DURATION, "simulated seconds")
        init_warp()
        device = checked_device(str(device), "device")
        # its own validated copy, read-only: a change to the scene (or to sim.physics) after this
        # point would otherwise reach the run without validation
        self.scene = scene.frozen_copy()
        self.physics = self.scene.physics
        self.model, self.state = build_model(self.scene, device, until)
        self.device = self.model.device
        self.solver = make_solver(self.model)
        for name, array in getattr(
            self.solver, "carried", {}
        ).items():  # a solver's warm starts move with the particles
            self.state.carry(name, array)
        self.time = 0.0
        self.step_count = 0
        self._last = None  # the last step's dt and fastest speed, for the next step's events
        self.stats: list[dict] | deque = [] if history is None else deque(maxlen=history)
        # heights are taken against gravity, whichever way it points (y up when it has none)
        g_vector = np.asarray(self.physics.gravity, dtype=np.float64)
        g = float(np.linalg.norm(g_vector))
        up = -g_vector / g if g > 0.0 else np.array([0.0, 1.0, 0.0])
        lo, hi = (np.asarray(b, dtype=np.float64) for b in (self.model.domain_lower, self.model.domain_upper))
        height = float(np.abs(up) @ (hi - lo))
        floor = float(np.minimum(lo * up, hi * up).sum())  # the domain's lowest point along up
        # a body thrown in at speed: its fastest point counts in the first step's CFL rule (as it does
        # in every later one) and raises the derived limit, as the splash it makes may be faster
        body_top = 0.0
        if self.model.rigid is not None:
            top2 = wp.zeros(1, dtype=float, device=self.model.device)
            self.model.rigid.speeds(top2)
            body_top = math.sqrt(float(top2.numpy()[0]))
        # Gravity-driven flows reach about sqrt(2 g y_top) (y_top: the liquid's top above the floor). The
        # CFL rule uses at least that speed, so the first steps, taken from rest, are not so long
        # that IISPH's linearised density prediction breaks down near the walls.
        x = self.state.x.numpy()[: self.state.n].astype(np.float64)
        fall = float((x @ up).max()) - floor if len(x) else 0.0
        speed = math.sqrt(2.0 * g * max(fall, 0.0))
        jet = 0.0  # an emitted stream falls from its nozzle
        for e in self.scene.emitters:
            jet = max(jet, math.sqrt(e.speed**2 + 2.0 * g * max(float(np.asarray(e.center) @ up) - floor, 0.0)))
        speed = max(speed, jet)
        velocity_limit = self.physics.max_velocity or max(
            10.0, 10.0 * math.sqrt(2.0 * g * height), START_SPEED_MARGIN * max(body_top, jet)
        )
        self.flows = Flows(self.scene, self.state, self.device)
        self.flows.emit(self.time)  # the layers due at the start are there from the start
        self.loop = TimeLoop(self.model, self.state, self.solver, speed, velocity_limit)
        self.loop.max_speed2.fill_(body_top * body_top)
        body_loads = self.loop.bodies.loads if self.loop.bodies is not None else None  # the free bodies'
        self.loop.flows = self.flows if self.flows.emitters else None
        self.loop.probes = (
            ProbeSampler(self.scene, self.model, self.solver, self.loop.capacity, body_loads)
            if self.scene.probes
            else None
        )
        # the probes' samples, as NumPy arrays by column name (empty for a scene without probes)
        self.probes = ProbeSamples(self.loop.probes.columns if self.loop.probes else [], probe_history)
        # graph=True replays the recorded loop over steps (see .graph); the plain path launches the
        # same step body from Python, times every stage, and is the reference the graph is tested against
        self.graph = LoopGraph(self.loop) if graph else None

    def __reduce_ex__(self, protocol):
        raise TypeError(
            "a Simulation holds its state on a Warp device and cannot be pickled or copied; keep "
            "sim.checkpoint() and restore() it into a Simulation of the same scene"
        )

    @property
    def n_particles(self) -> int:
        """Fluid particles now (emitters add, sinks remove)."""
        return self.state.n

    def step(self, dt: Optional[float] = None) -> dict:
        """Advance one time step (``dt``: seconds, or ``None`` for the CFL rule); returns its
        statistics record (also appended to ``stats``). With ``physics.substeps`` (the default) a
        ``dt`` longer than the substep rule allows now is refused (``ValueError``); a step due to
        land on an emitter's or a sink's event is shortened to it."""
        if dt is not None and (
            isinstance(dt, bool)
            or not (isinstance(dt, (int, float, np.floating, np.integer)) and MIN_STEP <= float(dt) <= 1.0)
        ):
            raise ValueError(f"dt = {dt!r}: must be a number in [{MIN_STEP:g}, 1] seconds")
        if dt is not None and self.physics.substeps:
            limit = self._step_limit()
            if float(dt) > limit * (1.0 + 1.0e-9):
                raise ValueError(
                    f"dt = {dt!r}: longer than one step may be now ({limit:.3g} s, in which the fastest particle, or "
                    "the fall from the liquid's top, crosses a spacing); advance(dt) cuts it into steps, and "
                    "physics.substeps = false takes such a step as it is"
                )
        (record,) = self._steps(math.inf, None if dt is None else float(dt), 1)
        return record

    def _step_limit(self) -> float:
        """The longest step the substep rule lets a fixed dt take now (``step_length.choose_dt``):
        ``h / (max(max|v|, sqrt(2) sqrt(2 g y_top)) + c)``."""
        loop = self.loop
        fastest = math.sqrt(max(float(loop.max_speed2.numpy()[0]), 0.0))
        speed = max(fastest, math.sqrt(2.0) * loop.velocity_scale) + float(self.solver.signal_speed)
        return float(self.model.spacing) / speed if speed > 0.0 else 1.0

    def advance(self, duration: float, callback: Optional[Callable[[dict], None]] = None) -> None:
        """Simulate ``duration`` seconds; the last step is shortened to land on the end time.
        With ``graph=True`` the steps run as replays of the recorded loop (.graph)."""
        if isinstance(duration, bool) or not (
            isinstance(duration, (int, float, np.floating, np.integer)) and 0.0 <= duration <= MAX_DURATION
        ):
            raise ValueError(f"duration = {duration!r}: must be a number of seconds in [0, {MAX_DURATION:g}]")
        if callback is not None and not callable(callback):
            raise TypeError(f"callback = {callback!r}: must be a function of a step's record, or None")
        end = self.time + float(duration)
        while self.time < end - 1e-9:
            # a replayed graph's steps are taken together: all of them are accepted (the clock and
            # the records) before the callback sees any, so one that raises leaves the clock true
            batch, diverged = [], None
            try:
                for record in self._steps(end):
                    batch.append(record)
            except DivergenceError as e:
                diverged = e
            if callback is not None:
                for record in batch:
                    callback(record)
            if diverged is not None:
                raise diverged
        self.flows.drain()  # and at the end of every call: a run's frame

    def _steps(self, end: float, dt: Optional[float] = None, limit: Optional[int] = None):
        """The next steps towards ``end``: one plain step, or one replay of the graph (up to the
        log's capacity of steps). Yields each step's record; raises DivergenceError at the step
        that diverged (the loop on the device stopped there too)."""
        # Layers and sink checks due now, or within a quarter of the last step (landing on one that
        # close would cut a sliver of a step, whose pressure kicks the next step); steps land on
        # the next ones unless they fall that close before ``end`` (then they are taken there), so
        # the plain and graph paths act alike.
        last = self._last  # the last step's (dt, max_velocity): the simulation's own, not stats' (a caller's list)
        slack = 0.25 * last[0] if last else 0.0
        speed = max(last[1] if last else 0.0, self.loop.velocity_scale)
        self.flows.check_sinks(self.time + slack, self.time, speed)
        self.flows.emit(self.time + slack)
        event = self.flows.next_event()
        if event < end - slack:
            end = event

        def restart():
            self.loop.start(self.time, self.step_count, end, dt, limit)

        restart()
        if self.graph is None or self.step_count == 0:  # a plain first step loads every module the graph uses
            records = [self.loop.plain_step()]
        else:
            records = self.graph.replay(restart)
        if self.loop.probes:
            self.probes.add(self.loop.probes.rows(len(records)))
        for k, record in enumerate(records):
            yield self._accept(record, last=k == len(records) - 1)

    def _accept(self, record: dict, last: bool = True) -> dict:
        """Number and keep a step's record; raise DivergenceError if the step blew up. The free
        bodies' state is read once a batch (``last``: its last record; a replayed graph's steps
        end in one state)."""
        self.step_count += 1
        self.time = record["t"]
        self._last = (record["dt"], record["max_velocity"])
        record = {"step": self.step_count, **record}
        self.stats.append(record)
        record = dict(record)  # the caller's: a change to it never reaches stats
        reason = None
        if record["non_finite"]:
            reason = f"{record['non_finite']} particles have non-finite position or velocity"
        elif record["escaped"]:
            lo, hi = (", ".join(f"{c:.3g}" for c in b) for b in (self.model.domain_lower, self.model.domain_upper))
            reason = f"{record['escaped']} particles left the domain ({lo})..({hi})"
        elif last and (body := self._body_astray()) is not None:
            reason = body
        elif record["max_velocity"] > self.loop.velocity_limit:
            reason = (
                f"max velocity {record['max_velocity']:.3g} m/s exceeds the limit {self.loop.velocity_limit:.3g} m/s"
            )
        if reason:
            raise DivergenceError(self.step_count, self.time, reason)
        return record

    def _body_astray(self) -> str | None:
        """Why a free body ended the step where none can be (its state not finite, or its centre of
        mass outside the domain the particles must stay in), or ``None``."""
        rigid = self.model.rigid
        if rigid is None or not rigid.n:
            return None
        state = rigid.values()  # read every step on the plain path: no spin, no per-body Python when all is well
        lo, hi = np.asarray(self.model.domain_lower), np.asarray(self.model.domain_upper)
        finite = np.logical_and.reduce([np.isfinite(a).all(axis=1) for a in state.values()])
        inside = np.all((state["position"] >= lo) & (state["position"] <= hi), axis=1)
        if finite.all() and inside.all():
            return None
        for k, name in enumerate(body_names(self.scene.bodies)):
            if not finite[k]:
                return f"body {name} has a non-finite position, orientation or velocity"
            if not inside[k]:
                c = state["position"][k]
                return f"body {name} left the domain ({', '.join(f'{v:.3g}' for v in c)} m)"
        return None

    def checkpoint(self) -> dict:
        """Everything the next step depends on, as NumPy arrays: the particles in their memory
        order (with the solver's warm starts), the clock, the step count (the reorder schedule)
        the top speed (the CFL rule) and what is left
        of a fixed step being cut into substeps.
        A simulation restored from it continues bitwise as this one would."""
        s = self.state
        # copies: on the CPU .numpy() is a view of the live arrays
        out = {name: array.numpy()[: s.n].copy() for name, array in s.fields().items()}
        out.update({f"carried_{name}": array.numpy()[: s.n].copy() for name, array in s.carried.items()})
        out.update(
            max_speed2=self.loop.max_speed2.numpy().copy(),
            sub_left=self.loop.sub_left.numpy().copy(),
            sub_done=self.loop.sub_done.numpy().copy(),
            time=np.float64(self.time),
            step_count=np.int64(self.step_count),
            method=np.array(self.physics.method),
            next_id=np.int64(s.next_id),
            **self.flows.checkpoint(),
        )
        if self.model.rigid is not None:  # the free bodies' state, float64 as the device holds it
            out.update({f"bodies_{k}": v for k, v in self.model.rigid.host().items() if k != "spin"})
        return out

    def restore(self, checkpoint: dict) -> None:
        """Continue from :meth:`checkpoint`'s arrays (``ValueError`` when they are not of this
        scene or make no sense: :mod:`.state_check`, all of it checked before anything is taken,
        so a refused state leaves the simulation as it was). The step records and the probes'
        samples kept so far are of the timeline left behind: they are dropped."""
        if not isinstance(checkpoint, dict):
            raise TypeError(f"checkpoint: a dict of arrays (Simulation.checkpoint()), not {type(checkpoint).__name__}")
        s = self.state
        if not isinstance(checkpoint.get("x"), np.ndarray) or checkpoint["x"].ndim != 2:
            raise ValueError("checkpoint: has no x, the particles' positions as an (N, 3) array")
        n = len(checkpoint["x"])
        if n > s.capacity or (not self.scene.emitters and not self.scene.sinks and n != s.n):
            raise ValueError(f"checkpoint: holds {n} particles, the scene makes {s.n}; its geometry changed")
        domain = (self.model.domain_lower, self.model.domain_upper)
        try:
            time, steps, next_id = check_state(checkpoint, self.scene, domain, carried=list(s.carried))
        except ValueError as e:
            raise ValueError(f"checkpoint: {e}") from None
        if str(checkpoint["method"]) != self.physics.method:
            raise ValueError(
                f"checkpoint: was made by {checkpoint['method']}, the scene asks for {self.physics.method}"
            )
        for name, array in s.fields().items():
            array[:n].assign(checkpoint[name])
        for name, array in s.carried.items():
            array[:n].assign(checkpoint[f"carried_{name}"])
        rigid = self.model.rigid
        if rigid is not None:
            rigid.assign({k: checkpoint[f"bodies_{k}"] for k in rigid.fields()})
        s.count = n
        s.next_id = next_id
        self.flows.restore(checkpoint)
        self.loop.max_speed2.assign(checkpoint["max_speed2"])
        if "sub_left" in checkpoint:  # a fixed step being cut into substeps (older checkpoints: none)
            self.loop.sub_left.assign(checkpoint["sub_left"])
            self.loop.sub_done.assign(checkpoint["sub_done"])
        self.time, self.step_count = time, steps
        self.stats.clear()
        self.probes.clear()
        self._last = None

    # NumPy accessors, in original particle order.
    @property
    def positions(self) -> np.ndarray:
        return self.state.numpy_by_id("x")

    @property
    def velocities(self) -> np.ndarray:
        return self.state.numpy_by_id("v")

    @property
    def densities(self) -> np.ndarray:
        return self.state.numpy_by_id("rho")

    @property
    def pressures(self) -> np.ndarray:
        return self.state.numpy_by_id("p")

    @property
    def boundary_positions(self) -> np.ndarray:
        return self.model.boundary_x.numpy().copy()  # on the CPU numpy() is a view the next step moves

    @property
    def bodies(self) -> dict:
        """The free bodies now: ``position`` (centre of mass, m), ``orientation`` (unit quaternion
        x, y, z, w), ``velocity`` (m/s), ``spin`` (angular velocity, rad/s), ``momentum``
        (angular, kg m^2/s), ``acceleration``, ``angular_acceleration`` (m/s^2, rad/s^2, the
        last step's, contacts included), ``coupled``, ``coupled_angular`` (the last step's
        accelerations by the liquid and gravity alone, which the next step's added mass takes):
        arrays of one row per body (none without bodies)."""
        return self.model.rigid.host() if self.model.rigid is not None else {}
