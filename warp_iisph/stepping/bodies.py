"""The moving bodies in a step: keyframed obstacles and free bodies placed at the step's start,
and after the liquid's step the free bodies moved by what the liquid did to them.

At the start, each free body's pose and motion go into the bodies' poses (``sph.rigid``), the
keyframed obstacles' come from their keyframes, and every moving body's boundary particles are
placed from its start pose (``sph.bodies``). After the solver's step, the liquid's force and
moment on each free body (``sph.wall_forces``, about its centre of mass at the step's start),
gravity and the contacts move it, and its end pose is what the containment holds the liquid out
of. All of it runs on the device, inside a graph too; nothing allocates.
"""

from __future__ import annotations

from ..sph.wall_forces import WallForces


class BodySteps:
    """The per-step work of ``model``'s moving bodies, stepped with ``solver``."""

    def __init__(self, model, solver):
        self.model = model
        self.rigid = model.rigid
        self.loads = None
        if self.rigid is not None and self.rigid.n:
            ranges = list(zip(self.rigid.first, self.rigid.counts))
            self.loads = WallForces.of_ranges(model, solver, ranges, self.rigid.state.position)

    def place(self, time, dt) -> None:
        """The bodies where they are at the step's start (``time``, ``dt``: device scalars)."""
        model = self.model
        if self.loads is not None:
            self.rigid.begin_step(model.bodies.poses)
        model.bodies.place(model.boundary_x, model.boundary_v, model.boundary_a, time, dt)

    def move(self, state, time, dt, max_speed2) -> None:
        """The free bodies' update after the liquid's step from ``time``, their fastest points into
        ``max_speed2``."""
        if self.loads is None:
            return
        model = self.model
        self.loads.compute(state)
        self.rigid.advance(self.loads, model.containment.solids, model.bodies.poses, model.boundary_x, time, dt)
        self.rigid.speeds(max_speed2)

    def arrays(self) -> list:
        """What a step changes of the bodies (a graph's redo restores it)."""
        return self.rigid.arrays() if self.loads is not None else []
