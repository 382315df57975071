"""Frame output on a background thread, so that the next frame simulates while files are written.

The main thread takes each frame's host copies (the device's work ends there) and hands the
formatting and writing to one worker thread (which writes a frame's files side by side on a few
more, :meth:`FrameQueue.together`); Warp's launches release the GIL, so on the CPU the
simulation's kernels and the writer share the cores, and on CUDA the copy is all the GPU waits
for. At most one frame is in flight: a new one first waits for the last, which bounds memory and
raises a failed write at the next frame. Files appear atomically (see :mod:`.formats`), so a
frame on disk is always a whole frame.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Optional


class FrameQueue:
    """Runs ``submit(fn)`` jobs one at a time, in order, on a worker thread (or inline when
    ``background`` is false). ``blocked`` is the main thread's seconds spent waiting for the
    writer, ``busy`` the writer's seconds of work (overlapped with the simulation)."""

    def __init__(self, background: bool = True):
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="warp-iisph-writer") if background else None
        # a frame's files are written side by side (NumPy's packing and the disk release the GIL):
        # at 1M particles the particle file, the mesh and the checkpoint take 70-110 ms each
        self._files = ThreadPoolExecutor(4, thread_name_prefix="warp-iisph-files") if background else None
        self._pending: Optional[Future] = None
        self.blocked = 0.0
        self.busy = 0.0

    def _timed(self, fn: Callable[[], None]) -> None:
        t = time.perf_counter()
        try:
            fn()
        finally:
            self.busy += time.perf_counter() - t

    def submit(self, fn: Callable[[], None]) -> None:
        self.wait()
        if self._pool is None:
            t = time.perf_counter()
            self._timed(fn)
            self.blocked += time.perf_counter() - t
        else:
            self._pending = self._pool.submit(self._timed, fn)

    def together(self, jobs: list) -> None:
        """Run ``jobs`` side by side (in turn when not in the background) and wait for all of
        them; re-raises the first error."""
        if self._files is None or len(jobs) < 2:
            for job in jobs:
                job()
            return
        futures = [self._files.submit(job) for job in jobs]
        for f in futures:
            f.exception()  # all finish before any error is raised: no file is left half-written
        for f in futures:
            f.result()

    def wait(self) -> None:
        """Block until the job in flight is written; re-raises its error."""
        if self._pending is not None:
            t = time.perf_counter()
            job, self._pending = self._pending, None
            try:
                job.result()
            finally:
                self.blocked += time.perf_counter() - t

    def close(self) -> None:
        try:
            self.wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._files.shutdown(wait=True)

    def __enter__(self) -> "FrameQueue":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
