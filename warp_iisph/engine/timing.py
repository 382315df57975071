"""Wall time per named stage: the one timer the solver, the surface and the run share."""

from __future__ import annotations

import time
from contextlib import contextmanager

import warp as wp


class StageTimes:
    """Wall seconds per named stage, accumulated; on CUDA the device is synchronised at each
    stage's end, so a stage's time includes its kernels, not only their launches."""

    def __init__(self, device=None, stages: tuple = ()):
        self.device = None if device is None else wp.get_device(device)
        self.seconds = dict.fromkeys(stages, 0.0)

    @contextmanager
    def __call__(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            if self.device is not None and self.device.is_cuda:
                wp.synchronize_device(self.device)
            self.add(name, time.perf_counter() - t0)

    def add(self, name: str, seconds: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + seconds

    def merge(self, other: dict) -> None:
        """Add another set of stage seconds to these."""
        for name, seconds in other.items():
            self.add(name, seconds)

    def ms(self) -> dict:
        """Milliseconds per stage, rounded as the statistics record them."""
        return {k: round(1e3 * v, 4) for k, v in self.seconds.items()}
