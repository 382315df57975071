"""One place through which per-particle kernels are launched.

Every per-particle kernel takes ``offset: int`` as its first argument and works on particle
``wp.tid() + offset``, writing only that particle's outputs. This keeps the door open for
splitting a CPU launch into index ranges (Warp runs a CPU kernel on one thread). Kernels that
use atomics (reductions, counts) are launched with ``wp.launch`` directly and never split.
"""

import warp as wp


def launch_particles(kernel, n: int, inputs: list, device) -> None:
    """Launch ``kernel`` over particles ``0 .. n-1`` (``offset`` prepended to ``inputs``)."""
    if n <= 0:
        return
    wp.launch(kernel, dim=n, inputs=[0, *inputs], device=device)
