"""The force and moment the liquid exerts on walls: for each group of boundary particles (a body, an
obstacle), the exact reaction of the pressure and friction terms the step applied to fluid
particles from those boundary particles, with its moment about a point per group. The one sum
behind a free body's coupling (:mod:`.rigid`) and a force probe (:mod:`..stepping.probing`).

A fluid particle i with boundary neighbour b was pushed in the step by

- pressure: ``F_ib = -m s_i psi_b (p_i/rho_i^2 + w p_b) grad W_ib`` (IISPH, WCSPH:
  :func:`~.solvers.base.integrate`, with ``w = 1/rho0^2`` and the walls' extrapolated pressures
  ``p_b = max(p~_i + head_ib, 0)`` of :mod:`.wall_pressure`, ``s_i`` the walls' completed gradient
  of :mod:`.wall_gradient`; ``w = 0``, ``s_i = 1`` with Akinci's walls), or
  ``F_ib = -m psi_b (kappa_i + kappa_v_i) grad W_ib`` (DFSPH: the stiffness both solves applied
  over the step, :func:`~.solvers.dfsph.apply_stiffness`; as force = impulse / dt);
- friction: ``F_ib = m 2 mu_b (psi_b / rho_i) ((v_i - v_b) . x_ib) / (|x_ib|^2 + 0.01 h^2) grad W_ib``
  (:func:`~.solvers.forces.non_pressure_acceleration`), on the velocities each of the viscosity's
  sub-steps started from, each sub-step's share ``1/n`` of the step.

The wall takes ``-F_ib`` at ``x_b``. Each pair's term is computed from what the step kept (its
neighbour lists with ``grad W``, ``W`` and the walls' heads, the final pressures or stiffnesses)
in the solver's float32 arithmetic and summed in float64, in a fixed order: one thread per block
of :data:`BLOCK` fluid particles, in index and list order, then one thread per group and
component over the blocks in order. So the sums are the same bits on the plain path, split over
CPU threads or replayed in a graph, and they never allocate (graph-safe).

Usage::

    forces = WallForces(model, solver, labels, reference=points)  # a group per boundary particle, vec3d per group
    forces = WallForces.of_ranges(model, solver, [(first, count), ...], reference=points)
    forces.compute(state)          # after the solver's step (the friction is gathered during it)
    forces.totals                  # (groups, 12) float64: pressure force, friction force, their moments
    forces.wetted                  # (groups,) int32: its particles with a fluid neighbour in the step
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch, launch_particles
from .neighbors import NeighborList, entry
from .solvers.forces import ViscousTerms, viscous_pair, viscous_substep_count
from .wall_pressure import Walls, smoothed_pressure

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

BLOCK = wp.constant(256)  # fluid particles per thread of the first pass
COMPONENTS = 12  # per group: pressure force, friction force, pressure moment, friction moment (x, y, z each)
PRESSURE_FORCE, FRICTION_FORCE, PRESSURE_MOMENT, FRICTION_MOMENT = 0, 3, 6, 9


@wp.struct
class Groups:
    """Which boundary particles are summed together: ``of[b]`` is boundary particle b's group (-1:
    none); group r's particles lie within ``first[r] .. first[r] + count[r] - 1`` (a body's are
    exactly that range; an obstacle's, sorted by cell among the walls', are spread within it)."""

    of: wp.array(dtype=wp.int32)
    first: wp.array(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)
    reference: wp.array(dtype=wp.vec3d)  # the point each group's moment is taken about (m)
    n: int


@wp.struct
class Push:
    """What a fluid particle's walls push it with: ``p_i / rho_i^2`` (and the walls' own pressures
    through ``Walls.pressure_factor``), or DFSPH's stiffness ``kappa_i + kappa_v_i``."""

    p: wp.array(dtype=float)
    rho: wp.array(dtype=float)
    stiffness: int
    kappa: wp.array(dtype=float)
    kappa_v: wp.array(dtype=float)


@wp.func
def add_load(row: wp.array2d(dtype=wp.float64), blk: int, col: int, f: wp.vec3d, arm: wp.vec3d):
    """``f`` at col..col+2 of a block's row and its moment ``arm x f`` at col+3..col+5."""
    m = wp.cross(arm, f)
    for a in range(3):
        row[blk, col + a] = row[blk, col + a] + f[a]
        row[blk, col + 3 + a] = row[blk, col + 3 + a] + m[a]


@wp.kernel
def pressure_loads(
    offset: int,
    n: int,
    groups: Groups,
    push: Push,
    walls: Walls,
    xb: wp.array(dtype=wp.vec3),
    nf: NeighborList,
    nb: NeighborList,
    mass: float,
    partial: wp.array2d(dtype=wp.float64),
    wet: wp.array(dtype=wp.int32),
):
    """One block's pressure loads on every group, in index and list order; ``wet[b]`` set for
    every boundary particle of a group that has a fluid neighbour (the same value from any thread)."""
    blk = wp.tid() + offset
    for c in range(groups.n * 6):
        partial[blk, c] = wp.float64(0.0)
    p = push.p
    for i in range(blk * BLOCK, wp.min(blk * BLOCK + BLOCK, n)):
        touches = int(0)
        for m in range(nb.count[i]):
            if groups.of[nb.index[entry(nb, i, m)]] >= 0:
                touches = 1
        if touches == 0:
            continue
        own = float(0.0)
        if push.stiffness != 0:
            own = push.kappa[i] + push.kappa_v[i]
        else:
            rho_i = push.rho[i]
            own = p[i] / (rho_i * rho_i)
        extrapolated = walls.pressure_factor > 0.0
        p_c = float(0.0)
        s_i = float(1.0)
        if extrapolated:  # the smoothed pressure, summed as the solver's integrate sums it
            s_i = walls.gradient_scale[i]
            p_sum = float(0.0)
            for m in range(nf.count[i]):
                k = entry(nf, i, m)
                p_sum += nf.W[k] * p[nf.index[k]]
            p_c = smoothed_pressure(i, p, p_sum, walls)
        for m in range(nb.count[i]):
            k = entry(nb, i, m)
            b = nb.index[k]
            r = groups.of[b]
            if r < 0:
                continue
            wet[b] = 1
            p_b = float(0.0)
            if extrapolated:
                p_b = wp.max(p_c + nb.head[k], 0.0)
            term = (walls.psi[b] * s_i) * (own + walls.pressure_factor * p_b) * nb.grad_W[k]  # the fluid's a_i -= term
            add_load(partial, blk, r * 6, wp.float64(mass) * wp.vec3d(term), wp.vec3d(xb[b]) - groups.reference[r])


@wp.kernel
def friction_loads(
    offset: int,
    n: int,
    k_sub: int,
    groups: Groups,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    nb: NeighborList,
    terms: ViscousTerms,
    dt_step: wp.array(dtype=float),
    partial: wp.array2d(dtype=wp.float64),
):
    """One block's friction loads of viscous sub-step ``k_sub`` (its share of the step; none past
    the sub-steps this step takes), added to those of the earlier sub-steps (sub-step 0 starts)."""
    blk = wp.tid() + offset
    if k_sub == 0:
        for c in range(groups.n * 6):
            partial[blk, c] = wp.float64(0.0)
    subs = viscous_substep_count(dt_step[0], terms.limit, terms.most)
    if k_sub >= subs:
        return
    scale = wp.float64(-2.0 * terms.boundary_viscosity * terms.mass) / wp.float64(subs)
    for i in range(blk * BLOCK, wp.min(blk * BLOCK + BLOCK, n)):
        x_i = x[i]
        v_i = v[i]
        for m in range(nb.count[i]):
            k = entry(nb, i, m)
            b = nb.index[k]
            r = groups.of[b]
            if r < 0:
                continue
            f = (terms.psi[b] / rho[i]) * viscous_pair(v_i - terms.vb[b], x_i - terms.xb[b], terms.h, nb.grad_W[k])
            add_load(partial, blk, r * 6, scale * wp.vec3d(f), wp.vec3d(terms.xb[b]) - groups.reference[r])


@wp.kernel
def count_wet(groups: Groups, wet: wp.array(dtype=wp.int32), wetted: wp.array(dtype=wp.int32)):
    """Group r's boundary particles with a fluid neighbour this step."""
    r = wp.tid()
    first = groups.first[r]
    n = int(0)
    for b in range(first, first + groups.count[r]):
        if groups.of[b] == r:
            n += wet[b]
    wetted[r] = n


@wp.kernel
def total_loads(
    blocks: int,
    pressure: wp.array2d(dtype=wp.float64),
    friction: wp.array2d(dtype=wp.float64),
    totals: wp.array2d(dtype=wp.float64),
):
    """Group r's component c, the blocks' values summed in block order."""
    r, c = wp.tid()
    part = pressure
    if c == 3 or c == 4 or c == 5 or c >= 9:
        part = friction
    col = r * 6 + c % 3
    if c >= 6:
        col += 3
    acc = wp.float64(0.0)
    for blk in range(blocks):
        acc += part[blk, col]
    totals[r, c] = acc


class WallForces:
    """Forces and moments of the liquid on groups of boundary particles of ``model`` stepped by
    ``solver``: ``groups`` as one label per boundary particle (its group, -1 for none; use
    :meth:`of_ranges` for ``(first, count)`` ranges), ``reference`` a device array of one
    ``wp.vec3d`` per group (read when the loads are summed; the caller may change its values
    between steps). ``totals[r]`` holds, after :meth:`compute`, group r's pressure force (N) at
    columns 0-2, friction force 3-5, pressure moment about ``reference[r]`` (N m) 6-8 and friction
    moment 9-11, the averages over the step just taken; with ``count_wetted`` (a body's ranges)
    ``wetted[r]`` how many of its particles had a fluid neighbour."""

    def __init__(
        self, model, solver, groups: np.ndarray, reference: wp.array | None = None, count_wetted: bool = False
    ):
        dev = model.device
        self.device = dev
        self.model, self.solver = model, solver
        labels = np.asarray(groups, dtype=np.int32).reshape(-1)
        n = int(labels.max(initial=-1)) + 1
        first, count = np.zeros(max(n, 1), np.int32), np.zeros(max(n, 1), np.int32)
        for r in range(n):
            where = np.flatnonzero(labels == r)
            if len(where):
                first[r], count[r] = where[0], where[-1] + 1 - where[0]
        g = Groups()
        g.of = wp.array(labels if len(labels) else np.full(1, -1, np.int32), dtype=wp.int32, device=dev)
        g.first = wp.array(first, dtype=wp.int32, device=dev)
        g.count = wp.array(count, dtype=wp.int32, device=dev)
        g.n = n
        if reference is None:
            reference = wp.zeros(max(n, 1), dtype=wp.vec3d, device=dev)
        g.reference = reference
        self.groups = g
        self.blocks = max(1, -(-model.capacity // int(BLOCK)))
        width = max(n * 6, 1)
        self.pressure_part = wp.zeros((self.blocks, width), dtype=wp.float64, device=dev)
        self.friction_part = wp.zeros((self.blocks, width), dtype=wp.float64, device=dev)
        self.totals = wp.zeros((max(n, 1), COMPONENTS), dtype=wp.float64, device=dev)
        self.wet = wp.zeros(max(model.n_boundary, 1), dtype=wp.int32, device=dev)
        self.wetted = wp.zeros(max(n, 1), dtype=wp.int32, device=dev)  # per group: particles the liquid touched
        self.count_wetted = count_wetted  # a body's contacts read it; a force probe does not
        walls = solver.walls
        self.walls = getattr(walls, "walls", walls)  # a WallPressures holds its Walls; DFSPH keeps Walls itself
        self._pushes = None
        if n and model.physics.boundary_viscosity > 0.0:
            solver.viscous.observers.append(self._friction)  # the friction's sub-steps, as the solver takes them

    @classmethod
    def of_ranges(cls, model, solver, ranges: list, reference: wp.array | None = None) -> WallForces:
        """Groups that are ranges of boundary particles, ``(first, count)`` each (a body's)."""
        labels = np.full(model.n_boundary, -1, dtype=np.int32)
        for r, (first, count) in enumerate(ranges):
            labels[first : first + count] = r
        return cls(model, solver, labels, reference, count_wetted=True)

    def _push(self, state) -> Push:
        """The :class:`Push` of ``state`` (made once: the state's arrays keep their memory)."""
        if self._pushes is None:
            push = Push()
            push.p, push.rho = state.p, state.rho
            kappa, kappa_v = getattr(self.solver, "kappa", None), getattr(self.solver, "kappa_v", None)
            push.stiffness = int(kappa is not None)
            push.kappa = kappa if kappa is not None else state.p
            push.kappa_v = kappa_v if kappa_v is not None else state.p
            self._pushes = push
        return self._pushes

    def _friction(self, k: int, state, v_in: wp.array) -> None:
        """The friction loads of viscous sub-step ``k`` on the velocities ``v_in`` it starts from."""
        blocks = -(-state.n // int(BLOCK))
        terms, nb = self.solver.viscous.terms, self.solver.search.boundary.lists
        args = [state.n, k, self.groups, state.x, v_in, state.rho, nb, terms, self.solver.dt, self.friction_part]
        launch_particles(friction_loads, blocks, args, self.device, min_chunk=1)

    def compute(self, state) -> None:
        """The step's loads into ``totals``: the pressure's from the step's final pressures (the
        friction's were gathered during the step)."""
        if self.groups.n == 0 or state.n == 0:
            return
        search = self.solver.search
        blocks = -(-state.n // int(BLOCK))
        args = [
            state.n,
            self.groups,
            self._push(state),
            self.walls,
            self.model.boundary_x,
            search.fluid.lists,
            search.boundary.lists,
            float(self.model.mass),
        ]
        self.wet.zero_()
        launch_particles(pressure_loads, blocks, [*args, self.pressure_part, self.wet], self.device, min_chunk=1)
        if self.count_wetted:
            launch(count_wet, dim=self.groups.n, inputs=[self.groups, self.wet, self.wetted], device=self.device)
        launch(
            total_loads,
            dim=(self.groups.n, COMPONENTS),
            inputs=[blocks, self.pressure_part, self.friction_part, self.totals],
            device=self.device,
        )
