"""Liquid entering and leaving during a run: emitters add a layer of particles at their nozzle
each time the last layer has moved one spacing, unless liquid sits at the nozzle (a particle
closer than :data:`BLOCKED` spacings to a new one: the layer would overlap it and the pressure
solve would blow the two apart), when the layer is skipped and counted; the liquid just in front
of a pouring nozzle moves with its stream every step (:func:`drive`), so that it pushes the liquid
beyond away and its next layer finds room; sinks remove the particles inside them, often enough
that none crosses one unseen: between checks the fastest particle moves at most half the smallest
sink's thinnest side.

Emission and removal happen between steps, so a step (or a replayed graph of steps) always
sees one particle count; the time loop is told when the next layer or sink check is due (steps
land there), and a graph is recorded again for a new count. Removal goes through one host copy
of the positions, at each check and at the end of every ``Simulation.advance`` (a run's frame).
"""

from __future__ import annotations

import math
import os
import sys
import warnings

import numpy as np
import warp as wp

from ..engine.launch import launch_particles

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

# A liquid particle this close to a new one (in spacings) blocks the nozzle: the layer would overlap
# it and the pressure solve would blow the two apart.
BLOCKED = 0.75
# The liquid up to this far in front of a pouring nozzle (in spacings: one kernel support) and
# within MARGIN beside and behind its layer moves with the stream (:func:`drive`), as the liquid
# leaving a pipe does: it pushes the liquid in front away, so a nozzle in a wall under the surface
# pours (all but its first layer, where the liquid starts), and what falls back onto a nozzle is
# pushed off. MARGIN is over BLOCKED so that liquid entering the stretch from beside it is moved
# on in the steps before the next layer is due (0.75 h, BLOCKED itself, left an inlet in a wall
# blocked at a quarter of its layers; 1.0 h at its first only, lab, 2026-12-06).
DRIVEN = 2.0
MARGIN = 1.0
# A nozzle drives while it has poured one of its last RECENT layers due (those before its start
# count as poured, so what sits at a mouth in a wall from the start is pushed off; but not where
# liquid lies behind its mouth at its first layer: open water, which would keep flowing into it),
# so a blocked one stays still, not a pump that moves liquid without pouring any, and one blocked
# now and then keeps pouring.
RECENT = 3


@wp.kernel
def count_blocking(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    centre: wp.vec3,
    offsets: wp.array(dtype=wp.vec3),
    extent: float,
    reach: float,
    blocking: wp.array(dtype=wp.int32),
):
    """How many liquid particles are within ``reach`` of a position of the next layer (those
    farther than ``extent``, the layer's radius plus ``reach``, from its centre are not)."""
    x_i = x[wp.tid() + offset]
    r2 = reach * reach
    c = x_i - centre
    if wp.dot(c, c) > extent * extent:
        return
    for k in range(offsets.shape[0]):
        d = x_i - (centre + offsets[k])
        if wp.dot(d, d) < r2:
            wp.atomic_add(blocking, 0, 1)
            return


@wp.kernel
def emit_layer(
    first: int,
    centre: wp.vec3,
    offsets: wp.array(dtype=wp.vec3),
    velocity: wp.vec3,
    rho0: float,
    first_id: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    rho: wp.array(dtype=float),
    p: wp.array(dtype=float),
    ids: wp.array(dtype=wp.int32),
):
    k = wp.tid()
    i = first + k
    x[i] = centre + offsets[k]
    v[i] = velocity
    rho[i] = rho0
    p[i] = 0.0
    ids[i] = first_id + k


@wp.struct
class Nozzles:
    """The emitters' nozzles on the device, for :func:`drive`: each a disc (``half[k]`` its layer's
    radius, twice) or a rectangle (its layer's half width and height) at ``centre[k]`` facing
    ``direction[k]``, spanned by ``across[k]`` and ``up[k]``, pouring at ``speed[k]`` from
    ``start[k]`` to ``end[k]``; the liquid within ``margin`` of its layer's points (sideways and
    behind) or up to ``ahead`` in front of it moves with the stream."""

    centre: wp.array(dtype=wp.vec3)
    direction: wp.array(dtype=wp.vec3)
    across: wp.array(dtype=wp.vec3)
    up: wp.array(dtype=wp.vec3)
    half: wp.array(dtype=wp.vec2)
    disc: wp.array(dtype=wp.int32)
    speed: wp.array(dtype=float)
    start: wp.array(dtype=wp.float64)
    end: wp.array(dtype=wp.float64)
    pouring: wp.array(dtype=wp.int32)  # 1 while it drives (RECENT)
    margin: float
    ahead: float
    count: int


@wp.func
def in_stretch(nozzles: Nozzles, k: int, p: wp.vec3, behind: float, ahead: float) -> bool:
    """Whether point ``p`` lies in front of nozzle k's mouth, from ``behind`` its plane to
    ``ahead`` of it (along its direction), within ``margin`` beside its layer's points."""
    r = p - nozzles.centre[k]
    along = wp.dot(r, nozzles.direction[k])
    if along < -behind or along > ahead:
        return False
    a = wp.dot(r, nozzles.across[k])
    b = wp.dot(r, nozzles.up[k])
    half = nozzles.half[k]
    if nozzles.disc[k] != 0:
        reach = half[0] + nozzles.margin
        return a * a + b * b <= reach * reach
    return wp.abs(a) <= half[0] + nozzles.margin and wp.abs(b) <= half[1] + nozzles.margin


@wp.kernel
def drive(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    nozzles: Nozzles,
    time: wp.array(dtype=wp.float64),
    dt: wp.array(dtype=wp.float64),
):
    """A particle that started the step in the stretch in front of a pouring nozzle ends it moved
    at the stream's velocity (speed times direction, whatever the step's forces gave it), as the
    liquid leaving a pipe does: the stretch pushes the liquid in front of it away, and the next
    layer finds its place free."""
    i = wp.tid() + offset
    step = float(dt[0])
    x_end = x[i]
    x_start = x_end - step * v[i]
    t = time[0] + wp.float64(1.0e-9)  # the emission's 1 ns of slack for the float clock
    for k in range(nozzles.count):
        # from its start to its end
        if nozzles.pouring[k] != 0 and t >= nozzles.start[k] and t < nozzles.end[k]:
            if in_stretch(nozzles, k, x_start, nozzles.margin, nozzles.ahead):
                stream = nozzles.speed[k] * nozzles.direction[k]
                x[i] = x_start + step * stream
                v[i] = stream
                return


@wp.kernel
def count_behind(
    offset: int, x: wp.array(dtype=wp.vec3), nozzles: Nozzles, k: int, upto: float, found: wp.array(dtype=wp.int32)
):
    """Particles behind nozzle k's mouth, from as far behind its plane as its stretch reaches
    ahead to ``upto`` (negative: behind), counted into ``found`` (read as none or some): liquid
    there flows into the mouth."""
    if in_stretch(nozzles, k, x[wp.tid() + offset], nozzles.ahead, upto):
        wp.atomic_add(found, 0, 1)


class LiquidFullWarning(RuntimeWarning):
    """An emitter's layer was left out: the particles' room (sized for the run's length, or
    ``max_particles``) is full."""


def _caller_level() -> int:
    """The ``stacklevel`` of a warning raised here that names the first line outside the package
    (the user's ``sim.advance``), whatever path of the package's own calls led here."""
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    frame, level = sys._getframe(1), 1
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(package + os.sep):
        frame, level = frame.f_back, level + 1
    return level


def has_flows(scene) -> bool:
    """Whether ``scene`` has emitters or sinks: what its :class:`Flows` is true for (and a run's
    totals then count what came in and went out)."""
    return bool(scene.emitters or scene.sinks)


class Flows:
    """The scene's emitters and sinks acting on a :class:`~warp_iisph.setup.model.State`; true
    when there are any (:func:`has_flows`)."""

    def __init__(self, scene, state, device):
        h = scene.spacing
        self.active = has_flows(scene)
        self.emitters = scene.emitters
        self.sinks = [s.bounds for s in scene.sinks]
        # sink checks: every `thinnest / (2 v)` seconds for the top speed v (check_sinks' `speed`)
        self.thinnest = min((float(np.min(hi - lo)) for lo, hi in self.sinks), default=math.inf)
        self.next_check = math.inf if not self.sinks else 0.0
        self.rho0 = float(scene.physics.rho0)
        self.state = state
        self.device = device
        layers = [e.layer(h) for e in self.emitters]  # each layer's points, from its nozzle's centre
        self.layers = [wp.array(p.astype(np.float32), dtype=wp.vec3, device=device) for p in layers]
        self.period = [h / e.speed for e in self.emitters]  # a layer moves one spacing in this time
        self.next_time = [e.start for e in self.emitters]
        self.emitted = 0
        self.refused = 0  # particles an emitter could not add: the state was full
        self.warn_full = True  # a LiquidFullWarning at the first refusal (a run says so in run.json instead)
        self.blocked = 0  # particles of layers skipped: liquid sat at the nozzle
        self.removed = 0
        self.reach = BLOCKED * h
        self.spacing = h
        radii = [float(np.linalg.norm(p, axis=1).max(initial=0.0)) for p in layers]  # each layer's reach
        self.extents = [r + self.reach for r in radii]
        self._blocking = wp.zeros(1, dtype=wp.int32, device=device)
        # per emitter, which of its last RECENT layers due came in (bit 0 the last; those before its
        # start count as come in)
        self.poured_recently = np.full(len(self.emitters), 2**RECENT - 1, dtype=np.int64)
        self.nozzles = self._nozzles(h, layers, radii) if self.emitters else None

    def _nozzles(self, h: float, layers: list, radii: list) -> Nozzles:
        n, dev = Nozzles(), self.device
        es = self.emitters
        axes = [e.axes() for e in es]
        n.centre = wp.array(np.array([e.center for e in es], np.float32), dtype=wp.vec3, device=dev)
        n.direction = wp.array(np.array([e.direction for e in es], np.float32), dtype=wp.vec3, device=dev)
        n.across = wp.array(np.array([u for u, _ in axes], np.float32), dtype=wp.vec3, device=dev)
        n.up = wp.array(np.array([w for _, w in axes], np.float32), dtype=wp.vec3, device=dev)
        half = []
        for e, layer, r, (u, w) in zip(es, layers, radii, axes):
            if e.shape == "disc":
                half.append((r, r))
            else:
                half.append((float(np.abs(layer @ u).max()), float(np.abs(layer @ w).max())))
        n.half = wp.array(np.array(half, np.float32), dtype=wp.vec2, device=dev)
        n.disc = wp.array(np.array([e.shape == "disc" for e in es], np.int32), dtype=wp.int32, device=dev)
        n.speed = wp.array(np.array([e.speed for e in es], np.float32), dtype=float, device=dev)
        n.start = wp.array(np.array([e.start for e in es], np.float64), dtype=wp.float64, device=dev)
        ends = [math.inf if e.end is None else e.end for e in es]
        n.end = wp.array(np.array(ends, np.float64), dtype=wp.float64, device=dev)
        n.pouring = wp.ones(len(es), dtype=wp.int32, device=dev)
        self._pouring = np.ones(len(es), dtype=np.int32)
        n.margin, n.ahead, n.count = float(MARGIN * h), float(DRIVEN * h), len(es)
        return n

    def drive(self, n: int, time: wp.array, dt: wp.array) -> None:
        """The liquid in front of each pouring nozzle moves with its stream this step (:func:`drive`;
        ``n`` particles, ``time`` the step's start): graph-safe."""
        if self.nozzles is not None:
            launch_particles(drive, n, [self.state.x, self.state.v, self.nozzles, time, dt], self.device)

    def __bool__(self) -> bool:
        return self.active

    def next_emission(self) -> float:
        """When the next layer is due (inf: never again)."""
        times = [t for t, e in zip(self.next_time, self.emitters) if e.end is None or t < e.end]
        return min(times, default=math.inf)

    def next_event(self) -> float:
        """When the next layer or sink check is due: steps land there."""
        return min(self.next_emission(), self.next_check)

    def check_sinks(self, due_by: float, time: float, speed: float) -> int:
        """The sink check, if due by ``due_by`` (1 ns of slack), at ``time``, the next one
        scheduled for particles as fast as ``speed``; returns how many left."""
        if due_by + 1e-9 < self.next_check:
            return 0
        self.next_check = time + 0.5 * self.thinnest / max(speed, 1e-6)
        return self.drain()

    def emit(self, time: float) -> int:
        """Add every layer due by ``time`` (1 ns of slack for the float clock); returns how many
        particles came in."""
        s = self.state
        added = 0
        for k, e in enumerate(self.emitters):
            while self.next_time[k] <= time + 1e-9 and (e.end is None or self.next_time[k] < e.end):
                layer = self.layers[k]
                m = layer.shape[0]
                if s.count + m > s.capacity:
                    if self.refused == 0 and self.warn_full:
                        due, room = self.next_time[k], s.capacity
                        text = (
                            f"emitters[{k}]: no room for its layer due at t = {due:.4g} s: the liquid holds its most, "
                            f"{room} particles (sized by max_particles, or by the emitters' flow until the run's "
                            "end: Simulation(scene, until=SECONDS)); layers due from now on are left out"
                        )
                        warnings.warn(LiquidFullWarning(text), stacklevel=_caller_level())
                    self.refused += m
                    self._count_layer(k, False)
                elif self._blocked(e, layer, self.extents[k]):
                    self.blocked += m
                    if self.next_time[k] == e.start and self._open_water(k):
                        self.poured_recently[k] = 0  # no start-up drive: it would stir the water
                    self._count_layer(k, False)
                else:
                    self._count_layer(k, True)
                    velocity = wp.vec3(*(e.speed * np.asarray(e.direction)))
                    wp.launch(
                        emit_layer,
                        dim=m,
                        device=self.device,
                        inputs=[
                            s.count,
                            wp.vec3(*e.center),
                            layer,
                            velocity,
                            self.rho0,
                            s.next_id,
                            s.x,
                            s.v,
                            s.rho,
                            s.p,
                            s.id,
                        ],
                    )
                    s.clear_carried(s.count, m)  # no warm start from a particle that left
                    s.count += m
                    s.next_id += m
                    added += m
                self.next_time[k] += self.period[k]
        self.emitted += added
        self._update_pouring()
        return added

    def _count_layer(self, k: int, poured: bool) -> None:
        self.poured_recently[k] = ((self.poured_recently[k] << 1) | int(poured)) & (2**RECENT - 1)

    def _update_pouring(self) -> None:
        """Each nozzle drives while it has poured one of its last RECENT layers due."""
        if self.nozzles is None:
            return
        pouring = (self.poured_recently != 0).astype(np.int32)
        if not np.array_equal(pouring, self._pouring):
            self.nozzles.pouring.assign(pouring)
            self._pouring = pouring

    def _open_water(self, k: int) -> bool:
        """Whether liquid lies behind nozzle k's mouth (more than half a spacing behind its plane):
        open water that flows into it, not a mouth in a wall whose liquid the drive can push off."""
        return self._any(count_behind, [self.nozzles, k, -0.5 * self.spacing])

    def _blocked(self, emitter, layer, extent: float) -> bool:
        """Whether liquid sits where the layer would go."""
        return self._any(count_blocking, [wp.vec3(*emitter.center), layer, extent, float(self.reach)])

    def _any(self, kernel, inputs: list) -> bool:
        """Whether ``kernel`` (over the liquid's particles: ``x``, then ``inputs``, then the counter)
        counts any: one pass, one read. Split over threads, its increments may race, but a race only
        loses increments of a count already above zero."""
        s = self.state
        if s.count == 0:
            return False
        self._blocking.zero_()
        launch_particles(kernel, s.count, [s.x, *inputs, self._blocking], self.device)
        return int(self._blocking.numpy()[0]) > 0

    def drain(self) -> int:
        """Remove the particles inside a sink; returns how many left."""
        s = self.state
        if not self.sinks or s.count == 0:
            return 0
        x = s.host("x")
        inside = np.zeros(len(x), dtype=bool)
        for lo, hi in self.sinks:
            inside |= np.all((x >= lo) & (x <= hi), axis=1)
        gone = int(inside.sum())
        if gone:
            s.keep(np.nonzero(~inside)[0])
            self.removed += gone
        return gone

    def checkpoint(self) -> dict:
        return {
            "flows_next_time": np.asarray(self.next_time, dtype=np.float64),
            "flows_next_check": np.float64(self.next_check),
            "flows_counts": np.asarray([self.emitted, self.refused, self.removed, self.blocked], dtype=np.int64),
            "flows_poured_recently": self.poured_recently.copy(),
        }

    def restore(self, checkpoint: dict) -> None:
        if self.active and "flows_next_time" in checkpoint:  # a scene without flows keeps none
            self.next_time = [float(t) for t in checkpoint["flows_next_time"]]
            if "flows_next_check" in checkpoint:  # older checkpoints: sinks checked once per frame only
                self.next_check = float(checkpoint["flows_next_check"])
            counts = [int(c) for c in checkpoint["flows_counts"]] + [
                0
            ]  # checkpoints before the blocked count had three
            self.emitted, self.refused, self.removed, self.blocked = counts[:4]
            if "flows_poured_recently" in checkpoint:  # older checkpoints: every nozzle taken as pouring
                self.poured_recently = np.asarray(checkpoint["flows_poured_recently"], dtype=np.int64).copy()
            else:
                self.poured_recently[:] = 2**RECENT - 1
            self._update_pouring()
