"""Graph capture: the loop over steps recorded once and replayed, nothing read back inside it.

The recorded body is :meth:`TimeLoop.loop_body` (``wp.capture_while`` over the step; the reorder
inside ``wp.capture_if``; the IISPH Jacobi loop a nested ``wp.capture_while``); this module only
records and replays it. Neighbour storage cannot grow inside a graph: a replay whose lists needed
more than there is gets restored from the copy the graph takes at its start, the storage grows,
the graph is recorded again and replayed. On the CPU Warp records the launches and replays them
in C++; on CUDA these are CUDA graphs with conditional nodes (CUDA 12.4+).
"""

from __future__ import annotations

import time

import warp as wp

from ..engine.launch import recording


class LoopGraph:
    """Replays of the recorded loop over steps of a :class:`TimeLoop`, recorded on first use and
    again whenever the neighbour storage has moved."""

    def __init__(self, loop):
        self.loop = loop
        self.device = loop.model.device
        self.graph = None
        self._generation = None
        self.captures = 0
        self.redone = 0
        self.replays = 0
        self._backup = [wp.empty_like(a) for a in self._sources()]

    def _sources(self) -> list:
        """What a replay changes and a redo restores: the particles (with the solver's warm
        starts), the last step's top speed and the free bodies' state."""
        s = self.loop.state
        bodies = self.loop.bodies.arrays() if self.loop.bodies is not None else []
        return [s.x, s.v, s.rho, s.p, s.id, *s.carried.values(), self.loop.max_speed2, *bodies]

    def _generations(self) -> tuple:
        """What a recorded graph depends on: the neighbour storage, and the particle count (an
        emitter or a sink changes it between replays)."""
        search = self.loop.solver.search
        return (search.fluid.generation, search.boundary.generation, self.loop.state.n)

    def _record(self) -> None:
        with recording(), wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
            for copy, src in zip(self._backup, self._sources()):
                wp.copy(copy, src)
            self.loop.loop_body()
        self.graph = capture.graph
        self._generation = self._generations()
        self.captures += 1

    def replay(self, restart) -> list[dict]:
        """Replay the loop from the clock ``restart()`` sets; its records, with per-step ``ms``."""
        t0 = time.perf_counter()
        if self.graph is None or self._generation != self._generations():
            self._record()
        wp.capture_launch(self.graph)
        search = self.loop.solver.search
        over = [(b, k) for b, k in zip((search.fluid, search.boundary), self.loop.lists_needed()) if k > b.capacity]
        if over:
            for copy, dst in zip(self._backup, self._sources()):
                wp.copy(dst, copy)
            restart()
            for buffer, needed in over:
                buffer.grow(needed)
            self._record()
            wp.capture_launch(self.graph)
            self.redone += 1
        self.replays += 1
        k = self.loop.steps_logged()
        if k == 0:
            raise RuntimeError("graph replay made no progress")
        ms = {"step": round(1e3 * (time.perf_counter() - t0) / k, 4)}
        return [{**rec, "ms": ms} for rec in self.loop.records(k)]
