"""Twins of IISPH's pressure solve, kept for measurement only (benchmarks/pressure_solve.py): the
warm starts and iteration schemes the package's relaxed Jacobi is compared with. The package does
not use this module.

Warm starts (the pressure a step's solve starts from, after ``predict_advection``):

- ``hydrostatic``, ``half``, ``half_hydrostatic``: the package's ``physics.warm_start`` values
  (warp_iisph.sph.hydrostatic), set on the scene before the solver is built (the caller's job:
  the scene's iteration floor follows from it).
- ``full``: ``p(t - dt)``, on a scene set to ``half``.

Schemes, each run through the package's one loop (``IterativeSolve``; but for Jacobi none ends at
eta by blending, so each reports its last iterate's error):

- ``jacobi``: the package's relaxed Jacobi kernels and ending.
- ``bb``: projected preconditioned gradient steps ``p = max(p + w D^-1 (rho_pred - rho0), 0)`` with
  the Barzilai-Borwein length ``w = (s . D s) / (s . y)`` from the last two iterates (bounded to
  [0.2, 3]; the first step 0.5), ``D = -a_diag``: one operator evaluation per iteration.
- ``cg``: Jacobi-preconditioned conjugate gradients (Polak-Ribiere, ``beta >= 0``) in ``p / rho^2``
  on the particles compressed or pressed at the start (the others held at zero), the walls' active
  entries frozen for the step, clamped at zero at the end. The extrapolated walls make the system
  non-symmetric, which conjugate gradients assume.
- ``chebyshev``: Chebyshev semi-iteration over Jacobi (eigenvalues of ``D^-1 A`` taken in
  [0.01, 4]; two plain relaxed steps first; no momentum through a clamped particle).
"""

from __future__ import annotations

import warp as wp

from warp_iisph.engine.launch import launch_particles
from warp_iisph.engine.reduce import sum_into
from warp_iisph.sph.neighbors import NeighborList, entry
from warp_iisph.sph.solvers.base import Fluid
from warp_iisph.sph.solvers.iisph import (
    IISPHSolver,
    IISPHTerms,
    dij_pj_term,
    jacobi_advance,
    jacobi_boundary_sigma,
    jacobi_sigma_term,
)
from warp_iisph.sph.solvers.iteration import IterativeSolve
from warp_iisph.sph.wall_pressure import Walls, smoothed_pressure

WARM_STARTS = ("hydrostatic", "half", "half_hydrostatic", "full")
SCHEMES = ("jacobi", "bb", "cg", "chebyshev")
INACTIVE = wp.constant(-1.0e30)  # a wall entry's head that marks it inactive for the step (cg)


@wp.kernel
def scale_pressure(offset: int, s: float, p: wp.array(dtype=float)):
    i = wp.tid() + offset
    p[i] = s * p[i]


@wp.kernel
def mark_inactive_walls(offset: int, p: wp.array(dtype=float), nf: NeighborList, nb: NeighborList, walls: Walls):
    """Freeze the walls' active set for the step: an entry whose pressure is zero at the start stays off."""
    i = wp.tid() + offset
    if nb.count[i] == 0:
        return
    p_sum = float(0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        p_sum += nf.W[k] * p[nf.index[k]]
    p_c = smoothed_pressure(i, p, p_sum, walls)
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        if p_c + nb.head[k] <= 0.0:
            nb.head[k] = INACTIVE


@wp.kernel
def displacement_of(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    iisph: IISPHTerms,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    linear: int,
):
    """As ``pressure_sum_dij_pj``; with ``linear`` the walls' pressure is the smoothed pressure of
    ``p`` alone (no head, no clamp) on the active entries: the operator's linear part."""
    i = wp.tid() + offset
    dt = fluid.dt[0]
    acc = wp.vec3(0.0, 0.0, 0.0)
    extrapolated = walls.pressure_factor > 0.0 and nb.count[i] > 0
    p_sum = float(0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        j = nf.index[k]
        acc -= dij_pj_term(fluid.mass, p[j], rho[j], nf.grad_W[k])
        if extrapolated:
            p_sum += nf.W[k] * p[j]
    if extrapolated:
        p_c = smoothed_pressure(i, p, p_sum, walls)
        for m in range(nb.count[i]):
            k = entry(nb, i, m)
            head = nb.head[k]
            p_b = float(0.0)
            if head > 0.5 * INACTIVE:
                if linear != 0:
                    p_b = p_c
                else:
                    p_b = wp.max(p_c + head, 0.0)
            acc -= (walls.psi[nb.index[k]] * walls.pressure_factor * p_b) * nb.grad_W[k]
    sdp = dt * dt * acc
    iisph.sum_dij_pj[i] = sdp
    iisph.displacement[i] = iisph.d_ii[i] * p[i] + sdp


@wp.kernel
def density_change_of(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    iisph: IISPHTerms,
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    out: wp.array(dtype=float),
):
    """``a_ii p_i + s_i``: the density change the pressures ``p`` give particle i."""
    i = wp.tid() + offset
    dt = fluid.dt[0]
    rho_i = rho[i]
    p_i = p[i]
    sdp_i = iisph.sum_dij_pj[i]
    d_ji_scale = dt * dt * fluid.mass / (rho_i * rho_i)
    sigma = float(0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        g = nf.grad_W[k]
        sigma += jacobi_sigma_term(fluid.mass, sdp_i, iisph.displacement[nf.index[k]], (d_ji_scale * g) * p_i, g)
    out[i] = iisph.a_ii[i] * p_i + jacobi_boundary_sigma(i, walls.psi, nb, sdp_i, sigma)


@wp.func
def preconditioned(e: float, a_diag: float) -> float:
    """``D^-1 (rho_pred - rho0)``: the relaxed Jacobi step direction (``D = -a_diag``)."""
    z = float(0.0)
    if a_diag < -1.0e-12:
        z = e / (-a_diag)
    return z


@wp.kernel
def bb_terms(
    offset: int,
    rho_adv: wp.array(dtype=float),
    change: wp.array(dtype=float),
    rho0: float,
    a_diag: wp.array(dtype=float),
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    p_last: wp.array(dtype=float),
    e: wp.array(dtype=float),
    e_last: wp.array(dtype=float),
    t_sds: wp.array(dtype=wp.float64),
    t_sy: wp.array(dtype=wp.float64),
    error: wp.array(dtype=wp.float64),
):
    i = wp.tid() + offset
    e_i = rho_adv[i] + change[i] - rho0
    s = p[i] - p_last[i]
    w = 1.0 / (rho[i] * rho[i])
    t_sds[i] = wp.float64(w * s) * wp.float64(-a_diag[i] * s)
    t_sy[i] = wp.float64(w * s) * wp.float64(e_last[i] - e_i)
    error[i] = wp.max(wp.float64(e_i / rho0), wp.float64(0.0))
    e[i] = e_i
    e_last[i] = e_i
    p_last[i] = p[i]


@wp.kernel
def bb_length(
    sds: wp.array(dtype=wp.float64),
    sy: wp.array(dtype=wp.float64),
    iterations: wp.array(dtype=wp.int32),
    length: wp.array(dtype=float),
):
    w = float(0.5)
    if iterations[0] > 0:
        w = 3.0
        if sy[0] > wp.float64(0.0):
            w = wp.min(wp.max(float(sds[0] / sy[0]), 0.2), 3.0)
    length[0] = w


@wp.kernel
def bb_step(
    offset: int,
    length: wp.array(dtype=float),
    e: wp.array(dtype=float),
    a_diag: wp.array(dtype=float),
    p: wp.array(dtype=float),
):
    i = wp.tid() + offset
    p[i] = wp.max(p[i] + length[0] * preconditioned(e[i], a_diag[i]), 0.0)


@wp.kernel
def cg_start(
    offset: int,
    rho_adv: wp.array(dtype=float),
    change: wp.array(dtype=float),
    rho0: float,
    a_diag: wp.array(dtype=float),
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    free: wp.array(dtype=float),
    e: wp.array(dtype=float),
    z: wp.array(dtype=float),
    d: wp.array(dtype=float),
    t_rz: wp.array(dtype=wp.float64),
):
    i = wp.tid() + offset
    e_i = rho_adv[i] + change[i] - rho0
    e[i] = e_i
    f = wp.where(p[i] > 0.0 or e_i > 0.0, 1.0, 0.0)
    free[i] = f
    z_i = f * preconditioned(e_i, a_diag[i])
    z[i] = z_i
    d[i] = z_i
    t_rz[i] = wp.float64(e_i * z_i / (rho[i] * rho[i]))


@wp.kernel
def cg_curvature(
    offset: int,
    d: wp.array(dtype=float),
    q: wp.array(dtype=float),
    rho: wp.array(dtype=float),
    t: wp.array(dtype=wp.float64),
):
    i = wp.tid() + offset
    t[i] = wp.float64(d[i]) * wp.float64(-q[i]) / wp.float64(rho[i] * rho[i])


@wp.kernel
def cg_length(rz: wp.array(dtype=wp.float64), dq: wp.array(dtype=wp.float64), alpha: wp.array(dtype=float)):
    a = wp.float64(0.0)
    if dq[0] > wp.float64(0.0):
        a = rz[0] / dq[0]
    alpha[0] = float(a)


@wp.kernel
def cg_update(
    offset: int,
    alpha: wp.array(dtype=float),
    d: wp.array(dtype=float),
    q: wp.array(dtype=float),
    a_diag: wp.array(dtype=float),
    rho: wp.array(dtype=float),
    free: wp.array(dtype=float),
    rho0: float,
    p: wp.array(dtype=float),
    e: wp.array(dtype=float),
    z: wp.array(dtype=float),
    t_rz: wp.array(dtype=wp.float64),
    t_cross: wp.array(dtype=wp.float64),
    error: wp.array(dtype=wp.float64),
):
    i = wp.tid() + offset
    a = alpha[0]
    p[i] = p[i] + a * d[i]
    e_i = e[i] + a * q[i]
    e[i] = e_i
    z_last = z[i]
    z_i = free[i] * preconditioned(e_i, a_diag[i])
    z[i] = z_i
    w = 1.0 / (rho[i] * rho[i])
    t_rz[i] = wp.float64(w * e_i * z_i)
    t_cross[i] = wp.float64(w * e_i * z_last)
    error[i] = wp.max(wp.float64(e_i / rho0), wp.float64(0.0))


@wp.kernel
def cg_beta(
    rz: wp.array(dtype=wp.float64),
    rz_new: wp.array(dtype=wp.float64),
    cross: wp.array(dtype=wp.float64),
    beta: wp.array(dtype=float),
):
    b = wp.float64(0.0)
    if rz[0] > wp.float64(0.0):
        b = wp.max((rz_new[0] - cross[0]) / rz[0], wp.float64(0.0))
    beta[0] = float(b)
    rz[0] = rz_new[0]


@wp.kernel
def cg_direction(offset: int, beta: wp.array(dtype=float), z: wp.array(dtype=float), d: wp.array(dtype=float)):
    i = wp.tid() + offset
    d[i] = z[i] + beta[0] * d[i]


@wp.kernel
def clamp_pressure(offset: int, p: wp.array(dtype=float)):
    i = wp.tid() + offset
    p[i] = wp.max(p[i], 0.0)


@wp.kernel
def chebyshev_terms(
    offset: int,
    iterations: wp.array(dtype=wp.int32),
    lo: float,
    hi: float,
    plain: int,
    rho_adv: wp.array(dtype=float),
    change: wp.array(dtype=float),
    rho0: float,
    a_diag: wp.array(dtype=float),
    p: wp.array(dtype=float),
    step: wp.array(dtype=float),
    p_next: wp.array(dtype=float),
    error: wp.array(dtype=wp.float64),
):
    """The next iterate into ``p_next`` (and its step); the error of ``p``."""
    i = wp.tid() + offset
    k = iterations[0] - plain  # Chebyshev steps before this one (negative: a plain relaxed step)
    e_i = rho_adv[i] + change[i] - rho0
    error[i] = wp.max(wp.float64(e_i / rho0), wp.float64(0.0))
    z = preconditioned(e_i, a_diag[i])
    d = float(0.0)
    if k < 0:
        d = 0.5 * z
    else:
        theta = 0.5 * (hi + lo)
        delta = 0.5 * (hi - lo)
        sigma = theta / delta
        r_last = 1.0 / sigma
        r = r_last
        for _ in range(k):
            r_last = r
            r = 1.0 / (2.0 * sigma - r_last)
        if k == 0:
            d = z / theta
        else:
            d = r * r_last * step[i] + (2.0 * r / delta) * z
    q = p[i] + d
    if q <= 0.0:
        q = 0.0
        step[i] = 0.0
    else:
        step[i] = q - p[i]
    p_next[i] = q


class VariantIISPH(IISPHSolver):
    """IISPH with the warm start and iteration scheme of a variant (module docstring)."""

    def __init__(self, model, warm: str = "half", scheme: str = "jacobi"):
        super().__init__(model)
        if warm not in WARM_STARTS or scheme not in SCHEMES:
            raise ValueError(f"variant {warm}/{scheme}: warm start one of {WARM_STARTS}, scheme one of {SCHEMES}")
        self.warm, self.scheme = warm, scheme
        n, dev = model.capacity, model.device
        self.solve = IterativeSolve(n, dev, ends_at_eta=scheme == "jacobi")  # the package's ending for Jacobi

        def f32():
            return wp.zeros(n, dtype=float, device=dev)

        def f64():
            return wp.zeros(n, dtype=wp.float64, device=dev)

        self.change, self.e, self.e_last, self.p_last, self.z, self.d, self.q, self.free = (f32() for _ in range(8))
        self.t_a, self.t_b = f64(), f64()
        self.s_a, self.s_b, self.s_c = (wp.zeros(1, dtype=wp.float64, device=dev) for _ in range(3))
        self.length = wp.zeros(1, dtype=float, device=dev)
        self.beta = wp.zeros(1, dtype=float, device=dev)
        expected = "half" if warm == "full" else warm
        if self.warm_start != expected:
            raise ValueError(f"variant {warm}: the scene's physics.warm_start must be {expected!r}")

    def predict_advection(self, model, state) -> None:
        super().predict_advection(model, state)  # the scene's start (0.5 p(t - dt) for "full")
        if self.warm == "full":
            launch_particles(scale_pressure, state.n, [2.0, state.p], model.device)

    def launch_step(self, model, state, timer=None, sync: bool = True) -> None:
        if self.scheme == "jacobi":
            return super().launch_step(model, state, timer, sync)
        self.run_scheme = {"bb": self.bb_solve, "cg": self.cg_solve, "chebyshev": self.chebyshev_solve}[self.scheme]
        return super().launch_step(model, state, timer, sync)

    def pressure_change(self, model, state, p, linear: int, out) -> None:
        nf, nb = self.search.fluid.lists, self.search.boundary.lists
        common = [self.fluid, nf, nb, self.walls.walls, self.terms, state.rho, p]
        launch_particles(displacement_of, state.n, [*common, linear], model.device)
        launch_particles(density_change_of, state.n, [*common, out], model.device)

    # the solve: IISPHSolver.launch_step runs self.solve.run(..., jacobi_iteration, advance); the
    # other schemes replace those two callables through these methods

    def jacobi_iteration(self, model, state) -> None:
        if self.scheme == "jacobi":
            return super().jacobi_iteration(model, state)
        return self.run_scheme(model, state)

    def bb_solve(self, model, state) -> None:
        ph, n, dev, t = self.physics, state.n, model.device, self.terms
        self.pressure_change(model, state, state.p, 0, self.change)
        launch_particles(
            bb_terms,
            n,
            [t.rho_adv, self.change, ph.rho0, t.a_diag, state.rho, state.p, self.p_last, self.e, self.e_last, self.t_a,
             self.t_b, self.solve.error],
            dev,
        )  # fmt: skip
        sum_into(self.t_a, n, self.s_a)
        sum_into(self.t_b, n, self.s_b)
        wp.launch(bb_length, dim=1, inputs=[self.s_a, self.s_b, self.solve.iterations, self.length], device=dev)
        # the step itself is taken by advance (after the convergence test), as Jacobi's update
        launch_particles(jacobi_advance, n, [self.no_blend(dev), state.p, self.p_next], dev)  # p_next = p
        launch_particles(bb_step, n, [self.length, self.e, self.terms.a_diag, self.p_next], dev)

    def cg_solve(self, model, state) -> None:
        ph, n, dev, t = self.physics, state.n, model.device, self.terms
        if int(self.solve.iterations.numpy()[0]) == 0:  # the start: residual, free set, first direction
            if self.walls.extrapolated:
                launch_particles(
                    mark_inactive_walls,
                    n,
                    [state.p, self.search.fluid.lists, self.search.boundary.lists, self.walls.walls],
                    dev,
                )
            self.pressure_change(model, state, state.p, 0, self.change)
            launch_particles(
                cg_start,
                n,
                [t.rho_adv, self.change, ph.rho0, t.a_diag, state.rho, state.p, self.free, self.e, self.z, self.d,
                 self.t_a],
                dev,
            )  # fmt: skip
            sum_into(self.t_a, n, self.s_a)
        self.pressure_change(model, state, self.d, 1, self.q)
        launch_particles(cg_curvature, n, [self.d, self.q, state.rho, self.t_b], dev)
        sum_into(self.t_b, n, self.s_b)
        wp.launch(cg_length, dim=1, inputs=[self.s_a, self.s_b, self.length], device=dev)
        launch_particles(
            cg_update,
            n,
            [self.length, self.d, self.q, self.terms.a_diag, state.rho, self.free, ph.rho0, state.p, self.e, self.z,
             self.t_a, self.t_b, self.solve.error],
            dev,
        )  # fmt: skip
        sum_into(self.t_a, n, self.s_c)
        sum_into(self.t_b, n, self.s_b)
        wp.launch(cg_beta, dim=1, inputs=[self.s_a, self.s_c, self.s_b, self.beta], device=dev)
        launch_particles(cg_direction, n, [self.beta, self.z, self.d], dev)
        launch_particles(jacobi_advance, n, [self.no_blend(dev), state.p, self.p_next], dev)  # p_next = p

    def chebyshev_solve(self, model, state) -> None:
        ph, n, dev = self.physics, state.n, model.device
        self.pressure_change(model, state, state.p, 0, self.change)
        launch_particles(
            chebyshev_terms,
            n,
            [self.solve.iterations, 0.01, 4.0, 2, self.terms.rho_adv, self.change, ph.rho0, self.terms.a_diag, state.p,
             self.d, self.p_next, self.solve.error],
            dev,
        )  # fmt: skip

    def no_blend(self, dev) -> wp.array:
        if not hasattr(self, "_no_blend"):
            self._no_blend = wp.full(1, -1.0, dtype=float, device=dev)
        return self._no_blend

    def integrate(self, model, state, walls) -> None:
        if self.scheme == "cg":
            launch_particles(clamp_pressure, state.n, [state.p], model.device)
        super().integrate(model, state, walls)
