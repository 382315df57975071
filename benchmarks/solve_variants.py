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
- ``twolevel``: relaxed Jacobi plus, every iteration, a coarse correction of its residual: the
  active particles' residuals averaged over cells about 4 spacings wide (``CoarseCorrection``),
  ``dt^2 lap(e) = rho0 r`` solved on the liquid cells (7-point Laplacian, mirrored at walls, zero
  at the free surface placed by the cells' fill fractions; SOR sweeps on one thread, so CPU only),
  ``e`` interpolated trilinearly back to the particles and added with the least-squares length
  ``(r . A z) / (A z . A z)`` (one more operator pass). The geometric Laplacian is the continuum's
  ``dt^2 lap p`` (the SPH operator gives 0.95 of it on a quadratic field inside the water); what it
  misses is the walls: in a smooth pressure rise the layers along the walls are compressed, not
  relieved, so the measured length comes out negative (docs/pressure_solve.md).
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
    jacobi_sigma,
    jacobi_update,
    pressure_sum_dij_pj,
)
from warp_iisph.sph.solvers.iteration import IterativeSolve
from warp_iisph.sph.wall_pressure import Walls, smoothed_pressure

WARM_STARTS = ("hydrostatic", "half", "half_hydrostatic", "full")
SCHEMES = ("jacobi", "bb", "cg", "chebyshev", "twolevel")
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
    out[i] = iisph.a_ii[i] * p[i] + jacobi_sigma(i, fluid, nf, nb, walls, iisph, rho, p)


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
        # the package's ending for Jacobi and for Jacobi with the coarse correction
        self.solve = IterativeSolve(n, dev, ends_at_eta=scheme in ("jacobi", "twolevel"))

        def f32():
            return wp.zeros(n, dtype=float, device=dev)

        def f64():
            return wp.zeros(n, dtype=wp.float64, device=dev)

        self.change, self.e, self.e_last, self.p_last, self.z, self.d, self.q, self.free = (f32() for _ in range(8))
        self.t_a, self.t_b = f64(), f64()
        self.s_a, self.s_b, self.s_c = (wp.zeros(1, dtype=wp.float64, device=dev) for _ in range(3))
        self.length = wp.zeros(1, dtype=float, device=dev)
        self.beta = wp.zeros(1, dtype=float, device=dev)
        self.coarse = CoarseCorrection(model) if scheme == "twolevel" else None
        expected = "half" if warm == "full" else warm
        if self.warm_start != expected:
            raise ValueError(f"variant {warm}: the scene's physics.warm_start must be {expected!r}")

    def predict_advection(self, model, state) -> None:
        super().predict_advection(model, state)  # the scene's start (0.5 p(t - dt) for "full")
        if self.warm == "full":
            launch_particles(scale_pressure, state.n, [2.0, state.p], model.device)
        if self.coarse is not None:
            self.coarse.bin(state.x, state.n)

    def launch_step(self, model, state, timer=None, sync: bool = True) -> None:
        if self.scheme == "jacobi":
            return super().launch_step(model, state, timer, sync)
        self.run_scheme = {
            "bb": self.bb_solve,
            "cg": self.cg_solve,
            "chebyshev": self.chebyshev_solve,
            "twolevel": self.twolevel_iteration,
        }[self.scheme]
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

    def twolevel_iteration(self, model, state) -> None:
        """Relaxed Jacobi's update plus the coarse correction of its residual."""
        nf, nb = self.search.fluid.lists, self.search.boundary.lists
        n, dev, walls, c = state.n, model.device, self.walls.walls, self.coarse
        common = [self.fluid, nf, nb, walls, self.terms, state.rho, state.p]
        launch_particles(pressure_sum_dij_pj, n, common, dev)
        c.grid.r.zero_()
        launch_particles(
            pressure_jacobi_residual,
            n,
            [*common, float(self.physics.omega), self.a_least, c.cell, c.grid, self.e, self.p_next, self.solve.error],
            dev,
        )
        wp.launch(
            coarse_solve,
            dim=1,
            inputs=[c.grid, self.dt, float(self.physics.rho0), COARSE_SWEEPS, COARSE_SOR],
            device=dev,
        )
        launch_particles(coarse_prolong, n, [state.x, c.grid, self.z], dev)
        if COARSE_LINE_SEARCH:
            self.pressure_change(model, state, self.z, 1, self.q)  # q = A z: one more operator pass
            launch_particles(correction_terms, n, [self.e, self.q, state.p, self.z, self.t_a, self.t_b], dev)
            sum_into(self.t_a, n, self.s_a)
            sum_into(self.t_b, n, self.s_b)
        else:
            self.s_a.fill_(1.0)
            self.s_b.fill_(1.0)
        launch_particles(add_correction, n, [self.s_a, self.s_b, COARSE_DAMPING, self.z, self.p_next], dev)

    def no_blend(self, dev) -> wp.array:
        if not hasattr(self, "_no_blend"):
            self._no_blend = wp.full(1, -1.0, dtype=float, device=dev)
        return self._no_blend

    def integrate(self, model, state, walls) -> None:
        if self.scheme == "cg":
            launch_particles(clamp_pressure, state.n, [state.p], model.device)
        super().integrate(model, state, walls)


# --- two-level: relaxed Jacobi plus a coarse correction on a grid of cells (scheme "twolevel") ---

COARSE_CELLS = 4  # spacings per coarse cell (about; each axis fitted to the tank's extent)
COARSE_SWEEPS = 60  # SOR sweeps of the coarse Poisson problem per iteration
COARSE_SOR = 1.6
COARSE_DAMPING = 1.0
COARSE_LINE_SEARCH = 1  # scale each correction by the residual's least-squares share along A z
FLUID = wp.constant(1)
SOLID = wp.constant(2)


@wp.struct
class CoarseGrid:
    """Cells over the tank: ``kind`` 1 liquid, 0 air (pressure zero at the surface, placed by the
    fill fractions), 2 solid (mirrored); ``fill`` particles per cell over a full cell's count;
    ``r`` the restricted residual (rho0 - rho_pred) / rho0; ``e`` the coarse pressure correction."""

    lower: wp.vec3
    size: wp.vec3
    dims: wp.vec3i
    full: float
    fill: wp.array(dtype=float)
    walls: wp.array(dtype=float)
    kind: wp.array(dtype=int)
    r: wp.array(dtype=float)
    e: wp.array(dtype=float)


@wp.func
def cell_coords(g: CoarseGrid, x: wp.vec3) -> wp.vec3i:
    return wp.vec3i(
        wp.clamp(int(wp.floor((x[0] - g.lower[0]) / g.size[0])), 0, g.dims[0] - 1),
        wp.clamp(int(wp.floor((x[1] - g.lower[1]) / g.size[1])), 0, g.dims[1] - 1),
        wp.clamp(int(wp.floor((x[2] - g.lower[2]) / g.size[2])), 0, g.dims[2] - 1),
    )


@wp.func
def cell_index(g: CoarseGrid, c: wp.vec3i) -> int:
    return (c[0] * g.dims[1] + c[1]) * g.dims[2] + c[2]


@wp.kernel
def coarse_bin_fluid(offset: int, x: wp.array(dtype=wp.vec3), g: CoarseGrid, cell: wp.array(dtype=int)):
    i = wp.tid() + offset
    c = cell_index(g, cell_coords(g, x[i]))
    cell[i] = c
    wp.atomic_add(g.fill, c, 1.0 / g.full)


@wp.kernel
def coarse_bin_walls(xb: wp.array(dtype=wp.vec3), g: CoarseGrid):
    b = wp.tid()
    x = xb[b]
    for k in range(3):
        if x[k] < g.lower[k] or x[k] > g.lower[k] + g.size[k] * float(g.dims[k]):
            return
    wp.atomic_add(g.walls, cell_index(g, cell_coords(g, x)), 1.0)


@wp.kernel
def coarse_classify(g: CoarseGrid):
    c = wp.tid()
    k = int(0)
    if g.fill[c] >= 0.5:
        k = FLUID
    elif g.walls[c] > 0.0:
        k = SOLID
    g.kind[c] = k


@wp.kernel
def pressure_jacobi_residual(
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
    cell: wp.array(dtype=int),
    g: CoarseGrid,
    res: wp.array(dtype=float),
    p_new: wp.array(dtype=float),
    density_error: wp.array(dtype=wp.float64),
):
    """The package's Jacobi update (pressure_jacobi), and the residual ``rho0 - rho_pred`` of the
    active particles (pressed or compressed; zero for the others) into ``res`` and, as a fraction
    of rho0, summed into their cells."""
    i = wp.tid() + offset
    p_i = p[i]
    sigma = jacobi_sigma(i, fluid, nf, nb, walls, iisph, rho, p)
    a = iisph.a_ii[i]
    dt = fluid.dt[0]
    jacobi_update(
        i, sigma, p_i, a, iisph.a_diag[i], iisph.rho_adv[i], fluid.rho0, omega, a_least * dt * dt, p_new, density_error
    )
    rho_pred = iisph.rho_adv[i] + a * p_i + sigma
    r = float(0.0)
    if p_i > 0.0 or rho_pred > fluid.rho0:
        r = fluid.rho0 - rho_pred
        wp.atomic_add(g.r, cell[i], r / fluid.rho0 / g.full)
    res[i] = r


@wp.func
def face_weight(g: CoarseGrid, f_c: float, nbr: int, axis: int) -> wp.vec2:
    """(weight on the neighbour's e, weight on the cell's own e) of one face's Laplacian term."""
    inv = 1.0 / (g.size[axis] * g.size[axis])
    if nbr < 0:
        return wp.vec2(0.0, 0.0)  # outside the grid: a wall, mirrored
    k = g.kind[nbr]
    if k == FLUID:
        return wp.vec2(inv, inv)
    if k == SOLID:
        return wp.vec2(0.0, 0.0)
    theta = wp.clamp(wp.min(f_c, 1.0) - 0.5 + g.fill[nbr], 0.25, 1.0)  # the surface's distance, in cells
    return wp.vec2(0.0, inv / theta)


@wp.func
def neighbour_cell(g: CoarseGrid, c: wp.vec3i, axis: int, side: int) -> int:
    n = wp.vec3i(
        c[0] + wp.where(axis == 0, side, 0), c[1] + wp.where(axis == 1, side, 0), c[2] + wp.where(axis == 2, side, 0)
    )
    if n[axis] < 0 or n[axis] >= g.dims[axis]:
        return -1
    return cell_index(g, n)


@wp.kernel
def coarse_solve(g: CoarseGrid, dt: wp.array(dtype=float), rho0: float, sweeps: int, w: float):
    """SOR sweeps (one thread) of ``dt^2 lap(e) = rho0 r`` over the liquid cells, from ``e = 0``:
    the 7-point Laplacian, ``e`` mirrored at walls and zero at the free surface, placed between a
    cell and its air neighbour by their fill fractions (ghost fluid, clamped to a quarter cell)."""
    n = g.dims[0] * g.dims[1] * g.dims[2]
    dt2 = dt[0] * dt[0]
    for c in range(n):
        g.e[c] = 0.0
    for _s in range(sweeps):
        for ix in range(g.dims[0]):
            for iy in range(g.dims[1]):
                for iz in range(g.dims[2]):
                    cc = wp.vec3i(ix, iy, iz)
                    c = cell_index(g, cc)
                    if g.kind[c] == FLUID:
                        off = float(0.0)
                        diag = float(0.0)
                        air = float(0.0)
                        f_c = g.fill[c]
                        for axis in range(3):
                            for s in range(2):
                                nbr = neighbour_cell(g, cc, axis, 2 * s - 1)
                                fw = face_weight(g, f_c, nbr, axis)
                                if fw[0] > 0.0:
                                    off += fw[0] * g.e[nbr]
                                    diag += fw[1]
                                else:
                                    air += fw[1]
                        a_ii = -dt2 * (air + diag)
                        if a_ii < 0.0:
                            e_new = (rho0 * g.r[c] - dt2 * off) / a_ii
                            g.e[c] = (1.0 - w) * g.e[c] + w * e_new


@wp.func
def coarse_value(g: CoarseGrid, c: wp.vec3i, own: float) -> float:
    """The correction at a cell centre for interpolation: past the grid's faces the nearest cell's
    (mirrored walls), zero in air, ``own`` (the particle's cell's) in a solid cell."""
    cc = wp.vec3i(wp.clamp(c[0], 0, g.dims[0] - 1), wp.clamp(c[1], 0, g.dims[1] - 1), wp.clamp(c[2], 0, g.dims[2] - 1))
    idx = cell_index(g, cc)
    kind = g.kind[idx]
    if kind == FLUID:
        return g.e[idx]
    if kind == SOLID:
        return own
    return 0.0


@wp.kernel
def coarse_prolong(offset: int, x: wp.array(dtype=wp.vec3), g: CoarseGrid, z: wp.array(dtype=float)):
    """``z = e(x_i)``, ``e`` interpolated trilinearly between cell centres."""
    i = wp.tid() + offset
    x_i = x[i]
    u = wp.vec3(0.0)
    base = wp.vec3i(0, 0, 0)
    for k in range(3):
        s = (x_i[k] - g.lower[k]) / g.size[k] - 0.5
        b = int(wp.floor(s))
        base[k] = b
        u[k] = s - float(b)
    own_c = cell_coords(g, x_i)
    own = coarse_value(g, own_c, 0.0)
    v = float(0.0)
    for dx in range(2):
        for dy in range(2):
            for dz in range(2):
                wgt = (
                    wp.where(dx == 1, u[0], 1.0 - u[0])
                    * wp.where(dy == 1, u[1], 1.0 - u[1])
                    * wp.where(dz == 1, u[2], 1.0 - u[2])
                )
                v += wgt * coarse_value(g, wp.vec3i(base[0] + dx, base[1] + dy, base[2] + dz), own)
    z[i] = v


@wp.kernel
def correction_terms(
    offset: int,
    res: wp.array(dtype=float),
    q: wp.array(dtype=float),
    p: wp.array(dtype=float),
    z: wp.array(dtype=float),
    t_rq: wp.array(dtype=wp.float64),
    t_qq: wp.array(dtype=wp.float64),
):
    """Over the active particles (pressed, compressed or given a correction): ``r . q`` and
    ``q . q``, ``q = A z`` the density change the correction gives."""
    i = wp.tid() + offset
    active = res[i] != 0.0 or p[i] > 0.0 or z[i] > 0.0
    q_i = wp.where(active, q[i], 0.0)
    t_rq[i] = wp.float64(res[i]) * wp.float64(q_i)
    t_qq[i] = wp.float64(q_i) * wp.float64(q_i)


@wp.kernel
def add_correction(
    offset: int,
    rq: wp.array(dtype=wp.float64),
    qq: wp.array(dtype=wp.float64),
    damping: float,
    z: wp.array(dtype=float),
    p_new: wp.array(dtype=float),
):
    """``p_new += alpha z``, ``alpha = damping (r . q) / (q . q)`` (the residual's least-squares
    share along the correction's response), clamped at zero."""
    i = wp.tid() + offset
    alpha = float(0.0)
    if qq[0] > wp.float64(0.0):
        alpha = damping * float(rq[0] / qq[0])
    p_new[i] = wp.max(p_new[i] + alpha * z[i], 0.0)


class CoarseCorrection:
    """The coarse grid of a model and the launches of one correction."""

    def __init__(self, model, cells: float = COARSE_CELLS):
        h = float(model.spacing)
        lo = [float(v) + 0.5 * h for v in model.domain_lower]  # the box tank's faces
        hi = [float(v) - 0.5 * h for v in model.domain_upper]
        dims = [max(1, round((hi[k] - lo[k]) / (cells * h))) for k in range(3)]
        size = [(hi[k] - lo[k]) / dims[k] for k in range(3)]
        n = dims[0] * dims[1] * dims[2]
        g = CoarseGrid()
        g.lower, g.size, g.dims = wp.vec3(*lo), wp.vec3(*size), wp.vec3i(*dims)
        g.full = float(size[0] * size[1] * size[2] / h**3)
        dev = model.device
        g.fill, g.walls, g.r, g.e = (wp.zeros(n, dtype=float, device=dev) for _ in range(4))
        g.kind = wp.zeros(n, dtype=int, device=dev)
        self.grid, self.n_cells, self.device = g, n, dev
        self.cell = wp.zeros(model.capacity, dtype=int, device=dev)
        self.boundary_x = model.boundary_x

    def bin(self, x, n: int) -> None:
        g = self.grid
        g.fill.zero_()
        g.walls.zero_()
        launch_particles(coarse_bin_fluid, n, [x, g, self.cell], self.device)
        wp.launch(coarse_bin_walls, dim=self.boundary_x.shape[0], inputs=[self.boundary_x, g], device=self.device)
        wp.launch(coarse_classify, dim=self.n_cells, inputs=[g], device=self.device)
