"""Weakly compressible SPH (Becker & Teschner 2007), the baseline IISPH is measured against.

Pressure from the state equation ``p = k ((rho/rho0)^7 - 1)``, clamped at 0 (no tensile
pressure at the free surface), then the shared pressure acceleration and symplectic Euler.
Its time step is bounded by the speed of sound ``c = sqrt(7 k / rho0)``.
"""

from __future__ import annotations

import math
from contextlib import nullcontext

import warp as wp

from ...engine.launch import launch_particles
from ..wall_pressure import WallPressures
from .base import SPHSolver

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.kernel
def state_equation(offset: int, rho: wp.array(dtype=float), rho0: float, stiffness: float, p: wp.array(dtype=float)):
    i = wp.tid() + offset
    ratio = rho[i] / rho0
    r2 = ratio * ratio
    p[i] = wp.max(stiffness * (r2 * r2 * r2 * ratio - 1.0), 0.0)


class WCSPHSolver(SPHSolver):
    """Weakly compressible SPH. ``density_error`` in its statistics is the mean compression
    ``max(rho/rho0 - 1, 0)`` at the start of the step (there is no solver to converge)."""

    def __init__(self, model):
        super().__init__(model)
        self.walls = WallPressures(model, model.capacity)

    @property
    def signal_speed(self) -> float:
        return math.sqrt(7.0 * self.physics.stiffness / self.physics.rho0)

    def launch_step(self, model, state, timer=None, sync: bool = True) -> None:
        """One WCSPH step: densities, the state equation's pressure, forces, symplectic Euler."""
        timer = timer or nullcontext
        ph = self.physics
        with timer("neighbours"):
            nf, nb = self.find_neighbours(state, sync)
        with timer("density"):
            self.compute_densities(model, state)
            self.walls.prepare(model, state, nf, nb)
        with timer("advection"):
            self.advect_velocity(model, state)
        with timer("pressure"):
            launch_particles(state_equation, state.n, [state.rho, ph.rho0, float(ph.stiffness), state.p], model.device)
        with timer("integration"):
            self.integrate(model, state, self.walls)
