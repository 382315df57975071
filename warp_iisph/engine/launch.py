"""One place through which per-particle kernels are launched, split over CPU threads.

Warp runs a CPU kernel as one single-threaded loop, but a CPU launch releases Python's GIL: the
same kernel launched over disjoint index ranges from several Python threads runs on several
cores at once. Every per-particle kernel therefore takes ``offset: int`` first and works on
element ``wp.tid() + offset``, writing only that element's outputs (gathers, no atomics), so
its launch can be cut into contiguous chunks with bitwise-identical results.

Kernels that use atomics, scatters or tiles (cell counts, reductions, ``check_state``) and the
small ones a step launches (a clock, a body's update) go through :func:`launch`, whole. On CUDA
every launch is a plain ``wp.launch``.

The thread count defaults to the cores this process may use; :func:`set_threads` (or the CLI's
``--threads``, or the ``WARP_IISPH_THREADS`` environment variable) changes it.

On the CPU a launch's arguments are packed once and the packed launch replayed while they stay
the same (:func:`_packed`): ``wp.launch`` spends 20-70 us of Python packing a launch, more than a
light kernel's whole run over 16k particles, and a split launch packs each chunk on its own
thread, which then waits for the GIL. And a kernel is split only where a whole launch of it takes
longer than :data:`SPLIT_WORTH` (measured on its first launches after loading, per element, and
on every launch it is kept whole: a kernel whose first launches found little to do, as the
viscosity's sub-steps before the step grew long enough to need them, is split once the median of
its recent launches runs long):
handing a chunk to another thread and waiting for it costs about 50 us, which a light kernel
(a blend, a gather) over tens of thousands of particles does not win back. Neither changes a
result: split or not, packed once or every time, a kernel writes the same bits.
"""

from __future__ import annotations

import os
import struct
import threading
import time
from collections import OrderedDict, deque
from contextlib import contextmanager

import warp as wp
from warp._src.codegen import StructInstance
from warp._src.context import invoke, invoke_cpu_blocks
from warp._src.types import scalar_types

# Below this many elements per chunk, a thread hand-off costs more than it saves.
MIN_CHUNK = 2048
# A kernel is split only where a whole launch of it would run longer than this (s): a chunk handed
# to a helper costs about 0.05 ms (lab, 2 cores, 2026-12-07: a blend over 32k particles took
# 0.125 ms split in two, 0.139 ms whole; over 65k 0.21 and 0.25 ms), and a chunk's work is seldom
# half the whole's (0.25 ms moved the flood's step less than the machine's drift); 0 splits all.
SPLIT_WORTH = 4.0e-4
# Whole launches of a kernel timed before it is split or not for good: the fastest counts.
COST_SAMPLES = 2
# Whole launches of a kernel kept whole whose median decides whether it is split after all: a
# kernel's work may grow (one of the viscosity's sub-steps has work only in long steps, so its
# launches can alternate between none and much), where one long launch may be the machine's (or
# a wait for the GIL another thread holds). A kernel heavy in one launch of four or fewer stays whole.
RECENT = 4
# Packed launches kept per thread (about 60 a step of a scene with bodies, the surface's 20 more).
PACKED = 512

_threads: int | None = None
_workers: list = []  # the helper threads (_Worker)
_busy = threading.Lock()  # held by the thread whose split launch the workers run
_loaded: set = set()
_workers_lock = threading.Lock()  # guards the helper list (taken after _busy where both are)
# kernel -> [seconds per element of a whole launch (the fastest of the first timed), launches timed,
# the RECENT latest of the later whole launches]
_cost: dict = {}


class _ThreadState(threading.local):
    """Each thread's packed launches (the frame writer's thread launches too) and whether it is
    capturing a graph. Set up in each thread on first use: a plain ``threading.local`` read with
    ``getattr``'s default took about 1 us a launch where the attribute was missing."""

    def __init__(self):
        self.recording = 0
        self.packed = OrderedDict()


_local = _ThreadState()


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
    global _threads
    n = _parse_threads(n, name)
    with _busy, _workers_lock:  # the order _run_split takes them in
        if n != _threads:
            _stop_workers()
        _threads = n


class _Worker:
    """A thread that runs one job at a time, started and waited for through two locks: a
    ``ThreadPoolExecutor``'s futures and queue cost 35-90 us more a split launch (lab, 2 cores,
    2026-12-07: a blend over 16k particles 120 against 85 us, over 131k 451 against 365 us, whole
    67 and 519 us)."""

    def __init__(self):
        self._go, self._done = threading.Lock(), threading.Lock()
        self._go.acquire()
        self._done.acquire()
        self._job, self._error = None, None
        threading.Thread(target=self._loop, daemon=True, name="warp_iisph").start()

    def _loop(self) -> None:
        while True:
            self._go.acquire()
            if self._job is None:  # stopped
                return
            try:
                _run(self._job)
            except BaseException as e:  # handed to the thread that waits for it
                self._error = e
            self._done.release()

    def start(self, packed) -> None:
        self._job = packed
        self._go.release()

    def wait(self) -> None:
        """Until the job is done, through an interrupt too (raised after it: the helper may still be
        writing the caller's arrays, and a wait cut short would leave its next one returning early)."""
        interrupted = None
        while True:
            try:
                self._done.acquire()
                break
            except BaseException as e:  # Ctrl-C, or a Dask task stopped (run/cluster.py)
                interrupted = e
        error, self._error, self._job = self._error, None, None
        if interrupted is not None:
            raise interrupted
        if error is not None:
            raise error

    def stop(self) -> None:
        """End the thread once it is idle: a job it is running is finished first, one handed to it
        and not yet begun is dropped (its caller was stopped while handing out chunks)."""
        self._job = None
        try:
            self._go.release()
        except RuntimeError:  # already released by start(): the thread takes it and finds no job
            pass


def _stop_workers() -> None:
    """Let the helper threads end and make new ones when next needed (under ``_busy``)."""
    global _workers
    for w in _workers:
        w.stop()
    _workers = []


def _workers_for(n: int) -> list:
    """At least ``n`` helper threads."""
    with _workers_lock:
        while len(_workers) < n:
            _workers.append(_Worker())
        return _workers[:n]


def _after_fork_in_child() -> None:
    """A forked child has none of its parent's threads, and its locks may have been held by one
    of them (the frame writer's split launch): it starts afresh."""
    global _workers, _busy, _workers_lock
    _workers, _busy, _workers_lock = [], threading.Lock(), threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def _run_split(packed: list) -> None:
    """Run packed launches over disjoint ranges at once: the first here, each other on a helper
    thread. Where another thread's split launch holds the helpers (the frame writer's), all run
    here, one after another: the same bits either way."""
    if not _busy.acquire(blocking=False):
        for p in packed:
            _run(p)
        return
    started, handed = [], False
    try:
        try:
            for w, p in zip(_workers_for(len(packed) - 1), packed[1:]):
                w.start(p)
                started.append(w)
            handed = True
            _run(packed[0])
        finally:  # never return while a helper still writes the arrays
            errors = []
            for w in started:
                try:
                    w.wait()
                except BaseException as e:
                    errors.append(e)
        if errors:
            raise errors[0]
    finally:
        if not handed:  # stopped while handing out chunks: a helper may hold one nobody waits for
            _stop_workers()
        _busy.release()


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


@contextmanager
def recording():
    """While this thread captures a graph, its launches are recorded, not run: never split them
    (several threads would record into one capture at once) nor replayed packed (Warp records
    only what ``wp.launch`` launches). Other threads (the frame writer's) go on launching."""
    _local.recording += 1
    try:
        yield
    finally:
        _local.recording -= 1


def is_recording() -> bool:
    """Whether this thread is capturing a graph."""
    return _local.recording > 0


def _run(packed) -> None:
    """Run a packed CPU launch as ``Launch.launch`` does with no capture going on: Warp's capture
    of a CPU graph is process-wide, and a packed launch refuses to run while any thread records
    one, where this thread's launch is no part of it."""
    if packed.block_dim > 1:
        invoke_cpu_blocks(packed.kernel, packed.hooks, packed.params, False)
    else:
        invoke(packed.kernel, packed.hooks, packed.params, False)


def _signature(value):
    """What a launch packs of ``value``, as a key: an array's pointer, shape, strides and type (a
    packed launch holds exactly these), a struct by its storage (a packed launch holds it and
    reads its current fields when it runs), a vector or matrix by the object it holds and its
    value, a scalar by value; None where it cannot say (then the launch is packed anew)."""
    if isinstance(value, wp.array):
        if value.grad is not None:
            return None
        return (value.ptr, value.shape, value.strides, value.dtype)
    if isinstance(value, StructInstance):
        return ("struct", id(value.__ctype__()))
    if isinstance(value, float):  # by its bits: -0.0 == 0.0, and a NaN equals nothing
        return (type(value), _bits(value))
    if isinstance(value, (bool, int)):
        return (type(value), value)
    if value is None:
        return ("none",)
    if type(value) in scalar_types:  # a Warp scalar, packed by value
        v = value.value
        return (type(value), _bits(v) if isinstance(v, float) else v)
    if hasattr(value, "_length_"):  # a Warp vector or matrix: packed by reference, so the object too
        return (type(value), id(value), bytes(value))
    return None


def _bits(x: float) -> bytes:
    return struct.pack("<d", x)


def _packed(kernel, dim, inputs: list, device):
    """``kernel``'s launch over ``dim`` with ``inputs`` packed once, replayed while the inputs
    pack the same (:func:`_signature`) and Warp builds the same way (its mode, its float checks);
    None where an input cannot be keyed."""
    if isinstance(dim, list):
        dim = tuple(dim)
    key = [kernel, device.alias, dim, wp.config.mode, wp.config.verify_fp]
    for value in inputs:
        sig = _signature(value)
        if sig is None:
            return None
        key.append(sig)
    key = tuple(key)
    cache = _local.packed
    packed = cache.get(key)
    if packed is not None:
        cache.move_to_end(key)
        return packed
    packed = wp.launch(kernel, dim=dim, inputs=inputs, device=device, record_cmd=True)
    if packed is None:  # an empty launch: Warp records nothing
        return None
    packed.fwd_args = packed.adj_args = None  # kept for Warp's own capture only: they hold the arrays alive
    cache[key] = packed
    while len(cache) > PACKED:
        cache.popitem(last=False)
    return packed


def _launchable(kernel, dim, inputs: list, device):
    """A CPU launch to :func:`_run`: the packed one (:func:`_packed`), or where the inputs cannot
    be keyed one packed for this launch only; None for an empty launch."""
    packed = _packed(kernel, dim, inputs, device)
    if packed is None:
        packed = wp.launch(kernel, dim=dim, inputs=inputs, device=device, record_cmd=True)
    return packed


def launch(kernel, dim, inputs: list, device) -> None:
    """``wp.launch(kernel, dim=dim, inputs=inputs, device=device)``, packed once and replayed on
    the CPU (:func:`_packed`): for the small kernels a step launches whole (one thread per body,
    a count, a clock)."""
    device = wp.get_device(device)
    if device.is_cpu and not is_recording():
        packed = _launchable(kernel, dim, inputs, device)
        if packed is not None:
            _run(packed)
        return
    wp.launch(kernel, dim=dim, inputs=inputs, device=device)


def _whole(kernel, n: int, inputs: list, device) -> None:
    launch(kernel, n, [0, *inputs], device)


def launch_particles(kernel, n: int, inputs: list, device, min_chunk: int | None = None) -> None:
    """Launch ``kernel`` over elements ``0 .. n-1`` (``offset`` prepended to ``inputs``), split
    into one chunk per thread on the CPU where that pays (:data:`SPLIT_WORTH`). ``min_chunk``
    (default ``MIN_CHUNK``) is the fewest elements worth a thread: kernels whose element is a
    large piece of work (a block of the surface's lattice) pass a smaller one."""
    if n <= 0:
        return
    device = wp.get_device(device)
    if not device.is_cpu:
        wp.launch(kernel, dim=n, inputs=[0, *inputs], device=device)
        return
    key = (kernel.key, kernel.module.name, device.alias)
    if key not in _loaded:
        # the first launch loads (and maybe compiles) the module: never from several threads
        launch(kernel, n, [0, *inputs], device)
        _loaded.add(key)
        return
    least = MIN_CHUNK if min_chunk is None else max(1, min(int(min_chunk), MIN_CHUNK))
    # Warp's debug build keeps the CPU's tile storage in one process-wide pointer (no TLS in its
    # JIT): concurrent launches then corrupt each other (a segfault in the reorder's gather)
    split = not is_recording() and wp.config.mode != "debug"
    parts = min(get_threads(), n // least) if split else 1
    if parts > 1 and SPLIT_WORTH > 0.0:
        cost = _cost.get(key)
        if cost is None:
            cost = _cost[key] = [float("inf"), 0, deque(maxlen=RECENT)]
        if cost[1] < COST_SAMPLES or cost[0] * n < SPLIT_WORTH:  # whole, and timed
            t0 = time.perf_counter()
            _whole(kernel, n, inputs, device)
            per = (time.perf_counter() - t0) / n
            cost[1] += 1
            if cost[1] <= COST_SAMPLES:
                cost[0] = min(cost[0], per)
            else:  # kept whole: split once its recent launches run long (its work grew)
                recent = cost[2]
                recent.append(per)
                if len(recent) == RECENT:
                    middle = sorted(recent)[(RECENT - 1) // 2 : RECENT // 2 + 1]
                    if sum(middle) / len(middle) * n > SPLIT_WORTH:
                        cost[0] = max(recent)
            return
    if parts <= 1:
        _whole(kernel, n, inputs, device)
        return
    ranges = chunks(n, parts)
    packed = [_launchable(kernel, c, [s, *inputs], device) for s, c in ranges]
    _run_split(packed)
