"""The hydrostatic pressure a particle would carry under the liquid above it: ``rho0 |g| d``, ``d``
its depth below the highest particle of its column (columns one spacing wide across gravity,
which points along an axis), half a spacing added for the top particle's own layer. IISPH's
``physics.warm_start = "hydrostatic"`` starts each step's solve from half of it plus half of the
last step's pressure: the half warm start's memory, leaking towards a state function that is the
pressure of resting water instead of towards zero.

A column's height is the largest of its particles' (``wp.atomic_max``: the same on every device
and path, whatever the order); a droplet above the liquid raises its column's estimate, which
the solve then corrects like any other error of the start.
"""

from __future__ import annotations

import warp as wp

from ..engine.launch import launch_particles


@wp.func
def column_of(x_i: wp.vec3, across: wp.vec2i, lower: wp.vec3, h: float, n_columns: wp.vec2i) -> int:
    """The column a point is in (columns ``h`` wide along the two axes ``across`` gravity)."""
    a = wp.clamp(int((x_i[across[0]] - lower[across[0]]) / h), 0, n_columns[0] - 1)
    b = wp.clamp(int((x_i[across[1]] - lower[across[1]]) / h), 0, n_columns[1] - 1)
    return a * n_columns[1] + b


@wp.kernel
def column_tops(
    x: wp.array(dtype=wp.vec3),
    up: int,
    across: wp.vec2i,
    sign: float,
    lower: wp.vec3,
    h: float,
    n_columns: wp.vec2i,
    top: wp.array(dtype=float),
):
    """Each column's highest particle, as a height along ``-g`` (``up``: its axis, ``sign``: its
    direction)."""
    i = wp.tid()
    x_i = x[i]
    wp.atomic_max(top, column_of(x_i, across, lower, h, n_columns), sign * x_i[up])


@wp.kernel
def add_hydrostatic(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    up: int,
    across: wp.vec2i,
    sign: float,
    lower: wp.vec3,
    h: float,
    n_columns: wp.vec2i,
    top: wp.array(dtype=float),
    rho_g: float,
    share: float,
    p: wp.array(dtype=float),
):
    """``p += share rho0 |g| d``, ``d`` the depth below the column's top plus half a spacing."""
    i = wp.tid() + offset
    x_i = x[i]
    depth = top[column_of(x_i, across, lower, h, n_columns)] + 0.5 * h - sign * x_i[up]
    p[i] = p[i] + share * rho_g * wp.max(depth, 0.0)


class HydrostaticPressure:
    """The column heights over ``model``'s domain (allocated once) and the estimate's launches."""

    def __init__(self, model):
        g = tuple(model.physics.gravity)
        up = max(range(3), key=lambda k: abs(g[k]))
        self.up = up
        self.sign = 1.0 if g[up] < 0.0 else -1.0  # heights grow against gravity
        self.rho_g = float(model.physics.rho0 * abs(g[up]))
        across = [k for k in range(3) if k != up]
        self.across = wp.vec2i(*across)
        self.h = float(model.spacing)
        self.lower = wp.vec3(*model.domain_lower)
        span = [float(model.domain_upper[k] - model.domain_lower[k]) for k in across]
        self.n_columns = wp.vec2i(*(int(s / self.h) + 1 for s in span))
        self.top = wp.zeros(int(self.n_columns[0]) * int(self.n_columns[1]), dtype=float, device=model.device)
        self.device = model.device

    def add(self, x: wp.array, n: int, share: float, p: wp.array) -> None:
        """``p += share rho0 |g| d`` for the first ``n`` particles at ``x``."""
        if n == 0:
            return
        self.top.fill_(-1.0e30)
        grid = [self.up, self.across, self.sign, self.lower, self.h, self.n_columns]
        wp.launch(column_tops, dim=n, inputs=[x, *grid, self.top], device=self.device)
        launch_particles(add_hydrostatic, n, [x, *grid, self.top, self.rho_g, float(share), p], self.device)
