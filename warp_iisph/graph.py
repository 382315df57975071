"""Graph-captured time steps: every launch of a step (grid build, neighbour lists, density,
advection, the whole IISPH Jacobi loop with its convergence test through ``wp.capture_while``,
integration and the divergence checks) is recorded once and replayed; nothing is read back
inside a step. The step's ``dt`` lives in a device array written before each replay.

Between replays, on the host: the reorder by grid cell (every few steps, in place) and the
statistics. The neighbour storage cannot grow inside a graph: a step that needed more is
restored from the copy the graph took at its start, the storage grows, the graph is recorded
again and the step replayed. Works on CPU (Warp records the launches and replays them in C++)
and on CUDA (CUDA graphs with conditional nodes, CUDA 12.4+).
"""

from __future__ import annotations

import time

import warp as wp

from .launch import recording


class CapturedStepper:
    """Replays one recorded step per :meth:`step`; the plain path is ``solver.step``."""

    def __init__(self, solver, model, state):
        self.solver = solver
        self.device = model.device
        self.graph = None
        self._generation = None
        self.captures = 0
        self.redone = 0
        self._backup = {name: wp.empty_like(getattr(state, name)) for name in ("x", "v", "p")}

    def _generations(self):
        s = self.solver.search
        return (s.fluid.generation, s.boundary.generation)

    def _capture(self, model, state) -> None:
        with recording(), wp.ScopedCapture(device=self.device, force_module_load=False) as capture:
            for name, copy in self._backup.items():
                wp.copy(copy, getattr(state, name))
            self.solver.launch_step(model, state, sync=False)
        self.graph = capture.graph
        self._generation = self._generations()
        self.captures += 1

    def step(self, model, state, dt: float) -> dict:
        solver = self.solver
        if self.graph is None and solver.steps == 0:
            return solver.step(model, state, dt)  # loads every module the graph will use
        t0 = time.perf_counter()
        if solver.steps % solver.reorder_interval == 0:
            state.reorder(solver.search.cell_order(state.x))
        solver.dt.fill_(float(dt))
        if self.graph is None or self._generation != self._generations():
            self._capture(model, state)
        wp.capture_launch(self.graph)
        search = solver.search
        lists = [search.fluid] + ([search.boundary] if search.boundary_grid is not None else [])
        if any(b.overflowed() for b in lists):
            for name, copy in self._backup.items():
                wp.copy(getattr(state, name), copy)
            for b in lists:
                if b.total > b.capacity:
                    b.grow(b.total)
            self._capture(model, state)
            wp.capture_launch(self.graph)
            self.redone += 1
        solver.steps += 1
        if self.device.is_cuda:
            wp.synchronize_device(self.device)
        return solver.read_stats(model, dt, {"step": 1e3 * (time.perf_counter() - t0)})
