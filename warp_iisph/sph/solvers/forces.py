"""Non-pressure forces: gravity and the report's viscosity, as accelerations.

Viscosity (IGR205 report, after Monaghan): ``F_i = 2 mu m_i sum_j (m_j / rho_j)
(v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij`` with ``mu`` in m^2/s. With ``mu = 0`` the
neighbour loop is skipped entirely: the acceleration is gravity alone.

Wall friction (Akinci et al. 2012) uses the same form against the boundary particles (moving with
their obstacle's velocity ``v_b``), ``a_i += 2 mu_b sum_b (psi_b / rho_i) ((v_i - v_b) . x_ib) /
(|x_ib|^2 + 0.01 h^2) grad W_ib``, with its own
coefficient ``mu_b`` (m^2/s); 0 (the default) keeps the walls free-slip and costs nothing.

Being explicit, the viscosity is stable only for steps up to ``0.4 h^2 / mu``
(:func:`viscous_dt_limit`), which falls below the flow's own step (CFL) at fine spacings (at
the default ``mu``, below about 2 cm). A longer step applies it in ``n`` equal sub-steps of
``dt / n`` within that limit, on the step's neighbour lists (:class:`ViscousSubsteps`): the
pressure solve and the neighbour search run once per step, each viscous sub-step costs one pass
over the fluid lists. A step within the limit is one pass, as before.
"""

import math

import warp as wp

from ...engine.launch import launch_particles
from ..neighbors import NeighborList, entry

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

# the explicit viscosity's step limit, in h^2 / mu (see viscous_dt_limit)
VISCOUS_DT_FACTOR = 0.4


def viscous_dt_limit(h: float, physics) -> float:
    """Largest step the explicit viscosity is stable with, ``0.4 h^2 / mu`` (wall friction has the
    same form). Explicit Euler on ``dv/dt = -K v`` needs ``dt < 2 / lambda_max(K)``: on a lattice
    of spacing h (cubic spline, support 2h, the report's form with its 0.01 h^2) the largest
    eigenvalue, over all wave vectors, is ``2.92 mu / h^2``, i.e. ``dt < 0.685 h^2 / mu`` (Morris et
    al. 1997's ``0.125 h^2 / nu`` with ``nu = mu / 5`` gives 0.625). Settled, disordered particles
    go unstable earlier: the Martin & Moyce column at a/h = 30 blew up in its viscosity (compression
    of several per cent with no pressure) at 0.56 h^2 / mu and ran clean at 0.50; 0.4 keeps a
    quarter of margin below that. Infinite without viscosity."""
    mu = max(physics.viscosity, physics.boundary_viscosity)
    return math.inf if mu <= 0.0 else VISCOUS_DT_FACTOR * h * h / mu


@wp.func
def viscous_substep_count(dt: float, limit: float, most: int) -> int:
    """How many equal sub-steps within ``limit`` the viscosity takes over ``dt`` (at most ``most``)."""
    n = int(1)
    if dt > limit:
        n = wp.min(int(wp.ceil(dt / limit - 1.0e-5)), most)
    return wp.max(n, 1)


@wp.func
def viscous_pair(v_ij: wp.vec3, x_ij: wp.vec3, h: float, grad_W: wp.vec3) -> wp.vec3:
    """The report's pair term ``(v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij``."""
    return wp.dot(v_ij, x_ij) / (wp.dot(x_ij, x_ij) + 0.01 * h * h) * grad_W


@wp.struct
class ViscousTerms:
    """What the viscosity and wall friction need besides the particles' own state: the particle
    mass and spacing, both coefficients (m^2/s), the walls (positions, velocities, psi) and the
    step limit with the most sub-steps a step may take (:class:`ViscousSubsteps`)."""

    mass: float
    h: float
    viscosity: float
    boundary_viscosity: float
    xb: wp.array(dtype=wp.vec3)
    vb: wp.array(dtype=wp.vec3)
    psi: wp.array(dtype=float)
    limit: float
    most: int


@wp.func
def non_pressure_acceleration(
    i: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    nf: NeighborList,
    nb: NeighborList,
    terms: ViscousTerms,
    gravity: wp.vec3,
) -> wp.vec3:
    a = gravity
    h = terms.h
    if terms.viscosity > 0.0:
        x_i = x[i]
        v_i = v[i]
        visc = wp.vec3(0.0, 0.0, 0.0)
        for m in range(nf.count[i]):
            k = entry(nf, i, m)
            j = nf.index[k]
            visc += (terms.mass / rho[j]) * viscous_pair(v_i - v[j], x_i - x[j], h, nf.grad_W[k])
        a = a + 2.0 * terms.viscosity * visc
    if terms.boundary_viscosity > 0.0:
        x_i = x[i]
        v_i = v[i]
        fric = wp.vec3(0.0, 0.0, 0.0)
        for m in range(nb.count[i]):
            k = entry(nb, i, m)
            b = nb.index[k]
            fric += (terms.psi[b] / rho[i]) * viscous_pair(v_i - terms.vb[b], x_i - terms.xb[b], h, nb.grad_W[k])
        a = a + 2.0 * terms.boundary_viscosity * fric
    return a


@wp.kernel
def predict_velocity(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    nf: NeighborList,
    nb: NeighborList,
    terms: ViscousTerms,
    gravity: wp.vec3,
    dt_step: wp.array(dtype=float),
    v_adv: wp.array(dtype=wp.vec3),
):
    """v_adv = v + dt * (gravity + viscosity): the velocity before pressure acts (the first of the
    viscosity's sub-steps where the step is longer than its limit)."""
    i = wp.tid() + offset
    v_adv[i] = advected_velocity(i, x, v, rho, nf, nb, terms, gravity, dt_step[0])


@wp.func
def advected_velocity(
    i: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    nf: NeighborList,
    nb: NeighborList,
    terms: ViscousTerms,
    gravity: wp.vec3,
    dt: float,
) -> wp.vec3:
    """``v + dt (g + a_visc)``, or with ``n`` viscous sub-steps ``v + dt g + (dt / n) a_visc``
    (the first of them; :func:`viscous_substep` takes the others)."""
    n = viscous_substep_count(dt, terms.limit, terms.most)
    if n == 1:
        return v[i] + dt * non_pressure_acceleration(i, x, v, rho, nf, nb, terms, gravity)
    a_visc = non_pressure_acceleration(i, x, v, rho, nf, nb, terms, wp.vec3(0.0, 0.0, 0.0))
    return v[i] + dt * gravity + (dt / float(n)) * a_visc


@wp.kernel
def viscous_substep(
    offset: int,
    k: int,
    x: wp.array(dtype=wp.vec3),
    v_in: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    nf: NeighborList,
    nb: NeighborList,
    terms: ViscousTerms,
    dt_step: wp.array(dtype=float),
    v_out: wp.array(dtype=wp.vec3),
):
    """Viscous sub-step ``k`` (from 1) of the step: ``v += (dt / n) a_visc(v)`` if the step has
    more than ``k`` of them, else the velocity passed on unchanged."""
    i = wp.tid() + offset
    dt = dt_step[0]
    n = viscous_substep_count(dt, terms.limit, terms.most)
    if k < n:
        a = non_pressure_acceleration(i, x, v_in, rho, nf, nb, terms, wp.vec3(0.0, 0.0, 0.0))
        v_out[i] = v_in[i] + (dt / float(n)) * a
    else:
        v_out[i] = v_in[i]


class ViscousSubsteps:
    """The viscosity's sub-steps after the first: a fixed number of launches per step (graph-safe),
    as many as the longest step the run may take needs (the fixed dt, else dt_max); each does its
    sub-step, or passes the velocity on where this step needs fewer. ``terms`` is what every
    kernel computing the viscosity takes (:class:`ViscousTerms`)."""

    def __init__(self, model, capacity: int):
        ph = model.physics
        self.limit = viscous_dt_limit(model.spacing, ph)
        longest = ph.dt if ph.dt is not None else ph.dt_max
        self.most = 1 if not math.isfinite(self.limit) else max(1, math.ceil(longest / self.limit - 1.0e-5))
        self.scratch = wp.zeros(max(capacity, 1), dtype=wp.vec3, device=model.device) if self.most > 1 else None
        terms = ViscousTerms()
        terms.mass, terms.h = model.mass, model.spacing
        terms.viscosity, terms.boundary_viscosity = ph.viscosity, ph.boundary_viscosity
        terms.xb, terms.vb, terms.psi = model.boundary_x, model.boundary_v, model.boundary_psi
        terms.limit = min(self.limit, 1.0e30)  # float32 for the kernels
        terms.most = self.most
        self.terms = terms
        # each called as observer(k, state, v_in) with each sub-step's input velocities before it is
        # taken (0: the step's own): sums of the wall friction (sph/wall_forces.py)
        self.observers = []

    def run(self, model, state, nf, nb, dt_step: wp.array, v_adv: wp.array) -> None:
        """Sub-steps 1 .. most - 1 on ``v_adv`` (which holds sub-step 0's result and ends with the last)."""
        for observe in self.observers:
            observe(0, state, state.v)
        if self.most == 1:
            return
        src, dst = v_adv, self.scratch
        for k in range(1, self.most):
            for observe in self.observers:
                observe(k, state, src)
            launch_particles(
                viscous_substep, state.n, [k, state.x, src, state.rho, nf, nb, self.terms, dt_step, dst], model.device
            )
            src, dst = dst, src
        if src is not v_adv:
            wp.copy(v_adv, src, count=state.n)
