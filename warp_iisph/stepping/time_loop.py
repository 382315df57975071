"""The loop over time steps, the one owner of stepping: its device state (clock, end time, step
count, the step's dt, a log of step statistics) and its rules (the step's length,
:mod:`.step_length`; the reorder schedule; the divergence checks), all kernels.

One step is :meth:`TimeLoop.step_body`: choose dt, place the moving bodies, reorder by cell when
due, the solver's step, the free bodies' update (:mod:`.bodies`), record the statistics and
decide whether another step follows. The plain path launches it from a
Python loop, timing each stage and growing neighbour storage before it overflows; a graph
(:mod:`.graph`) records :meth:`TimeLoop.loop_body`, the same body inside ``wp.capture_while``,
and replays it. Nothing in the body allocates or reads back, so it may sit inside a CUDA graph's
conditional nodes.
"""

from __future__ import annotations

from contextlib import nullcontext

import warp as wp

from ..engine.launch import launch
from ..engine.reduce import max_into
from ..engine.timing import StageTimes
from ..sph.solvers import STAGES
from .bodies import BodySteps
from .step_length import Clock, StepRule, Substeps, choose_dt

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

LOG_FIELDS = (
    "dt",
    "iterations",
    "density_error",
    "compression",
    "max_velocity",
    "escaped",
    "non_finite",
    "wall_corrections",
    "obstacle_corrections",
    "t",
    "substeps",
)
# the fields of LOG_FIELDS that are counts
COUNT_FIELDS = ("iterations", "escaped", "non_finite", "wall_corrections", "obstacle_corrections", "substeps")
# particles are reordered by grid cell every this many steps (1 = every step)
REORDER_INTERVAL = 10


@wp.struct
class StepStatistics:
    """The device scalars a step's log row is made of."""

    compression_sum: wp.array(dtype=wp.float64)
    error_sum: wp.array(dtype=wp.float64)
    iterations: wp.array(dtype=wp.int32)
    max_speed2: wp.array(dtype=float)  # the step's top speed, squared (the CFL rule's)
    counts: wp.array(dtype=wp.int32)  # particles out of the domain, non-finite
    corrections: wp.array(dtype=wp.int32)  # particles the last line put back (walls, obstacles)
    needed: wp.array(dtype=wp.int32)  # list entries the loop's steps needed (fluid, boundary)
    list_total_fluid: wp.array(dtype=wp.int32)  # this step's need of each list
    list_total_boundary: wp.array(dtype=wp.int32)


@wp.kernel
def check_state(
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    lower: wp.vec3,
    upper: wp.vec3,
    speed2: wp.array(dtype=float),
    counts: wp.array(dtype=wp.int32),
):
    """Each particle's squared speed (0 where not finite; reduce.max_into takes the largest),
    particles outside the domain (counts[0]) and non-finite ones (counts[1])."""
    i = wp.tid()
    x_i = x[i]
    v_i = v[i]
    speed2[i] = 0.0
    if not (wp.isfinite(x_i) and wp.isfinite(v_i)):
        wp.atomic_add(counts, 1, 1)
        return
    speed2[i] = wp.dot(v_i, v_i)
    if (
        x_i[0] < lower[0]
        or x_i[1] < lower[1]
        or x_i[2] < lower[2]
        or x_i[0] > upper[0]
        or x_i[1] > upper[1]
        or x_i[2] > upper[2]
    ):
        wp.atomic_add(counts, 0, 1)


@wp.kernel
def reorder_due(steps: wp.array(dtype=wp.int32), interval: int, due: wp.array(dtype=wp.int32)):
    due[0] = wp.where(steps[0] % interval == 0, 1, 0)


@wp.kernel
def record_mean(
    slot: wp.array(dtype=wp.int32),
    n: int,
    total: wp.array(dtype=wp.float64),
    column: int,
    log: wp.array2d(dtype=wp.float64),
):
    """A solver's own statistic, a sum over particles, as its mean in the step's log row."""
    log[slot[0], column] = total[0] / wp.float64(n)


@wp.kernel
def record_count(
    slot: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32), column: int, log: wp.array2d(dtype=wp.float64)
):
    """A solver's own count (iterations) in the step's log row."""
    log[slot[0], column] = wp.float64(count[0])


@wp.kernel
def record_step(
    n: int,
    velocity_limit: wp.float64,
    clock: Clock,
    sub: Substeps,
    stats: StepStatistics,
    log: wp.array2d(dtype=wp.float64),
):
    """Append the step's statistics to the log, advance the clock, and decide whether another
    step follows: not at the end time, not past the step limit, not after a divergence."""
    k = clock.slot[0]
    dt = clock.dt[0]
    t = clock.time[0] + dt
    clock.time[0] = t
    counts, corrections = stats.counts, stats.corrections
    speed = wp.float64(wp.sqrt(stats.max_speed2[0]))
    log[k, 0] = dt
    log[k, 1] = wp.float64(stats.iterations[0])
    log[k, 2] = stats.error_sum[0] / wp.float64(n)
    log[k, 3] = stats.compression_sum[0] / wp.float64(n)
    log[k, 4] = speed
    log[k, 5] = wp.float64(counts[0])
    log[k, 6] = wp.float64(counts[1])
    log[k, 7] = wp.float64(corrections[0])
    log[k, 8] = wp.float64(corrections[1])
    log[k, 9] = t
    log[k, 10] = wp.float64(sub.pieces[0])
    stats.needed[0] = wp.max(stats.needed[0], stats.list_total_fluid[0])
    stats.needed[1] = wp.max(stats.needed[1], stats.list_total_boundary[0])
    clock.slot[0] = k + 1
    clock.steps[0] = clock.steps[0] + 1
    diverged = counts[0] > 0 or counts[1] > 0 or speed > velocity_limit
    last = diverged or k + 1 >= clock.step_limit[0] or t >= clock.end[0] - wp.float64(1.0e-9)
    clock.keep_going[0] = wp.where(last, 0, 1)


class TimeLoop:
    """The device state of the loop over steps of ``solver`` on ``model``/``state``, and its body.

    ``velocity_scale`` is the speed the CFL rule assumes at least (sqrt(2 g y_top)), and
    ``velocity_limit`` the speed beyond which a step counts as diverged. A solver with an
    ``extra_stats()`` (name: device scalar, a float64 sum over particles logged as its mean, or
    an int32 count) has those logged too, after :data:`LOG_FIELDS`."""

    def __init__(self, model, state, solver, velocity_scale: float, velocity_limit: float, log_capacity: int = 256):
        self.model, self.state, self.solver = model, state, solver
        self.physics = model.physics
        self.velocity_scale = float(velocity_scale)
        self.velocity_limit = float(velocity_limit)
        self.dt_limit = self.physics.dt_max  # the CFL rule's longest step
        self.capacity = int(log_capacity)
        self.extra = dict(solver.extra_stats()) if hasattr(solver, "extra_stats") else {}
        self.fields = LOG_FIELDS + tuple(self.extra)
        dev = model.device
        f64 = wp.float64
        self.time = wp.zeros(1, dtype=f64, device=dev)
        self.end = wp.zeros(1, dtype=f64, device=dev)
        self.dt64 = wp.zeros(1, dtype=f64, device=dev)
        self.dt_request = wp.zeros(1, dtype=f64, device=dev)
        self.steps = wp.zeros(1, dtype=wp.int32, device=dev)
        self.slot = wp.zeros(1, dtype=wp.int32, device=dev)
        self.step_limit = wp.zeros(1, dtype=wp.int32, device=dev)
        self.keep_going = wp.zeros(1, dtype=wp.int32, device=dev)
        self.due = wp.zeros(1, dtype=wp.int32, device=dev)
        self.needed = wp.zeros(2, dtype=wp.int32, device=dev)
        self.max_speed2 = wp.zeros(1, dtype=float, device=dev)  # the last step's top speed, squared: the CFL rule's
        self.counts = wp.zeros(2, dtype=wp.int32, device=dev)  # particles out of the domain, non-finite
        self.speed2 = wp.zeros(max(state.capacity, 1), dtype=float, device=dev)
        # the domain's corners as the state check takes them, made once (fixed when the model is
        # built; a packed launch holds the vectors it was given)
        self.domain = (wp.vec3(*model.domain_lower), wp.vec3(*model.domain_upper))
        # a fixed dt cut into substeps: what is left of the one being cut, substeps taken of it, and
        # how many it is cut into (logged)
        self.sub_left = wp.zeros(1, dtype=f64, device=dev)
        self.sub_done = wp.zeros(1, dtype=wp.int32, device=dev)
        self.pieces = wp.ones(1, dtype=wp.int32, device=dev)
        self.log = wp.zeros((self.capacity, len(self.fields)), dtype=f64, device=dev)
        self._zero_total = wp.zeros(1, dtype=wp.int32, device=dev)
        self.rule, self.clock, self.substeps, self.statistics = self._structs()
        self.probes = None  # a scene's probes (.probing.ProbeSampler), sampled at the end of a step
        self.flows = None  # a scene's emitters (.flows.Flows), whose nozzles drive the liquid in front of them
        self.bodies = BodySteps(model, solver) if model.bodies is not None else None

    def _structs(self) -> tuple[StepRule, Clock, Substeps, StepStatistics]:
        """The kernels' views of the loop's settings and device state (the same arrays)."""
        ph, f64 = self.physics, wp.float64
        rule = StepRule()
        rule.fixed_dt = f64(ph.dt if ph.dt is not None else -1.0)
        rule.cfl, rule.h = f64(ph.cfl), f64(self.model.spacing)
        rule.velocity_scale, rule.signal_speed = f64(self.velocity_scale), f64(self.solver.signal_speed)
        rule.dt_min, rule.dt_max, rule.split = f64(ph.dt_min), f64(self.dt_limit), int(ph.substeps)
        clock = Clock()
        for name in ("time", "end", "dt_request", "steps", "slot", "step_limit", "keep_going"):
            setattr(clock, name, getattr(self, name))
        clock.dt = self.dt64
        sub = Substeps()
        sub.left, sub.done, sub.pieces = self.sub_left, self.sub_done, self.pieces
        stats = StepStatistics()
        stats.compression_sum = self.solver._compression_sum
        stats.error_sum, stats.iterations = self.solver.solver_stats()
        stats.max_speed2, stats.counts = self.max_speed2, self.counts
        stats.corrections, stats.needed = self.model.containment.corrections, self.needed
        search = self.solver.search
        stats.list_total_fluid = search.fluid.needed
        stats.list_total_boundary = search.boundary.needed if search.boundary_grid is not None else self._zero_total
        return rule, clock, sub, stats

    def start(
        self, time: float, steps: int, end: float, dt: float | None = None, step_limit: int | None = None
    ) -> None:
        """Set the clock (the host's copy of time and step count is the truth between calls), the
        end time, a requested dt (``None``: the rules choose) and how many steps a replay may take."""
        self.time.fill_(time)
        self.steps.fill_(steps)
        self.end.fill_(end)
        self.dt_request.fill_(-1.0 if dt is None else dt)
        self.step_limit.fill_(self.capacity if step_limit is None else min(step_limit, self.capacity))

    def step_body(self, timer=None, sync: bool = False) -> None:
        """One step, all on the device. ``timer``: stage times (plain path); ``sync``: neighbour
        storage may be read back and grown (plain path); without it an overflow shows in
        ``needed`` and the caller redoes the step."""
        model, state, solver = self.model, self.state, self.solver
        dev = model.device
        launch(choose_dt, dim=1, device=dev, inputs=[self.rule, self.clock, self.substeps, self.max_speed2, solver.dt])
        if self.bodies is not None:  # moving bodies where they are at the step's start
            self.bodies.place(self.time, self.dt64)
        launch(reorder_due, dim=1, inputs=[self.steps, REORDER_INTERVAL, self.due], device=dev)
        with timer("neighbours") if timer else nullcontext():
            wp.capture_if(self.due, lambda: state.reorder(solver.search.cell_order(state.x, state.n)))
        solver.launch_step(model, state, timer, sync=sync)
        search = solver.search
        with timer("integration") if timer else nullcontext():
            self.max_speed2.zero_()
            if self.bodies is not None:  # loads, gravity and contacts move the free bodies (their speed counts)
                self.bodies.move(state, self.time, self.dt64, self.max_speed2)
            if self.flows is not None:  # the liquid in front of a pouring nozzle moves with its stream
                self.flows.drive(state.n, self.time, self.dt64)
            # the last line: nothing beyond a wall, every correction counted; then the checks
            model.containment.apply(state.x, state.v, search.boundary.lists, state.n, self.dt64)
            self.counts.zero_()
            lo, hi = self.domain
            launch(check_state, dim=state.n, device=dev, inputs=[state.x, state.v, lo, hi, self.speed2, self.counts])
            max_into(self.speed2, state.n, self.max_speed2)
        if self.probes:
            self.probes.sample(state, solver, self.time, self.dt64, self.max_speed2, self.slot)
        for column, value in enumerate(self.extra.values(), len(LOG_FIELDS)):  # before record_step moves the slot on
            if value.dtype == wp.float64:
                launch(record_mean, dim=1, device=dev, inputs=[self.slot, max(state.n, 1), value, column, self.log])
            else:
                launch(record_count, dim=1, device=dev, inputs=[self.slot, value, column, self.log])
        launch(
            record_step,
            dim=1,
            device=dev,
            inputs=[
                max(state.n, 1),
                wp.float64(self.velocity_limit),
                self.clock,
                self.substeps,
                self.statistics,
                self.log,
            ],
        )

    def loop_body(self) -> None:
        """Steps until the end time, the step limit or a divergence: what a graph records."""
        self.slot.zero_()
        self.needed.zero_()
        self.keep_going.fill_(1)
        wp.capture_while(self.keep_going, self.step_body)

    def plain_step(self) -> dict:
        """One step launched from Python, every stage timed: its record (with ``ms`` per stage)."""
        timer = StageTimes(self.model.device, STAGES)
        self.slot.zero_()
        self.step_body(timer, sync=True)
        (record,) = self.records(1)
        record["ms"] = timer.ms()
        return record

    def records(self, k: int) -> list[dict]:
        """The first ``k`` log rows as records (``t``: the time at the step's end)."""
        rows = self.log.numpy()[:k]
        counts = [name for name, value in self.extra.items() if value.dtype != wp.float64]
        out = []
        for row in rows:
            rec = dict(zip(self.fields, (float(v) for v in row)))
            for key in (*COUNT_FIELDS, *counts):
                rec[key] = int(rec[key])
            out.append(rec)
        return out

    def steps_logged(self) -> int:
        return int(self.slot.numpy()[0])

    def lists_needed(self) -> tuple[int, int]:
        """Entries the fluid and boundary lists needed during the last loop."""
        fluid, boundary = self.needed.numpy()
        return int(fluid), int(boundary)
