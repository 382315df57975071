"""The hydrostatic pressure a particle would carry under the liquid above it: ``rho0 |g| d``, ``d``
its depth below the highest particle of its column (columns one spacing wide across gravity,
which points along an axis), half a spacing added for the top particle's own layer.

IISPH's ``physics.warm_start = "hydrostatic"`` (the default where gravity points along an axis) starts each
step's solve from it alone (:meth:`HydrostaticPressure.start`): a state function, the pressure of
resting water, with no memory of the last step's pressure that could integrate resting water's
small errors into a bounce. A particle whose advected density is below rho0 is being pulled apart
and the solution leaves it free; started with its hydrostatic pressure it would keep an
over-pressure that the solve's criterion (compression only) never sees, which slowed the Martin &
Moyce front by about a point. Its hydrostatic share is therefore ramped from whole at rho0 to none at :data:`RELEASE`
below it. Resting water's pressed particles lie within -1.2 .. +0.5 % of rho0 (1st to 99th
percentile); a ramp of 0.5 % let their starts flip from step to step and the column bounce, 1 %
and 2 % held it (docs/physics.md 4.14).
Beside a free body (a particle with one of its boundary particles as a neighbour) the start is at
least half the last step's pressure: a column's estimate counts only the liquid above a particle,
not the weight of a body resting on it, and from the estimate alone the film under a sinking box
kept it jittering at 0.1 m/s and the bundled ``flood`` shot particles out of such films at 8.9 m/s
(4.96 with this rule, 4.50 from the half start, advanced in one call before the Jacobi step's
diagonal had its floor; docs/physics.md 4.14).
``"half_hydrostatic"`` starts from half of it (ungated) plus half of the last step's pressure.

A column's height is the largest of its particles' (``wp.atomic_max``: the same on every device
and path, whatever the order); a droplet above the liquid raises its column's estimate, which
the solve then corrects like any other error of the start.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch, launch_particles
from .neighbors import NeighborList, entry

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

RELEASE = wp.constant(0.01)  # advected density deficit (fraction of rho0) at which the start is zero


@wp.struct
class Columns:
    """Columns one spacing ``h`` wide across gravity over the domain from ``lower``: ``up`` is
    gravity's axis and ``sign`` the direction heights grow in (against it), ``across`` the other
    two axes, ``n_columns`` their counts; ``top`` each column's height."""

    up: int
    sign: float
    across: wp.vec2i
    lower: wp.vec3
    h: float
    n_columns: wp.vec2i
    top: wp.array(dtype=float)


@wp.func
def column_of(c: Columns, x_i: wp.vec3) -> int:
    """The column a point is in."""
    a = wp.clamp(int((x_i[c.across[0]] - c.lower[c.across[0]]) / c.h), 0, c.n_columns[0] - 1)
    b = wp.clamp(int((x_i[c.across[1]] - c.lower[c.across[1]]) / c.h), 0, c.n_columns[1] - 1)
    return a * c.n_columns[1] + b


@wp.kernel
def column_tops(x: wp.array(dtype=wp.vec3), c: Columns):
    """Each column's highest particle, as a height along ``-g``."""
    i = wp.tid()
    x_i = x[i]
    wp.atomic_max(c.top, column_of(c, x_i), c.sign * x_i[c.up])


@wp.kernel
def add_hydrostatic(
    offset: int, x: wp.array(dtype=wp.vec3), c: Columns, rho_g: float, share: float, p: wp.array(dtype=float)
):
    """``p += share rho0 |g| d``, ``d`` the depth below the column's top plus half a spacing."""
    i = wp.tid() + offset
    x_i = x[i]
    depth = c.top[column_of(c, x_i)] + 0.5 * c.h - c.sign * x_i[c.up]
    p[i] = p[i] + share * rho_g * wp.max(depth, 0.0)


@wp.kernel
def start_hydrostatic(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    c: Columns,
    rho_g: float,
    rho_adv: wp.array(dtype=float),
    rho0: float,
    nb: NeighborList,
    loaded: wp.array(dtype=wp.int32),
    any_loaded: int,
    p: wp.array(dtype=float),
):
    """``p = s rho0 |g| d``, ``s`` ramped from 1 to 0 as the advected density falls from rho0 to
    RELEASE below it."""
    i = wp.tid() + offset
    x_i = x[i]
    depth = c.top[column_of(c, x_i)] + 0.5 * c.h - c.sign * x_i[c.up]
    share = wp.clamp((rho_adv[i] / rho0 - 1.0) / RELEASE + 1.0, 0.0, 1.0)
    start = share * rho_g * wp.max(depth, 0.0)
    if any_loaded != 0:
        for m in range(nb.count[i]):
            if loaded[nb.index[entry(nb, i, m)]] != 0:
                start = wp.max(start, p[i])  # by a free body: at least half the last pressure (p[i] holds it)
                break
    p[i] = start


class HydrostaticPressure:
    """The column heights over ``model``'s domain (allocated once) and the estimate's launches."""

    def __init__(self, model):
        g = tuple(model.physics.gravity)
        up = max(range(3), key=lambda k: abs(g[k]))
        across = [k for k in range(3) if k != up]
        c = Columns()
        c.up, c.sign = up, 1.0 if g[up] < 0.0 else -1.0  # heights grow against gravity
        c.across, c.lower, c.h = wp.vec2i(*across), wp.vec3(*model.domain_lower), float(model.spacing)
        span = [float(model.domain_upper[k] - model.domain_lower[k]) for k in across]
        c.n_columns = wp.vec2i(*(int(s / c.h) + 1 for s in span))
        c.top = wp.zeros(int(c.n_columns[0]) * int(c.n_columns[1]), dtype=float, device=model.device)
        self.columns = c
        self.rho_g = float(model.physics.rho0 * abs(g[up]))
        self.device = model.device
        loaded = np.zeros(max(model.n_boundary, 1), np.int32)  # 1: a free body's boundary particle
        if model.rigid is not None:
            body = model.bodies.body.numpy()
            loaded[model.bodies.first : model.bodies.first + len(body)] = body >= model.bodies.n_keyed
        self.loaded = wp.array(loaded, dtype=wp.int32, device=model.device)
        self.any_loaded = int(loaded.any())  # without free bodies the start never looks at the walls

    def tops(self, x: wp.array, n: int) -> None:
        """The columns' heights from the first ``n`` particles at ``x``."""
        c = self.columns
        c.top.fill_(-1.0e30)
        launch(column_tops, dim=n, inputs=[x, c], device=self.device)

    def add(self, x: wp.array, n: int, share: float, p: wp.array) -> None:
        """``p += share rho0 |g| d`` for the first ``n`` particles at ``x``."""
        if n == 0:
            return
        self.tops(x, n)
        launch_particles(add_hydrostatic, n, [x, self.columns, self.rho_g, float(share), p], self.device)

    def start(self, x: wp.array, n: int, rho_adv: wp.array, rho0: float, nb: NeighborList, p: wp.array) -> None:
        """``p`` = the hydrostatic pressure, ramped by the advected density (module docstring)."""
        if n == 0:
            return
        self.tops(x, n)
        inputs = [x, self.columns, self.rho_g, rho_adv, float(rho0), nb, self.loaded, self.any_loaded, p]
        launch_particles(start_hydrostatic, n, inputs, self.device)
