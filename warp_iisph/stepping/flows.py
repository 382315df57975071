"""Liquid entering and leaving during a run: emitters add a layer of particles at their nozzle
each time the last layer has moved one spacing, unless liquid sits at the nozzle (a particle
closer than :data:`BLOCKED` spacings to a new one: the layer would overlap it and the pressure
solve would blow the two apart), when the layer is skipped and counted; sinks remove the
particles inside them, often enough that none crosses one unseen: between checks the fastest
particle moves at most half the smallest sink's thinnest side.

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

# A liquid particle this close to a new one (in spacings) blocks the nozzle. A stream leaving at
# its speed has moved one spacing when the next layer is due, so it does not block itself; one
# slowed below sqrt(2 g h) (a slow jet upwards) has moved less than 0.75 h by then, and every
# other layer is skipped: what it can push out is about what is emitted.
BLOCKED = 0.75


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
        self.layers = [wp.array(e.layer(h).astype(np.float32), dtype=wp.vec3, device=device) for e in self.emitters]
        self.period = [h / e.speed for e in self.emitters]  # a layer moves one spacing in this time
        self.next_time = [e.start for e in self.emitters]
        self.emitted = 0
        self.refused = 0  # particles an emitter could not add: the state was full
        self.warn_full = True  # a LiquidFullWarning at the first refusal (a run says so in run.json instead)
        self.blocked = 0  # particles of layers skipped: liquid sat at the nozzle
        self.removed = 0
        self.reach = BLOCKED * h
        self.extents = [float(np.linalg.norm(e.layer(h), axis=1).max(initial=0.0)) + self.reach for e in self.emitters]
        self._blocking = wp.zeros(1, dtype=wp.int32, device=device)

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
                elif self._blocked(e, layer, self.extents[k]):
                    self.blocked += m
                else:
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
        return added

    def _blocked(self, emitter, layer, extent: float) -> bool:
        """Whether liquid sits where the layer would go (one pass over the liquid, one read)."""
        s = self.state
        if s.count == 0:
            return False
        self._blocking.zero_()
        launch_particles(
            count_blocking,
            s.count,
            [s.x, wp.vec3(*emitter.center), layer, extent, float(self.reach), self._blocking],
            self.device,
        )
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
        }

    def restore(self, checkpoint: dict) -> None:
        if "flows_next_time" in checkpoint:
            self.next_time = [float(t) for t in checkpoint["flows_next_time"]]
            if "flows_next_check" in checkpoint:  # older checkpoints: sinks checked once per frame only
                self.next_check = float(checkpoint["flows_next_check"])
            counts = [int(c) for c in checkpoint["flows_counts"]] + [
                0
            ]  # checkpoints before the blocked count had three
            self.emitted, self.refused, self.removed, self.blocked = counts[:4]
