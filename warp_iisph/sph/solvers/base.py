"""The services every method's step uses: neighbours, density, the advected velocity, and (for
WCSPH and IISPH) the pressure acceleration with symplectic Euler.

Density (Akinci boundaries): ``rho_i = sum_j m W_ij + sum_b psi_b W_ib`` (j includes i).
Pressure acceleration: ``a_i = -sum_j m (p_i/rho_i^2 + p_j/rho_j^2) grad W_ij
- sum_b psi_b (p_i/rho_i^2 + p_b/rho0^2) grad W_ib``: a wall particle is a neighbour with its own
pressure ``p_b``, the fluid's pressure extrapolated into the wall (:mod:`..wall_pressure`,
``physics.wall_pressure = "extrapolated"``). With ``"fluid"`` the wall term is Akinci et al.'s
``psi_b (p_i/rho_i^2) grad W_ib`` (the fluid particle's own pressure, one term), with which the
fluid touching a wall carries about twice the hydrostatic pressure.

Neighbour lists store ``W`` beside ``grad W``; densities are summed from them.
"""

from __future__ import annotations

import warp as wp

from ...engine.launch import launch_particles
from ...engine.reduce import sum_into
from ..kernel import cubic_W
from ..neighbors import NeighborList, NeighborSearch, entry
from ..wall_pressure import WallPressures, Walls, smoothed_pressure
from .forces import ViscousSubsteps, predict_velocity

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

STAGES = ("neighbours", "density", "advection", "pressure", "integration")


@wp.struct
class Fluid:
    """What a step's fluid kernels read besides the particles' arrays."""

    mass: float  # each fluid particle's mass (kg)
    rho0: float  # rest density (kg/m^3)
    dt: wp.array(dtype=float)  # the step's length (s), on the device


@wp.kernel
def compute_density(
    offset: int,
    psi: wp.array(dtype=float),
    nf: NeighborList,
    nb: NeighborList,
    mass: float,
    H: float,
    rho0: float,
    rho: wp.array(dtype=float),
    compression: wp.array(dtype=wp.float64),
):
    """Density of fluid particle i from the W its lists hold, and its compression max(rho/rho0 - 1, 0)."""
    i = wp.tid() + offset
    r = mass * cubic_W(0.0, H)
    for m in range(nf.count[i]):
        r += mass * nf.W[entry(nf, i, m)]
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        r += psi[nb.index[k]] * nb.W[k]
    rho[i] = r
    compression[i] = wp.max(wp.float64(r / rho0) - wp.float64(1.0), wp.float64(0.0))


@wp.kernel
def integrate(
    offset: int,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    v_adv: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    v: wp.array(dtype=wp.vec3),
    x: wp.array(dtype=wp.vec3),
):
    """Pressure acceleration, then symplectic Euler: v = v_adv + dt a_p; x += dt v."""
    i = wp.tid() + offset
    dt = fluid.dt[0]
    mass = fluid.mass
    rho_i = rho[i]
    p_i = p[i] / (rho_i * rho_i)
    a = wp.vec3(0.0, 0.0, 0.0)
    extrapolated = walls.pressure_factor > 0.0 and nb.count[i] > 0
    p_sum = float(0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        j = nf.index[k]
        a -= mass * (p_i + p[j] / (rho[j] * rho[j])) * nf.grad_W[k]
        if extrapolated:
            p_sum += nf.W[k] * p[j]
    p_c = float(0.0)
    s_i = float(1.0)
    if extrapolated:
        p_c = smoothed_pressure(i, p, p_sum, walls)
        s_i = walls.gradient_scale[i]
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        p_b = float(0.0)
        if extrapolated:
            p_b = wp.max(p_c + nb.head[k], 0.0)
        a -= (walls.psi[nb.index[k]] * s_i) * (p_i + walls.pressure_factor * p_b) * nb.grad_W[k]
    v_i = v_adv[i] + dt * a
    v[i] = v_i
    x[i] = x[i] + dt * v_i


class SPHSolver:
    """What every method's step uses, as services: the neighbour search, densities, the advected
    velocity (gravity and viscosity), the pressure force with symplectic Euler, the step's dt on the
    device and the compression statistic. Each method writes its own :meth:`launch_step`, one named
    call per stage of its paper's algorithm (stages as :data:`STAGES`), and reads nothing back
    unless ``sync``: what a graph records. The step's statistics stay on the device
    (:meth:`solver_stats`), where the time loop (``warp_iisph.stepping``) logs them."""

    def __init__(self, model):
        self.physics = model.physics
        self.device = model.device
        n = model.capacity  # arrays for the most particles the liquid holds; launches over its current count
        self.search = NeighborSearch(n, model.boundary_x, model.support_radius, model.device, model.n_still)
        self.v_adv = wp.zeros(n, dtype=wp.vec3, device=model.device)
        self.compression = wp.zeros(n, dtype=wp.float64, device=model.device)
        self._compression_sum = wp.zeros(1, dtype=wp.float64, device=model.device)
        self._no_iterations = wp.zeros(1, dtype=wp.int32, device=model.device)
        self.dt = wp.zeros(1, dtype=float, device=model.device)  # the step, read by the kernels
        self.fluid = Fluid()
        self.fluid.mass, self.fluid.rho0, self.fluid.dt = model.mass, self.physics.rho0, self.dt
        self.viscous = ViscousSubsteps(model, n)  # the viscosity's sub-steps where a step exceeds its limit
        # made once, as the walls' and the probes' are: a vector made each step would have its launch
        # packed anew every step (engine/launch.py)
        self.gravity = wp.vec3(*self.physics.gravity)

    @property
    def signal_speed(self) -> float:
        """Speed of information the time step must resolve besides the flow (m/s)."""
        return 0.0

    def launch_step(self, model, state, timer=None, sync: bool = True) -> None:
        """Every launch of a step (after the reorder, which the time loop schedules); ``self.dt``
        holds the step."""
        raise NotImplementedError

    def solver_stats(self) -> tuple[wp.array, wp.array]:
        """The device sums of the pressure solver's final density error and its iteration count;
        WCSPH has no solver, so its error is the compression."""
        return self._compression_sum, self._no_iterations

    def find_neighbours(self, state, sync: bool) -> tuple[NeighborList, NeighborList]:
        """This step's fluid and boundary neighbour lists."""
        self.search.build(state.x, state.n, sync=sync)
        return self.search.fluid.lists, self.search.boundary.lists

    def compute_densities(self, model, state) -> None:
        """``rho`` from this step's lists, and the compression's sum for the step's statistics."""
        nf, nb = self.search.fluid.lists, self.search.boundary.lists
        launch_particles(
            compute_density,
            state.n,
            [
                model.boundary_psi,
                nf,
                nb,
                model.mass,
                model.support_radius,
                self.physics.rho0,
                state.rho,
                self.compression,
            ],
            model.device,
        )
        sum_into(self.compression, state.n, self._compression_sum)

    def advect_velocity(self, model, state) -> None:
        """``v_adv = v + dt (gravity + viscosity)``, the viscosity in sub-steps where the step
        exceeds its limit: the advection of the methods with no per-particle terms of their own
        to add (WCSPH, DFSPH; IISPH computes d_ii in the same pass)."""
        nf, nb = self.search.fluid.lists, self.search.boundary.lists
        launch_particles(
            predict_velocity,
            state.n,
            [state.x, state.v, state.rho, nf, nb, self.viscous.terms, self.gravity, self.dt, self.v_adv],
            model.device,
        )
        self.viscous.run(model, state, nf, nb, self.dt, self.v_adv)

    def integrate(self, model, state, walls: WallPressures) -> None:
        """The pressure acceleration from ``state.p`` (and the walls' pressures), then symplectic
        Euler from ``v_adv``."""
        nf, nb = self.search.fluid.lists, self.search.boundary.lists
        launch_particles(
            integrate,
            state.n,
            [self.fluid, nf, nb, walls.walls, self.v_adv, state.rho, state.p, state.v, state.x],
            model.device,
        )
