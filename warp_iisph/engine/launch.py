"""One place through which per-particle kernels are launched, split over CPU threads.

Warp runs a CPU kernel as one single-threaded loop, but a CPU launch releases Python's GIL: the
same kernel launched over disjoint index ranges from several Python threads runs on several
cores at once. Every per-particle kernel therefore takes ``offset: int`` first and works on
element ``wp.tid() + offset``, writing only that element's outputs (gathers, no atomics), so
its launch can be cut into contiguous chunks with bitwise-identical results.

Kernels that use atomics, scatters or tiles (cell counts, reductions, ``check_state``) go
through ``wp.launch`` directly and are never split. On CUDA every launch is a plain
``wp.launch``.

The thread count defaults to the cores this process may use; :func:`set_threads` (or the CLI's
``--threads``, or the ``WARP_IISPH_THREADS`` environment variable) changes it.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import warp as wp

# Below this many elements per chunk, a thread hand-off costs more than it saves.
MIN_CHUNK = 2048

_threads: int | None = None
_pool: ThreadPoolExecutor | None = None
_loaded: set = set()
_pool_lock = threading.Lock()


def available_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def get_threads() -> int:
    """Threads used for CPU launches."""
    global _threads
    if _threads is None:
        env = os.environ.get("WARP_IISPH_THREADS")
        _threads = _parse_threads(env, "WARP_IISPH_THREADS") if env else available_cores()
    return _threads


def _parse_threads(value, name: str) -> int:
    try:
        n = int(value)
    except (TypeError, ValueError):
        n = 0
    if n < 1 or n > 1024:
        raise ValueError(f"{name} = {value!r}: must be an integer in [1, 1024]")
    return n


def set_threads(n: int, name: str = "threads") -> None:
    """Use ``n`` threads for CPU launches (1 = single launches, as Warp does by itself); ``name``
    is what an error calls the value (``--threads``)."""
    global _threads, _pool
    n = _parse_threads(n, name)
    with _pool_lock:
        if n != _threads and _pool is not None:
            _pool.shutdown(wait=True)
            _pool = None
        _threads = n


def _submit(n: int, calls: list) -> list:
    """Submit ``calls`` (function, args) to a pool of at least ``n - 1`` workers. The frame
    writer's thread launches kernels too (OBJ text), so the pool is replaced and used under one
    lock: never shut down between a thread's look-up and its submits."""
    global _pool
    with _pool_lock:
        if _pool is None or _pool._max_workers < n - 1:
            if _pool is not None:
                _pool.shutdown(wait=True)
            _pool = ThreadPoolExecutor(max_workers=max(1, n - 1), thread_name_prefix="warp_iisph")
        return [_pool.submit(fn, *args) for fn, args in calls]


def chunks(n: int, parts: int) -> list[tuple[int, int]]:
    """``parts`` contiguous (start, length) ranges covering ``0 .. n-1``."""
    base, extra = divmod(n, parts)
    out, start = [], 0
    for k in range(parts):
        length = base + (1 if k < extra else 0)
        if length:
            out.append((start, length))
        start += length
    return out


_recording = 0


@contextmanager
def recording():
    """While a graph is being captured, launches are recorded, not run: never split them
    (several threads would record into one capture at once)."""
    global _recording
    _recording += 1
    try:
        yield
    finally:
        _recording -= 1


def _launch_chunk(kernel, start: int, count: int, inputs: list, device) -> None:
    wp.launch(kernel, dim=count, inputs=[start, *inputs], device=device)


def launch_particles(kernel, n: int, inputs: list, device, min_chunk: int | None = None) -> None:
    """Launch ``kernel`` over elements ``0 .. n-1`` (``offset`` prepended to ``inputs``), split
    into one chunk per thread on the CPU. ``min_chunk`` (default ``MIN_CHUNK``) is the fewest
    elements worth a thread: kernels whose element is a large piece of work (a block of the
    surface's lattice) pass a smaller one."""
    if n <= 0:
        return
    device = wp.get_device(device)
    least = MIN_CHUNK if min_chunk is None else max(1, min(int(min_chunk), MIN_CHUNK))
    # Warp's debug build keeps the CPU's tile storage in one process-wide pointer (no TLS in its
    # JIT): concurrent launches then corrupt each other (a segfault in the reorder's gather)
    split = device.is_cpu and not _recording and wp.config.mode != "debug"
    parts = min(get_threads(), n // least) if split else 1
    key = (kernel.key, kernel.module.name, device.alias)
    if parts <= 1 or key not in _loaded:
        # the first launch loads (and maybe compiles) the module: never from several threads
        wp.launch(kernel, dim=n, inputs=[0, *inputs], device=device)
        _loaded.add(key)
        return
    ranges = chunks(n, parts)
    futures = _submit(parts, [(_launch_chunk, (kernel, s, c, inputs, device)) for s, c in ranges[1:]])
    s, c = ranges[0]
    wp.launch(kernel, dim=c, inputs=[s, *inputs], device=device)
    for f in futures:
        f.result()
