"""Graph capture: time steps recorded once and replayed, with nothing read back inside a step.

- :class:`CapturedStepper` (``Simulation.step`` with ``graph=True``) replays one step: grid
  build, neighbour lists, density, advection, the IISPH Jacobi loop with its convergence test
  (``wp.capture_while``), integration and the divergence checks. ``dt`` lives in a device array.
- :class:`FrameGraph` (``Simulation.advance``) replays a loop over steps (``wp.capture_while``):
  each step picks its ``dt`` on the device, reorders by grid cell when due (``wp.capture_if``)
  and logs its statistics on the device; the host reads the log once per replay.

The neighbour storage cannot grow inside a graph: a replay that needed more is restored from the
copy the graph takes at its start, the storage grows, the graph is recorded again and replayed.
On CPU Warp records the launches and replays them in C++; on CUDA these are CUDA graphs with
conditional nodes (CUDA 12.4+).
"""

from __future__ import annotations

import time

import warp as wp

from .launch import recording


class CapturedStepper:
    """Replays one recorded step per :meth:`step`; the plain path is ``solver.step``."""

    def __init__(self, solver, model, state):
        self.solver = solver
        self.device = model.device
        self.graph = None
        self._generation = None
        self.captures = 0
        self.redone = 0
        self._backup = {name: wp.empty_like(getattr(state, name)) for name in ("x", "v", "p")}

    def _generations(self):
        s = self.solver.search
        return (s.fluid.generation, s.boundary.generation)

    def _capture(self, model, state) -> None:
        with recording(), wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
            for name, copy in self._backup.items():
                wp.copy(copy, getattr(state, name))
            self.solver.launch_step(model, state, sync=False)
        self.graph = capture.graph
        self._generation = self._generations()
        self.captures += 1

    def step(self, model, state, dt: float) -> dict:
        solver = self.solver
        if self.graph is None and solver.steps == 0:
            return solver.step(model, state, dt)  # loads every module the graph will use
        t0 = time.perf_counter()
        if solver.steps % solver.reorder_interval == 0:
            state.reorder(solver.search.cell_order(state.x))
        solver.dt.fill_(float(dt))
        if self.graph is None or self._generation != self._generations():
            self._capture(model, state)
        wp.capture_launch(self.graph)
        search = solver.search
        lists = [search.fluid] + ([search.boundary] if search.boundary_grid is not None else [])
        if any(b.overflowed() for b in lists):
            for name, copy in self._backup.items():
                wp.copy(getattr(state, name), copy)
            for b in lists:
                if b.total > b.capacity:
                    b.grow(b.total)
            self._capture(model, state)
            wp.capture_launch(self.graph)
            self.redone += 1
        solver.steps += 1
        if self.device.is_cuda:
            wp.synchronize_device(self.device)
        return solver.read_stats(model, dt, {"step": 1e3 * (time.perf_counter() - t0)})


# --- a whole frame: the loop over steps on the device ---------------------------------------------


@wp.kernel
def choose_dt(
    fixed_dt: wp.float64,
    cfl: wp.float64,
    h: wp.float64,
    velocity_scale: wp.float64,
    signal_speed: wp.float64,
    dt_min: wp.float64,
    dt_max: wp.float64,
    max_speed2: wp.array(dtype=float),
    time: wp.array(dtype=wp.float64),
    end: wp.array(dtype=wp.float64),
    dt64: wp.array(dtype=wp.float64),
    dt32: wp.array(dtype=float),
):
    """Simulation.next_dt and the landing rule of Simulation.advance, on the device."""
    dt = fixed_dt
    if fixed_dt <= wp.float64(0.0):
        speed = wp.max(wp.float64(wp.sqrt(max_speed2[0])), velocity_scale) + signal_speed
        dt = dt_max
        if speed > wp.float64(0.0):
            dt = cfl * h / speed
        dt = wp.min(wp.max(dt, dt_min), dt_max)
    left = end[0] - time[0]
    dt = wp.min(dt, left)
    if left - dt < wp.float64(1.0e-9) + wp.float64(0.05) * dt:
        dt = left
    dt64[0] = dt
    dt32[0] = float(dt)


@wp.kernel
def reorder_due(steps: wp.array(dtype=wp.int32), interval: int, due: wp.array(dtype=wp.int32)):
    due[0] = wp.where(steps[0] % interval == 0, 1, 0)


@wp.kernel
def record_step(
    n: int,
    capacity: int,
    velocity_limit: wp.float64,
    dt64: wp.array(dtype=wp.float64),
    compression_sum: wp.array(dtype=wp.float64),
    error_sum: wp.array(dtype=wp.float64),
    iterations: wp.array(dtype=wp.int32),
    max_speed2: wp.array(dtype=float),
    counts: wp.array(dtype=wp.int32),
    needed: wp.array(dtype=wp.int32),
    list_total_f: wp.array(dtype=wp.int32),
    list_total_b: wp.array(dtype=wp.int32),
    time: wp.array(dtype=wp.float64),
    end: wp.array(dtype=wp.float64),
    steps: wp.array(dtype=wp.int32),
    slot: wp.array(dtype=wp.int32),
    log: wp.array2d(dtype=wp.float64),
    keep_going: wp.array(dtype=wp.int32),
):
    """Append the step's statistics to the frame's log, advance the clock, and decide whether
    another step follows (not at the end time, not with a full log, not after a divergence)."""
    k = slot[0]
    t = time[0] + dt64[0]
    time[0] = t
    speed = wp.float64(wp.sqrt(max_speed2[0]))
    log[k, 0] = dt64[0]
    log[k, 1] = wp.float64(iterations[0])
    log[k, 2] = error_sum[0] / wp.float64(n)
    log[k, 3] = compression_sum[0] / wp.float64(n)
    log[k, 4] = speed
    log[k, 5] = wp.float64(counts[0])
    log[k, 6] = wp.float64(counts[1])
    log[k, 7] = t
    needed[0] = wp.max(needed[0], list_total_f[0])
    needed[1] = wp.max(needed[1], list_total_b[0])
    slot[0] = k + 1
    steps[0] = steps[0] + 1
    diverged = counts[0] > 0 or counts[1] > 0 or speed > velocity_limit
    keep_going[0] = wp.where(diverged or k + 1 >= capacity or t >= end[0] - wp.float64(1.0e-9), 0, 1)


LOG_FIELDS = ("dt", "iterations", "density_error", "compression", "max_velocity", "escaped", "non_finite", "t")


class FrameGraph:
    """Replays a recorded loop over steps until the simulation reaches an end time: one replay
    per up to ``log_capacity`` steps, with the statistics read back once per replay."""

    def __init__(self, sim, log_capacity: int = 256):
        self.sim = sim
        dev = sim.model.device
        self.device = dev
        self.capacity = int(log_capacity)
        self.graph = None
        self._generation = None
        self.captures = 0
        self.redone = 0
        self.replays = 0
        f64 = wp.float64
        self.time = wp.zeros(1, dtype=f64, device=dev)
        self.end = wp.zeros(1, dtype=f64, device=dev)
        self.dt64 = wp.zeros(1, dtype=f64, device=dev)
        self.steps = wp.zeros(1, dtype=wp.int32, device=dev)
        self.slot = wp.zeros(1, dtype=wp.int32, device=dev)
        self.keep_going = wp.zeros(1, dtype=wp.int32, device=dev)
        self.due = wp.zeros(1, dtype=wp.int32, device=dev)
        self.needed = wp.zeros(2, dtype=wp.int32, device=dev)
        self.log = wp.zeros((self.capacity, len(LOG_FIELDS)), dtype=f64, device=dev)
        self._no_iterations = wp.zeros(1, dtype=wp.int32, device=dev)
        self._zero_total = wp.zeros(1, dtype=wp.int32, device=dev)
        # what a replay changes and a redo must restore: the particles and the last step's top speed
        self._sources = lambda: [*(getattr(self.sim.state, k) for k in ("x", "v", "rho", "p", "id")), self.sim.solver._max_speed2]
        self._backup = [wp.empty_like(a) for a in self._sources()]
        wp.load_module(module="warp_iisph.graph", device=dev)

    def _generations(self):
        s = self.sim.solver.search
        return (s.fluid.generation, s.boundary.generation)

    def _step_body(self) -> None:
        sim = self.sim
        solver, model, state, ph = sim.solver, sim.model, sim.state, sim.physics
        dev = self.device
        f64 = wp.float64
        wp.launch(choose_dt, dim=1, device=dev, inputs=[
            f64(ph.dt if ph.dt is not None else -1.0), f64(ph.cfl), f64(model.spacing), f64(sim.velocity_scale),
            f64(solver.signal_speed), f64(ph.dt_min), f64(ph.dt_max), solver._max_speed2, self.time, self.end, self.dt64, solver.dt])
        wp.launch(reorder_due, dim=1, inputs=[self.steps, solver.reorder_interval, self.due], device=dev)
        wp.capture_if(self.due, lambda: state.reorder(solver.search.cell_order(state.x)))
        solver.launch_step(model, state, sync=False)
        search = solver.search
        iisph = hasattr(solver, "_iterations")
        wp.launch(record_step, dim=1, device=dev, inputs=[
            model.n_fluid, self.capacity, f64(sim.velocity_limit), self.dt64, solver._compression_sum,
            solver._error_sum if iisph else solver._compression_sum, solver._iterations if iisph else self._no_iterations,
            solver._max_speed2, solver._counts, self.needed, search.fluid.needed,
            search.boundary.needed if search.boundary_grid is not None else self._zero_total,
            self.time, self.end, self.steps, self.slot, self.log, self.keep_going])

    def _capture(self) -> None:
        with recording(), wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
            for copy, src in zip(self._backup, self._sources()):
                wp.copy(copy, src)
            self.slot.zero_()
            self.needed.zero_()
            self.keep_going.fill_(1)
            wp.capture_while(self.keep_going, self._step_body)
        self.graph = capture.graph
        self._generation = self._generations()
        self.captures += 1

    def _overflowing(self) -> list:
        needed = self.needed.numpy()
        search = self.sim.solver.search
        return [(b, int(k)) for b, k in ((search.fluid, needed[0]), (search.boundary, needed[1])) if k > b.capacity]

    def run_until(self, end: float) -> list[dict]:
        """Replay until the clock reaches ``end`` (or a divergence); returns the steps' records."""
        import numpy as np

        sim = self.sim
        records = []
        while sim.time < end - 1e-9:
            self.time.fill_(sim.time)
            self.end.fill_(end)
            self.steps.fill_(sim.solver.steps)
            if self.graph is None or self._generation != self._generations():
                self._capture()
            t0 = time.perf_counter()
            wp.capture_launch(self.graph)
            over = self._overflowing()
            if over:  # restore the replay's start, grow, record again, replay
                for copy, dst in zip(self._backup, self._sources()):
                    wp.copy(dst, copy)
                self.time.fill_(sim.time)
                self.steps.fill_(sim.solver.steps)
                for buffer, needed in over:
                    buffer.grow(needed)
                self._capture()
                wp.capture_launch(self.graph)
                self.redone += 1
            self.replays += 1
            k = int(self.slot.numpy()[0])
            log = self.log.numpy()[:k]
            wall_ms = 1e3 * (time.perf_counter() - t0)
            for row in log:
                rec = dict(zip(LOG_FIELDS, (float(v) for v in row)))
                for key in ("iterations", "escaped", "non_finite"):
                    rec[key] = int(rec[key])
                rec["ms"] = {"step": round(wall_ms / max(k, 1), 4)}
                records.append(rec)
            sim.solver.steps += k
            if k and not np.isfinite(log[-1, 7]):
                break
            sim.time = float(log[-1, 7]) if k else sim.time
            last = records[-1] if records else None
            if last and (last["escaped"] or last["non_finite"] or last["max_velocity"] > sim.velocity_limit):
                break
        return records
