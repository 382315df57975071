"""Sums over particles into a float64 scalar the caller keeps: no allocation, so they may run
inside the conditional bodies of a CUDA graph (``wp.utils.array_sum`` allocates there)."""

from __future__ import annotations

import warp as wp

TILE = 256


@wp.kernel
def sum_in_order(values: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.float64)):
    # a CPU launch is one loop over tid: the sum is taken in index order, as array_sum does
    wp.atomic_add(out, 0, values[wp.tid()])


@wp.kernel
def sum_tiles(values: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.float64)):
    # one atomic per tile of TILE values (out-of-range lanes load zeros)
    b = wp.tid()
    t = wp.tile_load(values, shape=TILE, offset=b * TILE)
    wp.tile_atomic_add(out, wp.tile_sum(t))


def sum_into(values: wp.array, n: int, out: wp.array) -> None:
    """``out[0] = sum(values[:n])`` in float64: in index order on the CPU (deterministic, the same
    bits as ``wp.utils.array_sum``), by tiles on CUDA."""
    out.zero_()
    if n <= 0:
        return
    if values.device.is_cpu:
        wp.launch(sum_in_order, dim=n, inputs=[values, out], device=values.device)
    else:
        wp.launch_tiled(sum_tiles, dim=[(n + TILE - 1) // TILE], inputs=[values[:n], out], block_dim=TILE, device=values.device)
