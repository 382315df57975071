"""Non-pressure forces: gravity and the report's viscosity, as accelerations.

Viscosity (IGR205 report, after Monaghan): ``F_i = 2 mu m_i sum_j (m_j / rho_j)
(v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij`` with ``mu`` in m^2/s. With ``mu = 0`` the
neighbour loop is skipped entirely: the acceleration is gravity alone.

Wall friction (Akinci et al. 2012) uses the same form against the boundary particles (moving with
their obstacle's velocity ``v_b``), ``a_i += 2 mu_b sum_b (psi_b / rho_i) ((v_i - v_b) . x_ib) /
(|x_ib|^2 + 0.01 h^2) grad W_ib``, with its own
coefficient ``mu_b`` (m^2/s); 0 (the default) keeps the walls free-slip and costs nothing.
"""

import warp as wp

from ..neighbors import NeighborList, entry


@wp.func
def viscous_pair(v_ij: wp.vec3, x_ij: wp.vec3, h: float, grad_W: wp.vec3) -> wp.vec3:
    """The report's pair term ``(v_ij . x_ij) / (|x_ij|^2 + 0.01 h^2) grad W_ij``."""
    return wp.dot(v_ij, x_ij) / (wp.dot(x_ij, x_ij) + 0.01 * h * h) * grad_W


@wp.func
def non_pressure_acceleration(
    i: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    nf: NeighborList,
    mass: float,
    viscosity: float,
    h: float,
    gravity: wp.vec3,
    xb: wp.array(dtype=wp.vec3),
    vb: wp.array(dtype=wp.vec3),
    psi: wp.array(dtype=float),
    nb: NeighborList,
    boundary_viscosity: float,
) -> wp.vec3:
    a = gravity
    if viscosity > 0.0:
        x_i = x[i]
        v_i = v[i]
        visc = wp.vec3(0.0, 0.0, 0.0)
        for m in range(nf.count[i]):
            k = entry(nf, i, m)
            j = nf.index[k]
            visc += (mass / rho[j]) * viscous_pair(v_i - v[j], x_i - x[j], h, nf.grad_W[k])
        a = a + 2.0 * viscosity * visc
    if boundary_viscosity > 0.0:
        x_i = x[i]
        v_i = v[i]
        fric = wp.vec3(0.0, 0.0, 0.0)
        for m in range(nb.count[i]):
            k = entry(nb, i, m)
            b = nb.index[k]
            fric += (psi[b] / rho[i]) * viscous_pair(v_i - vb[b], x_i - xb[b], h, nb.grad_W[k])
        a = a + 2.0 * boundary_viscosity * fric
    return a


@wp.kernel
def predict_velocity(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    nf: NeighborList,
    mass: float,
    viscosity: float,
    h: float,
    gravity: wp.vec3,
    xb: wp.array(dtype=wp.vec3),
    vb: wp.array(dtype=wp.vec3),
    psi: wp.array(dtype=float),
    nb: NeighborList,
    boundary_viscosity: float,
    dt_step: wp.array(dtype=float),
    v_adv: wp.array(dtype=wp.vec3),
):
    """v_adv = v + dt * (gravity + viscosity): the velocity before pressure acts."""
    i = wp.tid() + offset
    dt = dt_step[0]
    v_adv[i] = v[i] + dt * non_pressure_acceleration(i, x, v, rho, nf, mass, viscosity, h, gravity, xb, vb, psi, nb, boundary_viscosity)
