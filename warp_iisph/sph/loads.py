"""The loads the liquid puts on obstacles: each obstacle's force and moment, the exact reaction of
the forces the step's pressure and wall friction applied to fluid particles from that obstacle's
boundary particles.

A fluid particle i with boundary neighbour b of the obstacle was pushed, in the step just taken,
by ``F_ib = -m psi_b (p_i/rho_i^2 + w p_b) grad W_ib`` (IISPH, WCSPH: :func:`~.solvers.base.integrate`,
``w = 1/rho0^2`` with the walls' extrapolated pressures ``p_b = max(p~_i + head_ib, 0)``,
:mod:`.wall_pressure`, 0 with Akinci's) or ``F_ib = -m psi_b (kappa_i + kappa_v_i) grad W_ib``
(DFSPH: the stiffness both solves applied, :func:`~.solvers.dfsph.apply_stiffness`), and by the
wall friction ``m 2 mu_b (psi_b/rho_i) ((v_i - v_b) . x_ib) / (|x_ib|^2 + 0.01 h^2) grad W_ib``
(:func:`~.solvers.forces.non_pressure_acceleration`). The obstacle takes ``-F_ib`` at ``x_b``. The
sum is recomputed after the step from what the step kept (its neighbour lists with ``grad W``,
``W`` and the walls' heads, the final pressures or stiffnesses): each pair's term in the same
float32 arithmetic as the solver's, summed in float64. The friction needs the positions and
velocities the step started from (:meth:`ObstacleLoads.keep_start`; DFSPH's after its divergence
solve, recomputed from the stiffness it applied); where the viscosity took several sub-steps in a
step it is evaluated on those velocities (the first sub-step's) for the whole step.

Sums run in a fixed order: one thread per block of :data:`BLOCK` fluid particles, in index order,
then one thread per obstacle over the blocks in order; so the loads are the same bits on the plain
path, split over CPU threads or replayed in a graph. A two-way coupled body (its force and torque
each step) reads :attr:`ObstacleLoads.totals` after :meth:`ObstacleLoads.compute`.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch_particles
from .neighbors import NeighborList, entry
from .solvers.base import Fluid
from .solvers.dfsph import DFSPHSolver
from .solvers.forces import viscous_pair
from .wall_pressure import Walls, smoothed_pressure

# fluid particles per thread of the first pass
BLOCK = wp.constant(256)
# values per obstacle in ObstacleLoads.totals: pressure force, viscous force, their moments
COMPONENTS = wp.constant(12)


@wp.func
def add_load(row: wp.array2d(dtype=wp.float64), blk: int, col: int, f: wp.vec3d, arm: wp.vec3d):
    """``f`` and its moment ``arm x f`` into a block's row from column ``col`` (force at col..col+2,
    moment at col+6..col+8)."""
    m = wp.cross(arm, f)
    for a in range(3):
        row[blk, col + a] = row[blk, col + a] + f[a]
        row[blk, col + 6 + a] = row[blk, col + 6 + a] + m[a]


@wp.struct
class LoadTargets:
    """The obstacles whose loads are summed, and where the sums go."""

    owner: wp.array(dtype=wp.int32)  # each boundary particle's obstacle (-1: the tank)
    slot_of: wp.array(dtype=wp.int32)  # an obstacle's row in the totals, -1 for one not measured
    slots: int  # obstacles measured
    reference: wp.array(dtype=wp.vec3d)  # each measured obstacle's moment centre
    xb: wp.array(dtype=wp.vec3)  # boundary particles' positions
    partial: wp.array2d(dtype=wp.float64)  # one row per block of fluid particles


@wp.struct
class WallPush:
    """What pushed fluid particles from walls in the step: DFSPH's stiffnesses (``stiffness`` 1)
    or the pressures (0); and the friction's inputs, the step's start (``mu`` 0: no friction)."""

    stiffness: int
    kappa: wp.array(dtype=float)
    kappa_v: wp.array(dtype=float)
    mu: float  # physics.boundary_viscosity
    h: float
    x0: wp.array(dtype=wp.vec3)
    v0: wp.array(dtype=wp.vec3)


@wp.func
def divergence_push(i: int, push: WallPush, fluid: Fluid, nf: NeighborList, nb: NeighborList, walls: Walls) -> wp.vec3:
    """What DFSPH's divergence solve took from particle i's velocity, over dt: its stiffness's
    acceleration (:func:`~.solvers.dfsph.apply_stiffness`, the increments summed); the friction
    acts on the velocity after it."""
    a = wp.vec3(0.0, 0.0, 0.0)
    k_i = push.kappa_v[i]
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        a += fluid.mass * (k_i + push.kappa_v[nf.index[k]]) * nf.grad_W[k]
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        a += walls.psi[nb.index[k]] * k_i * nb.grad_W[k]
    return a


@wp.kernel
def block_loads(
    offset: int,
    n: int,
    targets: LoadTargets,
    fluid: Fluid,
    nf: NeighborList,
    nb: NeighborList,
    walls: Walls,
    push: WallPush,
    p: wp.array(dtype=float),
    rho: wp.array(dtype=float),
):
    """The loads of one block of fluid particles on every measured obstacle, in index and list
    order."""
    blk = wp.tid() + offset
    for c in range(targets.slots * COMPONENTS):
        targets.partial[blk, c] = wp.float64(0.0)
    first = blk * BLOCK
    last = wp.min(first + BLOCK, n)
    mass = fluid.mass
    for i in range(first, last):
        count = nb.count[i]
        if count == 0:
            continue
        own = float(0.0)
        if push.stiffness != 0:
            own = push.kappa[i] + push.kappa_v[i]
        else:
            rho_i = rho[i]
            own = p[i] / (rho_i * rho_i)
        v_i = wp.vec3(0.0, 0.0, 0.0)
        if push.mu > 0.0:
            v_i = push.v0[i]
            if push.stiffness != 0:
                v_i = v_i - fluid.dt[0] * divergence_push(i, push, fluid, nf, nb, walls)
        extrapolated = walls.pressure_factor > 0.0
        p_c = float(0.0)
        if extrapolated:
            p_sum = float(0.0)
            for m in range(nf.count[i]):
                k = entry(nf, i, m)
                p_sum += nf.W[k] * p[nf.index[k]]
            p_c = smoothed_pressure(i, p, p_sum, walls)
        for m in range(count):
            k = entry(nb, i, m)
            b = nb.index[k]
            o = targets.owner[b]
            if o < 0:
                continue
            s = targets.slot_of[o]
            if s < 0:
                continue
            p_b = float(0.0)
            if extrapolated:
                p_b = wp.max(p_c + nb.head[k], 0.0)
            term = walls.psi[b] * (own + walls.pressure_factor * p_b) * nb.grad_W[k]  # the solver's a_i -= term
            x_b = targets.xb[b]
            arm = wp.vec3d(x_b) - targets.reference[s]
            add_load(targets.partial, blk, s * COMPONENTS, wp.float64(mass) * wp.vec3d(term), arm)
            if push.mu > 0.0:
                fric = (walls.psi[b] / rho[i]) * viscous_pair(v_i - walls.v[b], push.x0[i] - x_b, push.h, nb.grad_W[k])
                # the solver's a_i += 2 mu_b fric: the obstacle takes minus that
                add_load(
                    targets.partial, blk, s * COMPONENTS + 3, wp.float64(-2.0 * push.mu * mass) * wp.vec3d(fric), arm
                )


@wp.kernel
def total_loads(blocks: int, partial: wp.array2d(dtype=wp.float64), totals: wp.array2d(dtype=wp.float64)):
    """Column c of an obstacle's totals: the blocks' values summed in block order."""
    s, c = wp.tid()
    acc = wp.float64(0.0)
    for blk in range(blocks):
        acc += partial[blk, s * COMPONENTS + c]
    totals[s, c] = acc


@wp.kernel
def keep_start_state(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    x0: wp.array(dtype=wp.vec3),
    v0: wp.array(dtype=wp.vec3),
):
    i = wp.tid() + offset
    x0[i] = x[i]
    v0[i] = v[i]


def _stiffness_of(solver, state):
    """DFSPH's wall push is its particles' stiffness (kappa + kappa_v, over density); the others'
    their pressure over density squared and the walls' own pressures (``state.p`` stands in for
    the stiffness arrays they do not read)."""
    if isinstance(solver, DFSPHSolver):
        return 1, solver.kappa, solver.kappa_v
    return 0, state.p, state.p


class ObstacleLoads:
    """Force and moment on the obstacles ``obstacles`` (indices in the scene) from the step just
    taken. ``totals[s]`` for the s-th of them (float64): pressure force (N) at columns 0-2,
    viscous (wall friction) force 3-5, and their moments (N m) about ``reference[s]`` at 6-8 and
    9-11. ``reference`` is a device array (vec3d per obstacle), which a moving body may update."""

    def __init__(self, model, obstacles: list[int], references: list):
        self.model = model
        dev = model.device
        self.obstacles = list(obstacles)
        self.slots = len(self.obstacles)
        n_obstacles = int(model.boundary_owner.numpy().max(initial=-1)) + 1
        slot_of = np.full(max(n_obstacles, max(self.obstacles, default=-1) + 1, 1), -1, dtype=np.int32)
        for s, k in enumerate(self.obstacles):
            slot_of[k] = s
        self.slot_of = wp.array(slot_of, dtype=wp.int32, device=dev)
        self.reference = wp.array(np.asarray(references, dtype=np.float64).reshape(-1, 3), dtype=wp.vec3d, device=dev)
        self.blocks_capacity = max(1, -(-model.capacity // BLOCK))
        self.partial = wp.zeros((self.blocks_capacity, max(self.slots, 1) * COMPONENTS), dtype=wp.float64, device=dev)
        self.totals = wp.zeros((max(self.slots, 1), COMPONENTS), dtype=wp.float64, device=dev)
        ph = model.physics
        self.friction = float(ph.boundary_viscosity)
        n = model.capacity if self.friction > 0.0 else 1
        self.x0 = wp.zeros(max(n, 1), dtype=wp.vec3, device=dev)  # the step's start, for the friction
        self.v0 = wp.zeros(max(n, 1), dtype=wp.vec3, device=dev)
        self.targets = LoadTargets()
        self.targets.owner, self.targets.slot_of, self.targets.slots = model.boundary_owner, self.slot_of, self.slots
        self.targets.reference, self.targets.xb, self.targets.partial = self.reference, model.boundary_x, self.partial
        self.push = WallPush()
        self.push.mu, self.push.h, self.push.x0, self.push.v0 = self.friction, model.spacing, self.x0, self.v0

    def keep_start(self, state) -> None:
        """Before the step (after any reorder): the positions and velocities the friction uses."""
        if self.friction > 0.0:
            launch_particles(keep_start_state, state.n, [state.x, state.v, self.x0, self.v0], self.model.device)

    def compute(self, state, solver) -> wp.array:
        """The loads of the step just taken into :attr:`totals` (and returned)."""
        model = self.model
        if self.slots == 0 or state.n == 0:
            self.totals.zero_()
            return self.totals
        walls = solver.walls
        walls = getattr(walls, "walls", walls)  # IISPH's and WCSPH's WallPressures hold theirs
        self.push.stiffness, self.push.kappa, self.push.kappa_v = _stiffness_of(solver, state)
        blocks = -(-state.n // BLOCK)
        search = solver.search
        launch_particles(
            block_loads,
            blocks,
            [
                state.n,
                self.targets,
                solver.fluid,
                search.fluid.lists,
                search.boundary.lists,
                walls,
                self.push,
                state.p,
                state.rho,
            ],
            model.device,
            min_chunk=1,
        )
        wp.launch(
            total_loads, dim=(self.slots, COMPONENTS), inputs=[blocks, self.partial, self.totals], device=model.device
        )
        return self.totals
