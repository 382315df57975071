"""Simulation: a scene on a device, stepped in time with statistics and divergence checks."""

from __future__ import annotations

import math
from collections import deque
from typing import Callable, Optional

import numpy as np

from ..engine.devices import init_warp
from ..scene import Scene
from ..setup import build_model
from ..sph.solvers import make_solver


class DivergenceError(RuntimeError):
    """The simulation blew up; ``step`` and ``time`` say when, ``reason`` why."""

    def __init__(self, step: int, time: float, reason: str):
        super().__init__(f"simulation diverged at step {step}, t = {time:.5f} s: {reason}")
        self.step = step
        self.time = time
        self.reason = reason


class Simulation:
    """Runs a :class:`~warp_iisph.scene.Scene` with IISPH or WCSPH on one Warp device.

    Example::

        from warp_iisph import Simulation, scenes
        sim = Simulation(scenes.martin_moyce(spacing=0.02), device="cpu")
        sim.advance(0.5)                  # simulate half a second (graph=True: replay a captured step)
        x = sim.positions                 # (N, 3) NumPy array, in particle-id order
        print(sim.stats[-1]["density_error"])
    """

    def __init__(self, scene: Scene, device: str = "cpu", graph: bool = False, history: Optional[int] = None):
        """``history``: how many step records ``stats`` keeps (``None``: every one; a long run that
        writes them to disk keeps the last few, so memory stays flat)."""
        init_warp()
        self.scene = scene.validate()
        self.physics = scene.physics
        self.model, self.state = build_model(self.scene, device)
        self.device = self.model.device
        self.solver = make_solver(self.model)
        # graph=True replays a recorded step (see warp_iisph.graph); the plain path launches
        # each kernel from Python, times every stage, and is the reference the graph is tested against
        self.stepper = None
        self._frames = None
        if graph:
            from .graph import CapturedStepper

            self.stepper = CapturedStepper(self)
        self.time = 0.0
        self.step_count = 0
        self.stats: list[dict] | deque = [] if history is None else deque(maxlen=max(1, int(history)))
        self.max_speed = 0.0
        height = float(self.model.domain_upper[1] - self.model.domain_lower[1])
        g = float(np.linalg.norm(self.physics.gravity))
        self.velocity_limit = self.physics.max_velocity or max(10.0, 10.0 * math.sqrt(2.0 * g * height))
        # Gravity-driven flows reach about sqrt(2 g y_top) (y_top: the liquid's top above the floor). The
        # CFL rule uses at least that speed, so the first steps, taken from rest, are not so long
        # that IISPH's linearised density prediction breaks down near the walls.
        x = self.state.x.numpy()
        fall = float(x[:, 1].max() - self.model.domain_lower[1]) if len(x) else 0.0
        self.velocity_scale = math.sqrt(2.0 * g * max(fall, 0.0))

    @property
    def n_particles(self) -> int:
        return self.model.n_fluid

    def next_dt(self) -> float:
        """Fixed dt, or the CFL rule ``cfl * h / (max(max|v|, sqrt(2 g y_top)) + c)`` clamped to
        [dt_min, dt_max] (``c`` is WCSPH's speed of sound, 0 for IISPH)."""
        ph = self.physics
        if ph.dt is not None:
            return ph.dt
        speed = max(self.max_speed, self.velocity_scale) + self.solver.signal_speed
        dt = ph.dt_max if speed <= 0.0 else ph.cfl * self.model.spacing / speed
        return float(min(max(dt, ph.dt_min), ph.dt_max))

    def step(self, dt: Optional[float] = None) -> dict:
        """Advance one time step; returns its statistics record (also appended to ``stats``)."""
        if dt is None:
            dt = self.next_dt()
        elif isinstance(dt, bool) or not (isinstance(dt, (int, float, np.floating, np.integer)) and 0.0 < float(dt) <= 1.0):
            raise ValueError(f"dt = {dt!r}: must be a number in (0, 1] seconds")
        dt = float(dt)
        stepper = self.stepper or self.solver
        record = stepper.step(self.model, self.state, dt)
        self.time += dt
        return self._accept(record)

    def _accept(self, record: dict) -> dict:
        """Number and keep a step's record; raise DivergenceError if the step blew up."""
        self.step_count += 1
        record = {"step": self.step_count, **record, "t": self.time}
        self.stats.append(record)
        self.max_speed = record["max_velocity"]
        reason = None
        if record["non_finite"]:
            reason = f"{record['non_finite']} particles have non-finite position or velocity"
        elif record["escaped"]:
            lo, hi = (", ".join(f"{c:.3g}" for c in b) for b in (self.model.domain_lower, self.model.domain_upper))
            reason = f"{record['escaped']} particles left the domain ({lo})..({hi})"
        elif record["max_velocity"] > self.velocity_limit:
            reason = f"max velocity {record['max_velocity']:.3g} m/s exceeds the limit {self.velocity_limit:.3g} m/s"
        if reason:
            raise DivergenceError(self.step_count, self.time, reason)
        return record

    def advance(self, duration: float, callback: Optional[Callable[[dict], None]] = None) -> None:
        """Simulate ``duration`` seconds; the last step is shortened to land on the end time.
        With ``graph=True`` the steps run as replays of a recorded loop (warp_iisph.graph)."""
        if isinstance(duration, bool) or not (isinstance(duration, (int, float, np.floating, np.integer)) and math.isfinite(duration)
                                               and duration >= 0.0):
            raise ValueError(f"duration = {duration!r}: must be a finite number of seconds >= 0")
        end = self.time + float(duration)
        if self.stepper is not None and self.time < end - 1e-9:
            if self.solver.steps == 0:  # a plain first step loads every module the graph uses
                self._advance_plain(self.time + min(self.next_dt(), end - self.time), callback)
            if self._frames is None:
                from .graph import FrameGraph

                self._frames = FrameGraph(self)
            for rec in self._frames.replay_until(end):
                self.time = rec.pop("t")
                record = self._accept(rec)  # raises on a divergence, which ends the replays
                if callback is not None:
                    callback(record)
            return
        self._advance_plain(end, callback)

    def _advance_plain(self, end: float, callback) -> None:
        while self.time < end - 1e-9:
            dt = min(self.next_dt(), end - self.time)
            if end - self.time - dt < 1e-9 + 0.05 * dt:
                dt = end - self.time
            record = self.step(dt)
            if callback is not None:
                callback(record)

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
        return self.model.boundary_x.numpy()
