"""One frame of a run on disk: its particle file, surface mesh, the solids where they stand and,
when due, the checkpoint, handed to the writer thread together (:class:`.frame_queue.FrameQueue`);
the checkpoint is renamed in only after the frame's other files, so it is never ahead of them."""

from __future__ import annotations

import numpy as np

from ..setup.model import PARTICLE_FIELDS, id_order
from . import formats
from .checkpoint import PROBE_SAMPLES, stage_checkpoint


class FrameWriter:
    """Frames of ``sim`` into ``run`` as ``scene.output`` asks, on ``queue``; ``mesher`` meshes the
    surface (None: no meshes), ``solids`` writes the obstacles' and bodies' frames, ``owner_keys``
    go into every checkpoint (whose run it is), ``times`` take the main thread's download time,
    ``probes`` is the writer of ``probes.csv`` (None: no probes), whose row count every checkpoint
    records. :attr:`written` counts the frames whose files are all on disk."""

    def __init__(self, sim, run, scene, frames: int, queue, mesher, solids, owner_keys: dict, times, probes=None):
        self.sim, self.run, self.output, self.frames = sim, run, scene.output, frames
        self.queue, self.mesher, self.solids, self.probes = queue, mesher, solids, probes
        self.owner_keys, self.times = owner_keys, times
        self.written = 0

    def write(self, k: int) -> None:
        """Frame ``k``'s files, written side by side on the writer thread (the main thread only
        downloads: the writer orders the particles by id)."""
        sim, run = self.sim, self.run
        files, then, staged = [], [], []  # written side by side; then what must appear after them
        if self.output.particles:
            with self.times("export"):
                path = run.particle_frame(k)
                raw = {name: sim.state.host(name) for name in PARTICLE_FIELDS}
            files.append(lambda: _write_particles(path, raw))
        if self.mesher is not None:
            mesh, obj = self.mesher.mesh(sim.state.x[: sim.n_particles]), run.mesh_frame(k)
            files.append(lambda: self.mesher.export(mesh, obj))
        files += self.solids.jobs(k, sim)  # where every obstacle and body is at this frame, for the viewers
        every = self.output.checkpoint_every
        if every and (k % every == 0 or k == self.frames - 1):
            state = {**sim.checkpoint(), "frame": np.int64(k), **self.owner_keys}
            if self.probes is not None:  # its rows are flushed before the frame is handed over
                state[PROBE_SAMPLES] = np.int64(self.probes.rows)
            files.append(lambda: staged.append(stage_checkpoint(run, state)))
            then.append(lambda: staged[0].commit())

        def job():
            try:
                self.queue.together(files)
                for j in then:
                    j()
            except BaseException:
                for f in staged:  # a frame that failed leaves no checkpoint half-way
                    f.discard()
                raise
            self.written = k + 1

        self.queue.submit(job)


def _write_particles(path, raw: dict) -> None:
    """A particle frame from the downloaded fields, in the order of the particles' ids."""
    order = id_order(raw["id"])
    x, v, rho, p, ids = (raw[name][order] for name in PARTICLE_FIELDS)
    formats.write_particles(path, x, v, rho, p, ids=ids)
