"""Sums and maxima over particles into a scalar the caller keeps: no allocation, so they may run
inside the conditional bodies of a CUDA graph (``wp.utils.array_sum`` allocates there)."""

from __future__ import annotations

import warp as wp

from .launch import launch

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

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


@wp.kernel
def max_tiles(values: wp.array(dtype=float), out: wp.array(dtype=float)):
    # one atomic per tile of TILE values, from its first lane (out-of-range lanes load zeros:
    # values are >= 0); an atomic per particle on one word took 0.15-0.2 ms on an H200, and
    # as much when every lane of a tile did it (the CPU runs one lane per tile)
    b, lane = wp.tid()
    t = wp.tile_load(values, shape=TILE, offset=b * TILE)
    m = wp.tile_extract(wp.tile_max(t), 0)
    if lane == 0:
        wp.atomic_max(out, 0, m)


def max_into(values: wp.array, n: int, out: wp.array) -> None:
    """``out[0] = max(out[0], max(values[:n]))`` for values that are never negative, by tiles
    (on the CPU one thread per tile): exact, so the same on every device and path."""
    if n > 0:
        wp.launch_tiled(
            max_tiles, dim=[(n + TILE - 1) // TILE], inputs=[values[:n], out], block_dim=TILE, device=values.device
        )


def sum_into(values: wp.array, n: int, out: wp.array) -> None:
    """``out[0] = sum(values[:n])`` in float64: in index order on the CPU (deterministic, the same
    bits as ``wp.utils.array_sum``), by tiles on CUDA."""
    out.zero_()
    if n <= 0:
        return
    if values.device.is_cpu:
        launch(sum_in_order, dim=n, inputs=[values, out], device=values.device)
    else:
        wp.launch_tiled(
            sum_tiles, dim=[(n + TILE - 1) // TILE], inputs=[values[:n], out], block_dim=TILE, device=values.device
        )
