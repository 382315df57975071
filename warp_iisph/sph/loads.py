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
from .solvers.dfsph import DFSPHSolver
from .solvers.forces import viscous_pair
from .wall_pressure import smoothed_pressure

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


@wp.func
def divergence_push(
    i: int, kappa_v: wp.array(dtype=float), psi: wp.array(dtype=float), nf: NeighborList, nb: NeighborList, mass: float
) -> wp.vec3:
    """What DFSPH's divergence solve took from particle i's velocity, over dt: its stiffness's
    acceleration (:func:`~.solvers.dfsph.apply_stiffness`, the increments summed); the friction
    acts on the velocity after it."""
    a = wp.vec3(0.0, 0.0, 0.0)
    k_i = kappa_v[i]
    for m in range(nf.count[i]):
        k = entry(nf, i, m)
        a += mass * (k_i + kappa_v[nf.index[k]]) * nf.grad_W[k]
    for m in range(nb.count[i]):
        k = entry(nb, i, m)
        a += psi[nb.index[k]] * k_i * nb.grad_W[k]
    return a


@wp.kernel
def block_loads(
    offset: int,
    n: int,
    owner: wp.array(dtype=wp.int32),
    slot_of: wp.array(dtype=wp.int32),
    reference: wp.array(dtype=wp.vec3d),
    xb: wp.array(dtype=wp.vec3),
    vb: wp.array(dtype=wp.vec3),
    psi: wp.array(dtype=float),
    nf: NeighborList,
    nb: NeighborList,
    p: wp.array(dtype=float),
    rho: wp.array(dtype=float),
    stiffness: int,
    kappa: wp.array(dtype=float),
    kappa_v: wp.array(dtype=float),
    wall_weight: float,
    weight: wp.array(dtype=float),
    W0: float,
    mass: float,
    friction: float,
    h: float,
    x0: wp.array(dtype=wp.vec3),
    v0: wp.array(dtype=wp.vec3),
    dt_step: wp.array(dtype=float),
    slots: int,
    partial: wp.array2d(dtype=wp.float64),
):
    """The loads of one block of fluid particles on every measured obstacle (``slot_of``: an
    obstacle's row in the totals, -1 for one not measured), in index and list order."""
    blk = wp.tid() + offset
    for c in range(slots * COMPONENTS):
        partial[blk, c] = wp.float64(0.0)
    first = blk * BLOCK
    last = wp.min(first + BLOCK, n)
    for i in range(first, last):
        count = nb.count[i]
        if count == 0:
            continue
        own = float(0.0)
        if stiffness != 0:
            own = kappa[i] + kappa_v[i]
        else:
            rho_i = rho[i]
            own = p[i] / (rho_i * rho_i)
        v_i = wp.vec3(0.0, 0.0, 0.0)
        if friction > 0.0:
            v_i = v0[i]
            if stiffness != 0:
                v_i = v_i - dt_step[0] * divergence_push(i, kappa_v, psi, nf, nb, mass)
        walls = wall_weight > 0.0
        p_c = float(0.0)
        if walls:
            p_sum = float(0.0)
            for m in range(nf.count[i]):
                k = entry(nf, i, m)
                p_sum += nf.W[k] * p[nf.index[k]]
            p_c = smoothed_pressure(i, p, p_sum, W0, weight)
        for m in range(count):
            k = entry(nb, i, m)
            b = nb.index[k]
            o = owner[b]
            if o < 0:
                continue
            s = slot_of[o]
            if s < 0:
                continue
            p_b = float(0.0)
            if walls:
                p_b = wp.max(p_c + nb.head[k], 0.0)
            term = psi[b] * (own + wall_weight * p_b) * nb.grad_W[k]  # the solver's a_i -= term
            arm = wp.vec3d(xb[b]) - reference[s]
            add_load(partial, blk, s * COMPONENTS, wp.float64(mass) * wp.vec3d(term), arm)
            if friction > 0.0:
                fric = (psi[b] / rho[i]) * viscous_pair(v_i - vb[b], x0[i] - xb[b], h, nb.grad_W[k])
                # the solver's a_i += 2 mu_b fric: the obstacle takes minus that
                add_load(partial, blk, s * COMPONENTS + 3, wp.float64(-2.0 * friction * mass) * wp.vec3d(fric), arm)


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


def _stiffness_of(solver):
    """DFSPH's wall push is its particles' stiffness (kappa + kappa_v, over density); the others'
    their pressure over density squared and the walls' own pressures."""
    if isinstance(solver, DFSPHSolver):
        return 1, solver.kappa, solver.kappa_v
    return 0, None, None


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
        stiffness, kappa, kappa_v = _stiffness_of(solver)
        walls = getattr(solver, "walls", None)
        wall_weight = float(walls.factor) if walls is not None else 0.0
        weight = walls.weight if walls is not None else state.rho
        W0 = float(walls.W0) if walls is not None else 0.0
        blocks = -(-state.n // BLOCK)
        search = solver.search
        launch_particles(
            block_loads,
            blocks,
            [
                state.n,
                model.boundary_owner,
                self.slot_of,
                self.reference,
                model.boundary_x,
                model.boundary_v,
                model.boundary_psi,
                search.fluid.lists,
                search.boundary.lists,
                state.p,
                state.rho,
                stiffness,
                kappa if kappa is not None else state.p,
                kappa_v if kappa_v is not None else state.p,
                wall_weight,
                weight,
                W0,
                model.mass,
                self.friction,
                model.spacing,
                self.x0,
                self.v0,
                solver.dt,
                self.slots,
                self.partial,
            ],
            model.device,
            min_chunk=1,
        )
        wp.launch(
            total_loads, dim=(self.slots, COMPONENTS), inputs=[blocks, self.partial, self.totals], device=model.device
        )
        return self.totals
