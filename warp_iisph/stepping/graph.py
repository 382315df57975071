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

from ..engine.launch import recording


class RecordedGraph:
    """A graph over the solver's launches, recorded on first use and again whenever the
    neighbour storage has moved. A replay whose neighbour lists needed more storage than there
    is gets undone from the copy the graph takes at its start; the storage grows, and the graph
    is recorded and replayed again. Subclasses give the recorded body and what the lists needed."""

    def __init__(self, sim):
        self.sim = sim
        self.device = sim.model.device
        self.graph = None
        self._generation = None
        self.captures = 0
        self.redone = 0
        self._backup = [wp.empty_like(a) for a in self._sources()]

    def _sources(self) -> list:
        """What a replay changes and a redo restores: the particles and the last step's top speed."""
        state = self.sim.state
        return [state.x, state.v, state.rho, state.p, state.id, self.sim.solver._max_speed2]

    def _generations(self) -> tuple:
        search = self.sim.solver.search
        return (search.fluid.generation, search.boundary.generation)

    def _body(self) -> None:
        raise NotImplementedError

    def _needed(self) -> tuple[int, int]:
        """Entries the fluid and boundary lists needed during the last replay."""
        raise NotImplementedError

    def _rewind(self) -> None:
        """Reset the device state a redo starts from, besides the particles."""

    def _record(self) -> None:
        with recording(), wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
            for copy, src in zip(self._backup, self._sources()):
                wp.copy(copy, src)
            self._body()
        self.graph = capture.graph
        self._generation = self._generations()
        self.captures += 1

    def _launch(self) -> None:
        if self.graph is None or self._generation != self._generations():
            self._record()
        wp.capture_launch(self.graph)
        search = self.sim.solver.search
        over = [(b, k) for b, k in zip((search.fluid, search.boundary), self._needed()) if k > b.capacity]
        if over:
            for copy, dst in zip(self._backup, self._sources()):
                wp.copy(dst, copy)
            self._rewind()
            for buffer, needed in over:
                buffer.grow(needed)
            self._record()
            wp.capture_launch(self.graph)
            self.redone += 1


class CapturedStepper(RecordedGraph):
    """Replays one recorded step per :meth:`step`; the plain path is ``solver.step``."""

    def _body(self) -> None:
        self.sim.solver.launch_step(self.sim.model, self.sim.state, sync=False)

    def _needed(self) -> tuple[int, int]:
        search = self.sim.solver.search
        return int(search.fluid.needed.numpy()[0]), int(search.boundary.needed.numpy()[0])

    def step(self, model, state, dt: float) -> dict:
        solver = self.sim.solver
        if self.graph is None and solver.steps == 0:
            return solver.step(model, state, dt)  # loads every module the graph will use
        t0 = time.perf_counter()
        if solver.steps % solver.reorder_interval == 0:
            state.reorder(solver.search.cell_order(state.x))
        solver.dt.fill_(float(dt))
        self._launch()
        solver.steps += 1
        if self.device.is_cuda:
            wp.synchronize_device(self.device)
        return solver.read_stats(model, dt, {"step": round(1e3 * (time.perf_counter() - t0), 4)})


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


class FrameGraph(RecordedGraph):
    """Replays a recorded loop over steps until the simulation reaches an end time: one replay
    per up to ``log_capacity`` steps, with the statistics read back once per replay."""

    def __init__(self, sim, log_capacity: int = 256):
        dev = sim.model.device
        self.capacity = int(log_capacity)
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
        self._zero_total = wp.zeros(1, dtype=wp.int32, device=dev)
        super().__init__(sim)
        wp.load_module(module=__name__, device=dev)

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
        wp.launch(record_step, dim=1, device=dev, inputs=[
            model.n_fluid, self.capacity, f64(sim.velocity_limit), self.dt64, solver._compression_sum, *solver.solver_stats(),
            solver._max_speed2, solver._counts, self.needed, search.fluid.needed,
            search.boundary.needed if search.boundary_grid is not None else self._zero_total,
            self.time, self.end, self.steps, self.slot, self.log, self.keep_going])

    def _body(self) -> None:
        self.slot.zero_()
        self.needed.zero_()
        self.keep_going.fill_(1)
        wp.capture_while(self.keep_going, self._step_body)

    def _needed(self) -> tuple[int, int]:
        fluid, boundary = self.needed.numpy()
        return int(fluid), int(boundary)

    def _rewind(self) -> None:
        self.time.fill_(self.sim.time)
        self.steps.fill_(self.sim.solver.steps)

    def replay_until(self, end: float):
        """Replay until the clock reaches ``end``, yielding each step's record (with its end time
        ``t``) once per replay; the caller advances ``sim.time`` and stops on a divergence."""
        sim = self.sim
        while sim.time < end - 1e-9:
            self.end.fill_(end)
            self._rewind()
            t0 = time.perf_counter()
            self._launch()
            self.replays += 1
            k = int(self.slot.numpy()[0])
            if k == 0:
                raise RuntimeError("graph replay made no progress")
            log = self.log.numpy()[:k]
            ms = {"step": round(1e3 * (time.perf_counter() - t0) / k, 4)}
            sim.solver.steps += k
            for row in log:
                rec = dict(zip(LOG_FIELDS, (float(v) for v in row)))
                for key in ("iterations", "escaped", "non_finite"):
                    rec[key] = int(rec[key])
                yield {**rec, "ms": ms}
