"""The pressure a boundary particle pushes with: the fluid's pressure extrapolated into the wall,
in the manner of Adami, Hu & Adams (2012, J. Comput. Phys. 231), centred on the fluid particle it
pushes.

Akinci et al.'s walls push fluid particle i with ``psi_b p_i / rho_i^2 grad W_ib``: the fluid
particle's own pressure, in one term of the symmetric force where a fluid neighbour contributes two
(``p_i / rho_i^2 + p_j / rho_j^2``). To hold the fluid above it, the layer touching a wall then
carries about twice the hydrostatic pressure, and along a floor that layer is pushed hardest and
runs ahead. Here wall particle b is a neighbour with a pressure of its own, ``-psi_b (p_i / rho_i^2
+ p_b / rho0^2) grad W_ib``, where

    p_b = max(0, p~_i + rho_i (g - a_b) . (x_b - x~_i))

is the pressure at i, smoothed over i's neighbourhood (``p~_i = sum_j W_ij p_j / sum_j W_ij``,
i included, centred at ``x~_i = sum_j W_ij x_j / sum_j W_ij``), continued into the wall with the
hydrostatic (and, for a moving obstacle, inertial) gradient the momentum equation gives at a wall:
``grad p = rho (g - a_b)``. For a hydrostatic field it is exact. It is never negative (a wall
does not pull).

Smoothing over i's neighbourhood keeps a single over-compressed particle from doubling its walls'
push; the alternatives measured (Adami's own Shepard form, the unsmoothed p_i) are in
docs/physics.md 4.6.

IISPH treats p_b like a neighbour's pressure: it enters ``sum_j d_ij p_j`` from the iteration's
pressures (so the predicted density, and the convergence test, are those of the iterate), and
the Jacobi step divides by the system's true diagonal, which includes the share p_i has in the
walls' pressures of i and its neighbours (:mod:`.solvers.iisph`).
"""

from __future__ import annotations

import warp as wp

from ..engine.launch import launch_particles
from .kernel import cubic_W_np
from .neighbors import NeighborList, entry
from .wall_gradient import gradient_factor, regularisation

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.struct
class Walls:
    """The boundary particles as the fluid's kernels see them."""

    psi: wp.array(dtype=float)  # Akinci's psi: each boundary particle's volume times rho0 (kg)
    v: wp.array(dtype=wp.vec3)  # their velocities (zero for still walls)
    # 1/rho0^2 where they push with the fluid's pressure extrapolated into them, 0 with Akinci's
    # walls (whose term is the fluid particle's own pressure)
    pressure_factor: float
    weight: wp.array(dtype=float)  # sum_j W_ij (i included) of each fluid particle near walls
    W0: float  # W(0): a particle's own weight in that sum
    # s_i: the factor on fluid particle i's walls' gradients in the forces on it (1 where they are
    # Akinci's as they are; :mod:`.wall_gradient`), written each step for particles near walls
    gradient_scale: wp.array(dtype=float)


@wp.func
def smoothed_pressure(i: int, p: wp.array(dtype=float), p_sum: float, walls: Walls) -> float:
    """``p~_i`` from ``p_sum = sum_j W_ij p_j`` over i's neighbours (i itself added here)."""
    return (walls.W0 * p[i] + p_sum) / walls.weight[i]


@wp.kernel
def wall_heads(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    xb: wp.array(dtype=wp.vec3),
    ab: wp.array(dtype=wp.vec3),
    gravity: wp.vec3,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    complete: int,
    mass: float,
    rho0: float,
    regularisation: float,
):
    """For a fluid particle i near a wall, once per step: ``sum_j W_ij`` (i included), the centre
    ``x~_i`` of its neighbourhood, where its smoothed pressure sits, and for each wall neighbour b
    the head ``rho_i (g - a_b) . (x_b - x~_i)`` (stored in the list entry), so that a wall's pressure
    is ``max(p~_i + head, 0)``; with ``complete``, in the same passes over its lists, the factor
    ``s_i`` on its walls' gradient (:mod:`.wall_gradient`) into ``walls.gradient_scale``."""
    i = wp.tid() + offset
    if nb.count[i] == 0:
        return
    x_i = x[i]
    W0 = walls.W0
    s = W0
    c = W0 * x_i
    g_f = wp.vec3(0.0, 0.0, 0.0)
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        w = nf.W[k]
        s += w
        c += w * x[nf.index[k]]
        if complete != 0:
            g_f += nf.grad_W[k]
    c = c / s
    walls.weight[i] = s
    rho_i = rho[i]
    g_b = wp.vec3(0.0, 0.0, 0.0)
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        b = nb.index[k]
        nb.head[k] = rho_i * wp.dot(gravity - ab[b], xb[b] - c)
        if complete != 0:
            g_b += walls.psi[b] * nb.grad_W[k]
    if complete != 0:
        walls.gradient_scale[i] = gradient_factor(mass * g_f, g_b, rho_i, rho0, regularisation)


class WallPressures:
    """The walls' pressures a method's pressure force and solve use: extrapolated
    (``physics.wall_pressure = "extrapolated"``, with boundary particles) or Akinci's (the fluid
    particle's own, in one term); with extrapolated pressures, walls that complete the fluid's
    kernel gradient (``physics.wall_gradient = "completed"``, :mod:`.wall_gradient`). ``walls``
    is what the kernels take (:class:`Walls`)."""

    def __init__(self, model, capacity: int):
        ph = model.physics
        self.extrapolated = ph.wall_pressure == "extrapolated" and model.n_boundary > 0
        # the rule run.json's ``resolved`` states (Physics.resolved), with walls to complete
        self.completed = self.extrapolated and ph.resolved(model.rigid is not None)["wall_gradient"] == "completed"
        self.walls = walls_of(model, 1.0 / (ph.rho0 * ph.rho0) if self.extrapolated else 0.0, capacity)
        self.gravity = wp.vec3(*ph.gravity)

    def prepare(self, model, state, nf: NeighborList, nb: NeighborList) -> None:
        """Once per step, after densities: each wall entry's hydrostatic head and, with completed
        walls, each particle's factor on its walls' gradient (nothing with Akinci's walls)."""
        if self.extrapolated:
            launch_particles(
                wall_heads,
                state.n,
                [
                    *(state.x, state.rho, model.boundary_x, model.boundary_a, self.gravity, nf, nb, self.walls),
                    *(int(self.completed), model.mass, float(model.physics.rho0), regularisation(model)),
                ],
                model.device,
            )


def walls_of(model, pressure_factor: float = 0.0, capacity: int = 1) -> Walls:
    """The :class:`Walls` of ``model`` (``capacity``: fluid particles the smoothing weights serve)."""
    walls = Walls()
    walls.psi, walls.v = model.boundary_psi, model.boundary_v
    walls.pressure_factor = pressure_factor
    walls.weight = wp.ones(max(capacity, 1), dtype=float, device=model.device)
    walls.gradient_scale = wp.ones(max(capacity, 1), dtype=float, device=model.device)
    walls.W0 = float(cubic_W_np(0.0, model.support_radius))
    return walls
