"""Divergence-free SPH (Bender & Koschier 2017, IEEE TVCG 23(3)), with Akinci boundaries.

Two pressure solves per step, each a Jacobi iteration on the stiffness ``kappa_i / rho_i`` (the
paper's kappa over density; the pressure is ``p_i = kappa_i rho_i``), whose velocity change is
``dv_i = -dt sum_j m (kappa_i/rho_i + kappa_j/rho_j) grad W_ij - dt sum_b psi_b (kappa_i/rho_i) grad W_ib``:
a wall pushes with the fluid particle's own stiffness (one term, as the walls of IISPH and WCSPH
here). Setting the change of particle i's density rate that its own stiffness causes (through
its velocity and its neighbours') against the error gives the factor
``alpha_i / rho_i = 1 / (|sum_j m grad W_ij + sum_b psi_b grad W_ib|^2 + sum_j |m grad W_ij|^2)``.

A step (stages as :data:`~.base.STAGES`):

- density: ``rho_i`` (Akinci), then ``alpha_i / rho_i``.
- pressure (divergence solve), on the velocity the last step ended with: until the mean of
  ``max(D rho_i/Dt, 0) dt / rho0`` is at most ``eta_divergence`` (at least one iteration, at most
  ``max_iterations``), ``kappa_v_i / rho_i = max(kappa_v_i / rho_i + omega (D rho_i/Dt) / dt
  * alpha_i / rho_i, 0)`` with ``D rho_i/Dt = sum_j m v_ij . grad W_ij + sum_b psi_b (v_i - v_b)
  . grad W_ib``; a particle with fewer than :data:`MIN_NEIGHBORS` neighbours (fluid and wall) is
  left out: at a free surface its density rate says nothing about compression.
- advection: ``v_adv = v + dt a_nonpressure`` (:mod:`.forces`).
- pressure (constant-density solve), on ``v_adv``: until the mean predicted compression
  ``max(rho*_i / rho0 - 1, 0)``, ``rho*_i = rho_i + dt D rho_i/Dt``, is at most ``eta`` (at least
  ``min_iterations``, at most ``max_iterations``), ``kappa_i / rho_i = max(kappa_i / rho_i +
  omega (rho*_i - rho0) / dt^2 * alpha_i / rho_i, 0)``, with ``alpha_i / rho_i`` at most the
  inverse of :data:`DENOMINATOR_FLOOR` of a bulk particle's denominator (as IISPH's diagonal
  floor: a particle pinned between two walls would otherwise take unbounded steps). As IISPH's,
  the solve ends at the Jacobi update of the iterate at which the error (taken as linear between
  the last two iterates) reaches eta: the iteration that crosses eta applies only that share of
  its increments, and the step reports eta as its error.
- integration: ``v = v_adv``, ``x += dt v``; ``p_i = (kappa_i + kappa_v_i) rho_i`` (the pressure
  both solves applied this step) for frames, viewers and the hydrostatic check.

Each iteration computes the increments from the velocities so far (a gather), then moves the
velocities by the increments (a second gather), so the loop's error is that of its input
velocities. Both solves are relaxed Jacobi iterations (omega :data:`OMEGA`) on the total
stiffness, kept at or above zero, as IISPH's on the pressure: an iteration takes back stiffness
the error says is too much, so a warm start that proves too much does not stay in place (the
paper's one-way increments left resting water bouncing as a whole column; docs/physics.md 4.13).
Both start from half of the last step's stiffness where the velocity they start from compresses
the particle, and from zero elsewhere: the constant-density solve from ``kappa / rho`` itself
(``p / rho^2``, which does not depend on dt), the divergence solve from ``kappa_v / rho * dt``
over this step's dt (the velocity change it made does not depend on dt).
"""

from __future__ import annotations

from contextlib import nullcontext

import warp as wp

from ...engine.launch import launch_particles
from ..kernel import lattice_grad_W_squared
from ..neighbors import NeighborList, entry
from ..wall_pressure import Walls, walls_of
from .base import Fluid, SPHSolver
from .iteration import IterativeSolve

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

# Fewer neighbours (fluid and wall, self excluded) than this, and a particle takes no part in
# the divergence solve (the paper's particle deficiency rule; a resting particle has 26 fluid
# neighbours within 2h, and more beside a wall).
MIN_NEIGHBORS = wp.constant(20)
# Both solves start from this share of the last step's stiffness where the velocity they start
# from compresses (a larger share makes the resting column bounce: docs/physics.md 4.13).
WARM_START = wp.constant(0.5)
# The Jacobi relaxation of both solves (0.75 and 1 diverge: docs/physics.md 4.13).
OMEGA = wp.constant(0.5)
# The constant-density solve divides by at least this share of a bulk particle's denominator of
# alpha: a particle pinned in a film between two walls has next to none (its own stiffness hardly
# moves it) and took unbounded steps (the flood diverged at 0.56 s). As IISPH's DIAGONAL_FLOOR; the
# divergence solve keeps the raw factor (a floor there changed the dam break's sheets along walls).
DENOMINATOR_FLOOR = 0.25


@wp.kernel
def dfsph_factor(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    min_denominator: float,
    factor: wp.array(dtype=float),
):
    """``alpha_i / rho_i``; zero for a particle too alone to have one (its denominator is under
    ``min_denominator``)."""
    i = wp.tid() + offset
    mass = fluid.mass
    sum_grad = wp.vec3(0.0, 0.0, 0.0)
    sum_sq = float(0.0)
    for m in range(nf.count[i]):
        g = mass * nf.grad_W[entry(nf, i, m)]
        sum_grad += g
        sum_sq += wp.dot(g, g)
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        sum_grad += walls.psi[nb.index[k]] * nb.grad_W[k]
    d = wp.dot(sum_grad, sum_grad) + sum_sq
    factor[i] = wp.where(d > min_denominator, 1.0 / d, 0.0)


@wp.func
def density_rate(
    i: int, v: wp.array(dtype=wp.vec3), fluid: Fluid, nf: NeighborList, nb: NeighborList, walls: Walls
) -> float:
    """``D rho_i/Dt = sum_j m (v_i - v_j) . grad W_ij + sum_b psi_b (v_i - v_b) . grad W_ib``."""
    v_i = v[i]
    r = float(0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        r += fluid.mass * wp.dot(v_i - v[nf.index[k]], nf.grad_W[k])
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        b = nb.index[k]
        # a moving wall's velocity: the flow through it compresses
        r += walls.psi[b] * wp.dot(v_i - walls.v[b], nb.grad_W[k])
    return r


@wp.func
def take_part(i: int, nf: NeighborList, nb: NeighborList) -> bool:
    """Whether particle i has the neighbours to take part in the divergence solve."""
    return nf.count[i] + nb.count[i] >= MIN_NEIGHBORS


@wp.func
def relaxed_step(k: float, increment: float) -> float:
    """The change of a stiffness ``k`` by a relaxed Jacobi step, the total kept at or above zero."""
    return wp.max(k + OMEGA * increment, 0.0) - k


@wp.kernel
def start_divergence_solve(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    v: wp.array(dtype=wp.vec3),
    kappa_v_dt: wp.array(dtype=float),
    kappa_v: wp.array(dtype=float),
    delta: wp.array(dtype=float),
):
    """The warm start: a share of the last step's ``kappa_v / rho * dt`` over this step's dt,
    for the particles that take part and whose density the velocity ``v`` increases."""
    i = wp.tid() + offset
    k = float(0.0)
    if take_part(i, nf, nb):
        if density_rate(i, v, fluid, nf, nb, walls) > 0.0:
            k = WARM_START * kappa_v_dt[i] / fluid.dt[0]
    kappa_v[i] = 0.0
    delta[i] = k  # applied as the solve's first increment


@wp.kernel
def start_density_solve(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    kappa: wp.array(dtype=float),
    delta: wp.array(dtype=float),
):
    """The warm start: a share of the last step's ``kappa / rho``, which ``kappa`` holds, where
    the advected velocity ``v`` alone would compress the particle; zero elsewhere."""
    i = wp.tid() + offset
    k = float(0.0)
    if rho[i] + fluid.dt[0] * density_rate(i, v, fluid, nf, nb, walls) > fluid.rho0:
        k = WARM_START * kappa[i]
    kappa[i] = 0.0
    delta[i] = k  # applied as the solve's first increment


@wp.kernel
def divergence_jacobi(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    v: wp.array(dtype=wp.vec3),
    factor: wp.array(dtype=float),
    kappa_v: wp.array(dtype=float),
    delta: wp.array(dtype=float),
    error: wp.array(dtype=wp.float64),
):
    """The stiffness change towards cancelling particle i's density rate, and its compression
    rate as the density it would add in one step, a fraction of rho0."""
    i = wp.tid() + offset
    dt = fluid.dt[0]
    rate = float(0.0)
    if take_part(i, nf, nb):
        rate = density_rate(i, v, fluid, nf, nb, walls)
    delta[i] = relaxed_step(kappa_v[i], rate / dt * factor[i])
    error[i] = wp.float64(wp.max(rate, 0.0) * dt / fluid.rho0)


@wp.kernel
def density_jacobi(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    factor: wp.array(dtype=float),
    factor_most: float,
    kappa: wp.array(dtype=float),
    delta: wp.array(dtype=float),
    error: wp.array(dtype=wp.float64),
):
    """The stiffness change towards bringing particle i's predicted density ``rho*_i`` to rho0
    (``factor``: ``alpha_i / rho_i``, taken as at most ``factor_most``), and the predicted
    compression ``max(rho*_i / rho0 - 1, 0)``."""
    i = wp.tid() + offset
    dt = fluid.dt[0]
    rho0 = fluid.rho0
    rho_star = rho[i] + dt * density_rate(i, v, fluid, nf, nb, walls)
    delta[i] = relaxed_step(kappa[i], (rho_star - rho0) / (dt * dt) * wp.min(factor[i], factor_most))
    error[i] = wp.max(wp.float64(rho_star / rho0) - wp.float64(1.0), wp.float64(0.0))


@wp.kernel
def apply_stiffness(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    delta: wp.array(dtype=float),
    blend: wp.array(dtype=float),
    kappa: wp.array(dtype=float),
    v: wp.array(dtype=wp.vec3),
):
    """Add the stiffness increments ``d`` to the stiffness and their velocity change,
    ``v_i -= dt (sum_j m (d_i + d_j) grad W_ij + sum_b psi_b d_i grad W_ib)``, to the velocities
    (the wall pushes with the particle's own); where ``blend`` (:mod:`.iteration`)
    is not negative, only that share of them: the solve ends at the Jacobi update of the iterate
    at which its error reaches eta (the update is affine in the stiffness, but for the clamp at
    zero, so that is the last iterate plus ``blend`` times this iteration's increments)."""
    i = wp.tid() + offset
    d_i = delta[i]
    a = wp.vec3(0.0, 0.0, 0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        a += fluid.mass * (d_i + delta[nf.index[k]]) * nf.grad_W[k]
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        a += walls.psi[nb.index[k]] * d_i * nb.grad_W[k]
    b = wp.where(blend[0] < 0.0, 1.0, blend[0])
    kappa[i] = kappa[i] + b * d_i
    v[i] = v[i] - (fluid.dt[0] * b) * a


@wp.kernel
def finish_step(
    offset: int,
    v_adv: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    kappa: wp.array(dtype=float),
    kappa_v: wp.array(dtype=float),
    dt_step: wp.array(dtype=float),
    v: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
    p: wp.array(dtype=float),
    kappa_v_dt: wp.array(dtype=float),
):
    """``v = v*``, ``x += dt v``; the pressure both solves applied, ``p = (kappa + kappa_v) rho``
    (the arrays hold kappa / rho); the divergence solve's warm start for the next step."""
    i = wp.tid() + offset
    dt = dt_step[0]
    v_i = v_adv[i]
    v[i] = v_i
    x[i] = x[i] + dt * v_i
    rho_i = rho[i]
    p[i] = (kappa[i] + kappa_v[i]) * rho_i * rho_i
    kappa_v_dt[i] = kappa_v[i] * dt


class DFSPHSolver(SPHSolver):
    """Divergence-free SPH. Statistics: ``iterations`` and ``density_error`` are the
    constant-density solve's (as IISPH's), and :meth:`extra_stats` adds the divergence solve's
    iterations and final mean divergence error."""

    def __init__(self, model):
        super().__init__(model)
        n, dev = model.capacity, model.device
        self.factor = wp.zeros(n, dtype=float, device=dev)
        # the warm starts, kept with the particles by the state (Simulation registers `carried`)
        self.kappa = wp.zeros(n, dtype=float, device=dev)  # kappa / rho of the constant-density solve, its running sum
        self.kappa_v_dt = wp.zeros(n, dtype=float, device=dev)  # kappa_v / rho * dt of the last divergence solve
        self.kappa_v = wp.zeros(n, dtype=float, device=dev)  # kappa_v / rho, this step's running sum
        self.delta = wp.zeros(n, dtype=float, device=dev)  # the iteration's stiffness increments
        self.density_solve = IterativeSolve(n, dev)  # ends where its error reaches eta, as IISPH's
        self.divergence_solve = IterativeSolve(n, dev, ends_at_eta=False)
        self._whole = wp.full(1, -1.0, dtype=float, device=dev)  # no blend: whole increments
        # a denominator of alpha below this is a particle with next to no neighbours: (m / H^4)^2
        # is the scale of one neighbour's |m grad W|^2, 1e-6 of it a neighbour at the support's edge
        self.min_denominator = 1.0e-6 * (model.mass / model.support_radius**4) ** 2
        # the denominator of alpha of a particle inside resting liquid (|sum m grad W|^2 vanishes there)
        self.denominator_bulk = model.mass**2 * lattice_grad_W_squared(model.spacing, model.support_radius)
        self.factor_most = 1.0 / (DENOMINATOR_FLOOR * self.denominator_bulk) if DENOMINATOR_FLOOR > 0 else 1.0e30
        self.walls = walls_of(model)  # Akinci's walls: the fluid particle's own stiffness pushes
        self.carried = {"dfsph_kappa": self.kappa, "dfsph_kappa_v_dt": self.kappa_v_dt}

    def launch_step(self, model, state, timer=None, sync: bool = True) -> None:
        """One DFSPH step (Bender & Koschier 2017, Algorithm 1), stage by stage."""
        timer = timer or nullcontext
        n, dev = state.n, model.device
        with timer("neighbours"):
            nf, nb = self.find_neighbours(state, sync)
        with timer("density"):
            self.compute_densities(model, state)
            launch_particles(dfsph_factor, n, [self.fluid, nf, nb, self.walls, self.min_denominator, self.factor], dev)
        with timer("pressure"):
            self.correct_divergence_error(model, state)
        with timer("advection"):
            self.advect_velocity(model, state)  # v_adv = v + dt a_nonpressure
        with timer("pressure"):
            self.correct_density_error(model, state)
        with timer("integration"):
            launch_particles(
                finish_step,
                n,
                [self.v_adv, state.rho, self.kappa, self.kappa_v, self.dt, state.v, state.x, state.p, self.kappa_v_dt],
                dev,
            )

    def correct_divergence_error(self, model, state) -> None:
        """Make the velocity the last step ended with divergence-free (compression rates only)."""
        ph = self.physics
        self.start_solve(model, state, start_divergence_solve, [state.v, self.kappa_v_dt], self.kappa_v, state.v)
        self.divergence_solve.run(
            state.n,
            ph.eta_divergence,
            1,
            ph.max_iterations,
            lambda: self.divergence_iteration(model, state),
            lambda blend: self.apply(model, state, self.kappa_v, state.v, self._whole),
        )

    def correct_density_error(self, model, state) -> None:
        """Bring the density ``v_adv`` predicts to rho0 (the constant-density solve)."""
        ph = self.physics
        self.start_solve(model, state, start_density_solve, [self.v_adv, state.rho], self.kappa, self.v_adv)
        self.density_solve.run(
            state.n,
            ph.eta,
            ph.iteration_floor(),
            ph.max_iterations,
            lambda: self.density_iteration(model, state),
            lambda blend: self.apply(model, state, self.kappa, self.v_adv, blend),
        )

    def start_solve(self, model, state, kernel, first, kappa, v) -> None:
        """A solve's warm start (``kernel``: its increments from the last step's stiffness), applied
        to ``kappa`` and the velocities ``v`` as the solve's first increment."""
        launch_particles(kernel, state.n, [*self.common(), *first, kappa, self.delta], model.device)
        self.apply(model, state, kappa, v, self._whole)

    def common(self) -> list:
        """The arguments every DFSPH kernel of the step starts with."""
        return [self.fluid, self.search.fluid.lists, self.search.boundary.lists, self.walls]

    def apply(self, model, state, kappa, v, blend) -> None:
        """Add the increments ``delta`` (a ``blend`` share of them where it is not negative)."""
        launch_particles(apply_stiffness, state.n, [*self.common(), self.delta, blend, kappa, v], model.device)

    def divergence_iteration(self, model, state) -> None:
        launch_particles(
            divergence_jacobi,
            state.n,
            [*self.common(), state.v, self.factor, self.kappa_v, self.delta, self.divergence_solve.error],
            model.device,
        )

    def density_iteration(self, model, state) -> None:
        launch_particles(
            density_jacobi,
            state.n,
            [
                *self.common(),
                self.v_adv,
                state.rho,
                self.factor,
                self.factor_most,
                self.kappa,
                self.delta,
                self.density_solve.error,
            ],
            model.device,
        )

    def solver_stats(self) -> tuple[wp.array, wp.array]:
        return self.density_solve.stats()

    def extra_stats(self) -> dict:
        """Per-step statistics beyond the shared ones: the divergence solve's final mean error
        (a float64 sum over particles) and its iteration count."""
        error_sum, iterations = self.divergence_solve.stats()
        return {"divergence_error": error_sum, "divergence_iterations": iterations}
