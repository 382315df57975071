"""The force and moment the liquid exerts on walls: for each range of boundary particles (a body, an
obstacle, the tank), the exact reaction of the pressure and friction terms the step applied to
fluid particles from those boundary particles, with its moment about a point per range.

A fluid particle i with boundary neighbour b was pushed in the step by

- pressure: ``F_ib = -m psi_b (p_i/rho_i^2 + w p_b) grad W_ib`` (IISPH, WCSPH:
  :func:`~.solvers.base.integrate`, with ``w = 1/rho0^2`` and the walls' extrapolated pressures
  ``p_b = max(p~_i + head_ib, 0)`` of :mod:`.wall_pressure`, ``w = 0`` with Akinci's walls), or
  ``F_ib = -m psi_b (kappa_i + kappa_v_i) grad W_ib`` (DFSPH: the stiffness both solves applied
  over the step, :func:`~.solvers.dfsph.apply_stiffness`; as force = impulse / dt);
- friction: ``F_ib = m 2 mu_b (psi_b / rho_i) ((v_i - v_b) . x_ib) / (|x_ib|^2 + 0.01 h^2) grad W_ib``
  (:func:`~.solvers.forces.non_pressure_acceleration`), on the velocities each of the viscosity's
  sub-steps started from, each sub-step's share ``1/n`` of the step.

The wall takes ``-F_ib`` at ``x_b``. Each pair's term is computed from what the step kept (its
neighbour lists with ``grad W``, ``W`` and the walls' heads, the final pressures or stiffnesses)
in the solver's float32 arithmetic and summed in float64, in a fixed order: one thread per block
of :data:`BLOCK` fluid particles, in index and list order, then one thread per range and
component over the blocks in order. So the sums are the same bits on the plain path, split over
CPU threads or replayed in a graph, and they never allocate (graph-safe).

Usage::

    forces = WallForces(model, solver, ranges=[(first, count), ...], reference=points)  # vec3d per range
    forces.compute(state)          # after the solver's step (the friction is gathered during it)
    forces.totals                  # (ranges, 12) float64: pressure force, friction force, their moments
    forces.wetted                  # (ranges,) int32: its particles with a fluid neighbour in the step
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch_particles
from .neighbors import NeighborList, entry
from .solvers.forces import ViscousTerms, viscous_pair, viscous_substep_count
from .wall_pressure import Walls, smoothed_pressure

BLOCK = wp.constant(256)  # fluid particles per thread of the first pass
COMPONENTS = 12  # per range: pressure force, friction force, pressure moment, friction moment (x, y, z each)
PRESSURE_FORCE, FRICTION_FORCE, PRESSURE_MOMENT, FRICTION_MOMENT = 0, 3, 6, 9


@wp.struct
class Ranges:
    """Boundary particles ``first[r] .. first[r] + count[r] - 1`` make range r; ``lowest`` is the
    smallest ``first`` (a neighbour below it is in no range)."""

    first: wp.array(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)
    reference: wp.array(dtype=wp.vec3d)  # the point each range's moment is taken about (m)
    n: int
    lowest: int


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
def range_of(ranges: Ranges, b: int) -> int:
    """The range boundary particle b lies in, -1 for none."""
    if b < ranges.lowest:
        return -1
    for r in range(ranges.n):
        first = ranges.first[r]
        if b >= first and b < first + ranges.count[r]:
            return r
    return -1


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
    ranges: Ranges,
    push: Push,
    walls: Walls,
    xb: wp.array(dtype=wp.vec3),
    nf: NeighborList,
    nb: NeighborList,
    mass: float,
    partial: wp.array2d(dtype=wp.float64),
    wet: wp.array(dtype=wp.int32),
):
    """One block's pressure loads on every range, in index and list order; ``wet[b]`` set for
    every boundary particle of a range that has a fluid neighbour (the same value from any thread)."""
    blk = wp.tid() + offset
    for c in range(ranges.n * 6):
        partial[blk, c] = wp.float64(0.0)
    p = push.p
    for i in range(blk * BLOCK, wp.min(blk * BLOCK + BLOCK, n)):
        touches = int(0)
        for m in range(nb.count[i]):
            if range_of(ranges, nb.index[entry(nb, i, m)]) >= 0:
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
        if extrapolated:  # the smoothed pressure, summed as the solver's integrate sums it
            p_sum = float(0.0)
            for m in range(nf.count[i]):
                k = entry(nf, i, m)
                p_sum += nf.W[k] * p[nf.index[k]]
            p_c = smoothed_pressure(i, p, p_sum, walls)
        for m in range(nb.count[i]):
            k = entry(nb, i, m)
            b = nb.index[k]
            r = range_of(ranges, b)
            if r < 0:
                continue
            wet[b] = 1
            p_b = float(0.0)
            if extrapolated:
                p_b = wp.max(p_c + nb.head[k], 0.0)
            term = walls.psi[b] * (own + walls.pressure_factor * p_b) * nb.grad_W[k]  # the fluid's a_i -= term
            add_load(partial, blk, r * 6, wp.float64(mass) * wp.vec3d(term), wp.vec3d(xb[b]) - ranges.reference[r])


@wp.kernel
def friction_loads(
    offset: int,
    n: int,
    k_sub: int,
    ranges: Ranges,
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
        for c in range(ranges.n * 6):
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
            r = range_of(ranges, b)
            if r < 0:
                continue
            f = (terms.psi[b] / rho[i]) * viscous_pair(v_i - terms.vb[b], x_i - terms.xb[b], terms.h, nb.grad_W[k])
            add_load(partial, blk, r * 6, scale * wp.vec3d(f), wp.vec3d(terms.xb[b]) - ranges.reference[r])


@wp.kernel
def count_wet(ranges: Ranges, wet: wp.array(dtype=wp.int32), wetted: wp.array(dtype=wp.int32)):
    """Range r's boundary particles with a fluid neighbour this step."""
    r = wp.tid()
    first = ranges.first[r]
    n = int(0)
    for b in range(first, first + ranges.count[r]):
        n += wet[b]
    wetted[r] = n


@wp.kernel
def total_loads(
    blocks: int,
    pressure: wp.array2d(dtype=wp.float64),
    friction: wp.array2d(dtype=wp.float64),
    totals: wp.array2d(dtype=wp.float64),
):
    """Range r's component c, the blocks' values summed in block order."""
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
    """Forces and moments of the liquid on ranges of boundary particles of ``model`` stepped by
    ``solver``: ``ranges`` as ``(first, count)`` boundary indices, ``reference`` a device array of
    one ``wp.vec3d`` per range (read when the loads are summed; the caller may change its values
    between steps). ``totals[r]`` holds, after :meth:`compute`, range r's pressure force (N) at
    columns 0-2, friction force 3-5, pressure moment about ``reference[r]`` (N m) 6-8 and friction
    moment 9-11, the averages over the step just taken; ``wetted[r]`` how many of its particles
    had a fluid neighbour."""

    def __init__(self, model, solver, ranges: list, reference: wp.array | None = None):
        dev = model.device
        self.device = dev
        self.model, self.solver = model, solver
        r = Ranges()
        rows = np.asarray(ranges, dtype=np.int32).reshape(-1, 2)
        r.first = wp.array(rows[:, 0] if len(rows) else np.zeros(1, np.int32), dtype=wp.int32, device=dev)
        r.count = wp.array(rows[:, 1] if len(rows) else np.zeros(1, np.int32), dtype=wp.int32, device=dev)
        r.n = len(rows)
        r.lowest = int(rows[:, 0].min()) if len(rows) else 0
        if reference is None:
            reference = wp.zeros(max(r.n, 1), dtype=wp.vec3d, device=dev)
        r.reference = reference
        self.ranges = r
        self.blocks = max(1, -(-model.capacity // int(BLOCK)))
        width = max(r.n * 6, 1)
        self.pressure_part = wp.zeros((self.blocks, width), dtype=wp.float64, device=dev)
        self.friction_part = wp.zeros((self.blocks, width), dtype=wp.float64, device=dev)
        self.totals = wp.zeros((max(r.n, 1), COMPONENTS), dtype=wp.float64, device=dev)
        self.wet = wp.zeros(max(model.n_boundary, 1), dtype=wp.int32, device=dev)
        self.wetted = wp.zeros(max(r.n, 1), dtype=wp.int32, device=dev)  # per range: particles the liquid touched
        walls = solver.walls
        self.walls = getattr(walls, "walls", walls)  # a WallPressures holds its Walls; DFSPH keeps Walls itself
        self._pushes = None
        if r.n and model.physics.boundary_viscosity > 0.0:
            solver.viscous.observers.append(self._friction)  # the friction's sub-steps, as the solver takes them

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
        args = [state.n, k, self.ranges, state.x, v_in, state.rho, nb, terms, self.solver.dt, self.friction_part]
        launch_particles(friction_loads, blocks, args, self.device, min_chunk=1)

    def compute(self, state) -> None:
        """The step's loads into ``totals``: the pressure's from the step's final pressures (the
        friction's were gathered during the step)."""
        if self.ranges.n == 0 or state.n == 0:
            return
        search = self.solver.search
        blocks = -(-state.n // int(BLOCK))
        args = [
            state.n,
            self.ranges,
            self._push(state),
            self.walls,
            self.model.boundary_x,
            search.fluid.lists,
            search.boundary.lists,
            float(self.model.mass),
        ]
        self.wet.zero_()
        launch_particles(pressure_loads, blocks, [*args, self.pressure_part, self.wet], self.device, min_chunk=1)
        wp.launch(count_wet, dim=self.ranges.n, inputs=[self.ranges, self.wet, self.wetted], device=self.device)
        wp.launch(
            total_loads,
            dim=(self.ranges.n, COMPONENTS),
            inputs=[blocks, self.pressure_part, self.friction_part, self.totals],
            device=self.device,
        )
