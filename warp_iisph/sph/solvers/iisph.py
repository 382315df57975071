"""Implicit Incompressible SPH (Ihmsen et al. 2014, IEEE TVCG 20(3)), with Akinci boundary particles
whose pressure is the fluid's extrapolated into the wall (:mod:`..wall_pressure`).

Per step, after densities: ``predict_advection`` computes ``v_adv = v + dt a_nonpressure``,
``d_ii = -dt^2 sum_j m/rho_i^2 grad W_ij - dt^2 sum_b psi_b/rho_i^2 grad W_ib``,
``rho_adv = rho_i + dt sum_j m v_adv_ij . grad W_ij + dt sum_b psi_b (v_adv_i - v_b) . grad W_ib`` and
``a_ii = sum_j m (d_ii - d_ji) . grad W_ij + sum_b psi_b d_ii . grad W_ib`` with
``d_ji = dt^2 m/rho_i^2 grad W_ij``; the pressure starts from the hydrostatic pressure under the
particle's column (``physics.warm_start``, :mod:`..hydrostatic`) or from ``0.5 p(t - dt)``.
The solve is relaxed Jacobi: ``sum_j d_ij p_j = -dt^2 sum_j m p_j/rho_j^2 grad W_ij
- dt^2 sum_b psi_b p_b/rho0^2 grad W_ib`` (the walls' pressures ``p_b`` extrapolated from this
iteration's pressures: known values like the neighbours', so they enter ``s_i``; with
``physics.wall_pressure = "fluid"`` the wall term is Akinci's, i's own pressure, held by ``d_ii``),
``s_i = sum_j m (sum_dij_pj_i - d_jj p_j - (sum_dij_pj_j - d_ji p_i)) . grad W_ij
+ sum_b psi_b sum_dij_pj_i . grad W_ib``, the predicted density ``rho_adv + a_ii p_i + s_i`` and
``p_i = max(p_i + omega (rho0 - rho_pred_i) / a_diag_i, 0)`` (``a_diag``: the system's diagonal,
``a_ii`` plus the share p_i has in the walls' pressures near i; ``a_ii`` itself with Akinci's
walls, where the step is written ``(1 - omega) p_i + omega / a_ii (rho0 - rho_adv_i - s_i)``; taken
as at least :data:`DIAGONAL_FLOOR` of a bulk particle's in magnitude),
until the average predicted density error ``mean(max(rho_i/rho0 - 1, 0))`` (reduced in float64)
is at most ``eta`` and at least ``min_iterations`` ran, or ``max_iterations`` is reached. The
error is that of the iteration's input pressures (the residual; see ``jacobi_update``).

The solve ends at the Jacobi update of the pressures at which the error reaches eta (the one
loop's ending, :mod:`.iteration`), so the pressure of resting water does not jump with the
integer iteration count from step to step. Why relaxed Jacobi from the hydrostatic pressure, and
what faster schemes run into: docs/pressure_solve.md.
"""

from __future__ import annotations

from contextlib import nullcontext

import warp as wp

from ...engine.launch import launch_particles
from ..hydrostatic import HydrostaticPressure
from ..kernel import lattice_grad_W_squared
from ..neighbors import NeighborList, entry
from ..wall_pressure import WallPressures, Walls, smoothed_pressure
from .base import Fluid, SPHSolver
from .forces import ViscousTerms, advected_velocity
from .iteration import IterativeSolve

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

# The least magnitude of the diagonal a Jacobi step divides by, as a fraction of the diagonal of a
# particle inside resting liquid: only particles pinned between walls fall below it (jacobi_update).
DIAGONAL_FLOOR = 0.25


@wp.struct
class IISPHTerms:
    """IISPH's per-particle terms of a step (Ihmsen et al.'s names)."""

    v_adv: wp.array(dtype=wp.vec3)  # velocity after the non-pressure forces
    d_ii: wp.array(dtype=wp.vec3)  # displacement per unit of i's own pressure over the step
    a_ii: wp.array(dtype=float)  # density change per unit of i's own pressure
    a_diag: wp.array(dtype=float)  # the system's diagonal: a_ii plus i's share in the walls' pressures
    rho_adv: wp.array(dtype=float)  # density after advection
    sum_dij_pj: wp.array(dtype=wp.vec3)  # displacement the neighbours' (and walls') pressures give i
    displacement: wp.array(dtype=wp.vec3)  # sum_dij_pj + d_ii p_i
    wall_push: wp.array(dtype=wp.vec3)  # E_i: displacement per unit of the pressure i's walls push with


@wp.kernel
def predict_advection_velocity(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    nf: NeighborList,
    nb: NeighborList,
    terms: ViscousTerms,
    gravity: wp.vec3,
    fluid: Fluid,
    walls: Walls,
    p: wp.array(dtype=float),
    iisph: IISPHTerms,
):
    """``v_adv``, ``d_ii`` and, with extrapolated wall pressures, ``E_i = -dt^2 / rho0^2 sum_b
    psi_b grad W_ib`` over the walls whose pressure is positive at the step's start (judged from
    p_i): how far i moves per unit of the pressure its walls push with. Where the other walls lie
    opposite those (a particle in a film between a body and the floor, its pressure zero at the
    start: only the walls below count), they are counted too: they push as soon as p_i rises
    above their small negative head, and one side's push alone drives i into the other side's
    walls, a compression that cancelled ``a_ii`` in the diagonal (``a_diag / a_ii`` measured
    0.03) and made the Jacobi step overshoot thirtyfold (docs/physics.md 4.6)."""
    i = wp.tid() + offset
    dt = fluid.dt[0]
    wall_weight = walls.pressure_factor
    iisph.v_adv[i] = advected_velocity(i, x, v, rho, nf, nb, terms, gravity, dt)
    d = wp.vec3(0.0, 0.0, 0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        d -= terms.mass * nf.grad_W[k]
    rho_i = rho[i]
    e = wp.vec3(0.0, 0.0, 0.0)
    e_off = wp.vec3(0.0, 0.0, 0.0)  # the walls whose pressure is not positive at the start
    s_i = float(1.0)
    if wall_weight > 0.0 and nb.count[i] > 0:
        s_i = walls.gradient_scale[i]  # the forces' side of the walls' gradient (wall_gradient.py)
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        b = nb.index[k]
        g = (terms.psi[b] * s_i) * nb.grad_W[k]
        d -= g
        if wall_weight > 0.0:
            if p[i] + nb.head[k] > 0.0:
                e += g
            else:
                e_off += g
    if wp.dot(e, e_off) < 0.0:  # walls on opposite sides (a film): both push once p_i rises
        e += e_off
    iisph.d_ii[i] = d * (dt * dt / (rho_i * rho_i))
    iisph.wall_push[i] = (-dt * dt * wall_weight) * e


@wp.kernel
def predict_advection_density(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    iisph: IISPHTerms,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
):
    """``rho_adv``, ``a_ii`` and the warm start; with extrapolated wall pressures also the system's
    diagonal ``a_diag``: p_i enters the smoothed pressure of i and of its neighbours j near walls
    (weights ``w_ji = W_ij / sum_k W_jk``), whose walls then move them by ``w_ji E_j`` per unit
    (``E_j``: ``wall_push``), so ``a_diag = a_ii + sum_j m (w_ii E_i - w_ji E_j) . grad W_ij +
    sum_b psi_b w_ii E_i . grad W_ib``. Without it the Jacobi step overshoots where a particle's
    own pressure dominates its walls' (edges, corners, thin films)."""
    i = wp.tid() + offset
    dt = fluid.dt[0]
    mass = fluid.mass
    push = iisph.wall_push
    weight = walls.weight
    v_adv = iisph.v_adv
    v_i = v_adv[i]
    rho_i = rho[i]
    dii = iisph.d_ii[i]
    d_ji_scale = dt * dt * mass / (rho_i * rho_i)
    extrapolated = walls.pressure_factor > 0.0
    e_i = wp.vec3(0.0, 0.0, 0.0)
    if extrapolated and nb.count[i] > 0:
        e_i = push[i] * (walls.W0 / weight[i])
    r = float(0.0)
    a = float(0.0)
    w = float(0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        j = nf.index[k]
        g = nf.grad_W[k]
        r += mass * wp.dot(v_i - v_adv[j], g)
        a += mass * wp.dot(dii - d_ji_scale * g, g)
        if extrapolated:
            e = e_i
            if nb.count[j] > 0:
                e = e_i - push[j] * (nf.W[k] / weight[j])
            w += mass * wp.dot(e, g)
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        g = nb.grad_W[k]
        b = nb.index[k]
        psi_b = walls.psi[b]
        r += psi_b * wp.dot(v_i - walls.v[b], g)  # a moving wall's velocity: the flow through it compresses
        a += psi_b * wp.dot(dii, g)
        if extrapolated:
            w += psi_b * wp.dot(e_i, g)
    iisph.rho_adv[i] = rho_i + dt * r
    iisph.a_ii[i] = a
    if extrapolated:
        iisph.a_diag[i] = a + w
    p[i] = 0.5 * p[i]


@wp.func
def dij_pj_term(mass: float, p_j: float, rho_j: float, grad_W: wp.vec3) -> wp.vec3:
    """Neighbour j's part of ``-sum_j d_ij p_j / dt^2``."""
    return (mass * p_j / (rho_j * rho_j)) * grad_W


@wp.func
def jacobi_sigma_term(mass: float, sdp_i: wp.vec3, disp_j: wp.vec3, d_ji_p_i: wp.vec3, grad_W: wp.vec3) -> float:
    """Fluid neighbour j's part of ``s_i``: ``m (sum_k d_ik p_k - d_jj p_j - sum_{k != i} d_jk p_k)
    . grad W_ij``, with ``disp_j = d_jj p_j + sum_k d_jk p_k`` (j's whole pressure displacement,
    one gathered vector instead of three) less i's part ``d_ji p_i``."""
    return mass * wp.dot(sdp_i - disp_j + d_ji_p_i, grad_W)


@wp.func
def jacobi_boundary_sigma(
    i: int, psi: wp.array(dtype=float), nb: NeighborList, sdp_i: wp.vec3, fluid_sigma: float
) -> float:
    """``s_i``: the walls' parts added, in list order, to the fluid neighbours' sum."""
    sigma = fluid_sigma
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        sigma += psi[nb.index[k]] * wp.dot(sdp_i, nb.grad_W[k])
    return sigma


@wp.func
def jacobi_sigma(
    i: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    iisph: IISPHTerms,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
) -> float:
    """``s_i`` of the pressures ``p``, from this iteration's ``sum_dij_pj`` and ``displacement``:
    the fluid neighbours' parts (:func:`jacobi_sigma_term`), then the walls'."""
    dt = fluid.dt[0]
    mass = fluid.mass
    rho_i = rho[i]
    p_i = p[i]
    sdp_i = iisph.sum_dij_pj[i]
    d_ji_scale = dt * dt * mass / (rho_i * rho_i)
    sigma = float(0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        j = nf.index[k]
        g = nf.grad_W[k]
        sigma += jacobi_sigma_term(mass, sdp_i, iisph.displacement[j], (d_ji_scale * g) * p_i, g)
    return jacobi_boundary_sigma(i, walls.psi, nb, sdp_i, sigma)


@wp.func
def jacobi_update(
    i: int,
    sigma: float,
    p_i: float,
    a: float,
    a_diag: float,
    rho_adv_i: float,
    rho0: float,
    omega: float,
    a_least: float,
    p_new: wp.array(dtype=float),
    density_error: wp.array(dtype=wp.float64),
):
    """The relaxed Jacobi pressure from ``s_i``, and the predicted density error of the pressures
    this iteration started from.

    ``s_i`` is summed from the iteration's input pressures (the walls' pressures too), so
    ``rho_adv + a_ii p_i + s_i`` is the density those pressures predict: the true residual.
    Evaluating it with the updated ``p_i`` instead (as SPlisHSPlasH does) mixes two iterates and
    reports ``(1 - omega)`` times the residual, half of it at omega = 0.5, so the solver stopped at
    twice the error eta allows. The step divides the residual by the system's diagonal
    ``a_diag``: ``a_ii`` itself with Akinci's walls (then ``p + omega (rho0 - rho_pred) / a_ii`` is
    written in IISPH's form), ``a_ii`` plus the share p_i has through the walls' extrapolated
    pressures with those (:func:`wall_diagonal`).

    A diagonal above ``-a_least`` (small, or of the wrong sign; ``a_least``: :data:`DIAGONAL_FLOOR`
    of the diagonal of a particle inside resting liquid, 0 for none) is taken as ``-a_least``: a
    particle pinned in a film between two walls (a body closing on a tank wall) has walls on both
    sides whose pushes cancel, so its own pressure barely changes its density, and the unguarded
    step raised its pressure by 40 times a bulk particle's per unit of compression, to 0.8 MPa in
    one step in the ``flood``, which shot it out at 20 m/s. The floor changes the step, not the
    solution it converges to (its residual is still ``rho0 - rho_pred``); the dam break and SPHERIC
    run bit for bit as without it (benchmarks/pinned_films.py)."""
    p_next = float(0.0)
    rho_pred = rho_adv_i + a * p_i + sigma
    if wp.abs(a) > 1.0e-12:
        if a_least > 0.0 and a_diag > -a_least:
            p_next = wp.max(p_i - omega / a_least * (rho0 - rho_pred), 0.0)
        elif a_diag == a:
            p_next = wp.max((1.0 - omega) * p_i + omega / a * (rho0 - rho_adv_i - sigma), 0.0)
        else:
            p_next = wp.max(p_i + omega / a_diag * (rho0 - rho_pred), 0.0)
    p_new[i] = p_next
    density_error[i] = wp.max(wp.float64(rho_pred / rho0) - wp.float64(1.0), wp.float64(0.0))


@wp.kernel
def pressure_sum_dij_pj(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    iisph: IISPHTerms,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
):
    """``sum_j d_ij p_j``: the displacement the neighbours' pressures give particle i over the
    step, with the walls' pressures extrapolated from this iteration's (none with Akinci's walls,
    whose term is i's own pressure, in ``d_ii``); and ``displacement``, that plus i's own
    ``d_ii p_i``, which the Jacobi update gathers from each neighbour."""
    i = wp.tid() + offset
    dt = fluid.dt[0]
    mass = fluid.mass
    acc = wp.vec3(0.0, 0.0, 0.0)
    extrapolated = walls.pressure_factor > 0.0 and nb.count[i] > 0
    p_sum = float(0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        j = nf.index[k]
        acc -= dij_pj_term(mass, p[j], rho[j], nf.grad_W[k])
        if extrapolated:
            p_sum += nf.W[k] * p[j]
    if extrapolated:
        p_c = smoothed_pressure(i, p, p_sum, walls)
        s_i = walls.gradient_scale[i]
        for m in range(nb.count[i]):
            k = entry(nb, i, m)
            p_b = wp.max(p_c + nb.head[k], 0.0)
            acc -= ((walls.psi[nb.index[k]] * s_i) * walls.pressure_factor * p_b) * nb.grad_W[k]
    sdp = dt * dt * acc
    iisph.sum_dij_pj[i] = sdp
    iisph.displacement[i] = iisph.d_ii[i] * p[i] + sdp


@wp.kernel
def pressure_jacobi(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    iisph: IISPHTerms,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    omega: float,
    a_least: float,
    p_new: wp.array(dtype=float),
    density_error: wp.array(dtype=wp.float64),
):
    """One relaxed Jacobi update from ``s_i`` (:func:`jacobi_update`); ``a_least`` the floor of
    the diagonal per dt^2."""
    i = wp.tid() + offset
    sigma = jacobi_sigma(i, fluid, nf, nb, walls, iisph, rho, p)
    dt = fluid.dt[0]
    jacobi_update(
        i,
        sigma,
        p[i],
        iisph.a_ii[i],
        iisph.a_diag[i],
        iisph.rho_adv[i],
        fluid.rho0,
        omega,
        a_least * dt * dt,
        p_new,
        density_error,
    )


@wp.kernel
def jacobi_advance(
    offset: int,
    blend: wp.array(dtype=float),
    p_next: wp.array(dtype=float),
    p: wp.array(dtype=float),
):
    """The Jacobi update ``p_next`` of this iteration's pressures ``p``, or, where the error
    crossed eta in this iteration (``blend`` not negative, :mod:`.iteration`), the update of the
    pressures at which it reaches eta: ``p + blend (p_next - p)``."""
    i = wp.tid() + offset
    b = blend[0]
    if b >= 0.0:
        p[i] = p[i] + b * (p_next[i] - p[i])
    else:
        p[i] = p_next[i]


class IISPHSolver(SPHSolver):
    """Implicit incompressible SPH with relaxed Jacobi; statistics report the iterations and the
    final average predicted density error."""

    def __init__(self, model):
        super().__init__(model)
        n, dev = model.capacity, model.device
        self.walls = WallPressures(model, n)

        def vectors():
            return wp.zeros(n, dtype=wp.vec3, device=dev)

        def scalars():
            return wp.zeros(n, dtype=float, device=dev)

        t = IISPHTerms()
        t.v_adv = self.v_adv
        t.d_ii, t.sum_dij_pj, t.displacement, t.wall_push = vectors(), vectors(), vectors(), vectors()
        t.a_ii, t.rho_adv = scalars(), scalars()
        # the diagonal the Jacobi step divides by: a_ii itself with Akinci's walls
        t.a_diag = scalars() if self.walls.extrapolated else t.a_ii
        self.terms = t
        self.p_next = scalars()
        # |a_ii| / dt^2 inside resting liquid, (m / rho0)^2 sum_j |grad W_ij|^2, and the floor's share
        h = model.spacing
        self.a_bulk = h**6 * lattice_grad_W_squared(h, model.support_radius)
        self.a_least = DIAGONAL_FLOOR * self.a_bulk
        self.solve = IterativeSolve(n, dev)  # the pressure solve: relaxed Jacobi, ending where its error reaches eta
        self.warm_start = self.physics.pressure_start()  # physics.warm_start, resolved
        self.hydrostatic = HydrostaticPressure(model) if self.warm_start != "half" else None

    def launch_step(self, model, state, timer=None, sync: bool = True) -> None:
        """One IISPH step (Ihmsen et al. 2014, Algorithm 1), stage by stage."""
        timer = timer or nullcontext
        ph = self.physics
        with timer("neighbours"):
            nf, nb = self.find_neighbours(state, sync)
        with timer("density"):
            self.compute_densities(model, state)
            self.walls.prepare(model, state, nf, nb)
        with timer("advection"):
            self.predict_advection(model, state)  # v_adv, d_ii, rho_adv, a_ii; the warm start
        with timer("pressure"):
            self.solve.run(
                state.n,
                ph.eta,
                ph.iteration_floor(),
                ph.max_iterations,
                lambda: self.jacobi_iteration(model, state),
                lambda blend: launch_particles(jacobi_advance, state.n, [blend, self.p_next, state.p], model.device),
            )
        with timer("integration"):
            self.integrate(model, state, self.walls)

    def predict_advection(self, model, state) -> None:
        """``v_adv``, ``d_ii``, ``rho_adv``, ``a_ii`` (and the diagonal with the walls' share),
        and the warm start: the gated hydrostatic pressure (``"hydrostatic"``), ``0.5 p(t - dt)``
        (``"half"``) or that plus half the hydrostatic pressure (``"half_hydrostatic"``)."""
        nf, nb = self.search.fluid.lists, self.search.boundary.lists
        n, dev, walls = state.n, model.device, self.walls.walls
        g = self.gravity
        launch_particles(
            predict_advection_velocity,
            n,
            [state.x, state.v, state.rho, nf, nb, self.viscous.terms, g, self.fluid, walls, state.p, self.terms],
            dev,
        )
        self.viscous.run(model, state, nf, nb, self.dt, self.v_adv)
        launch_particles(predict_advection_density, n, [self.fluid, nf, nb, walls, self.terms, state.rho, state.p], dev)
        if self.warm_start == "hydrostatic":
            self.hydrostatic.start(state.x, n, self.terms.rho_adv, self.physics.rho0, nb, state.p)
        elif self.warm_start == "half_hydrostatic":
            self.hydrostatic.add(state.x, n, 0.5, state.p)

    def jacobi_iteration(self, model, state) -> None:
        """One relaxed Jacobi iteration: ``p_next`` and the predicted density error of ``p``."""
        nf, nb = self.search.fluid.lists, self.search.boundary.lists
        n, dev, walls = state.n, model.device, self.walls.walls
        common = [self.fluid, nf, nb, walls, self.terms, state.rho, state.p]
        launch_particles(pressure_sum_dij_pj, n, common, dev)
        launch_particles(
            pressure_jacobi, n, [*common, float(self.physics.omega), self.a_least, self.p_next, self.solve.error], dev
        )

    def solver_stats(self) -> tuple[wp.array, wp.array]:
        return self.solve.stats()
