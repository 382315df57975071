"""CPU launches packed once and replayed (engine.launch): the same results as ``wp.launch`` while
the inputs change under them, and light kernels kept whole, heavy ones split."""

import numpy as np
import pytest
import warp as wp

import warp_iisph.engine.launch as launch


@wp.struct
class Holder:
    a: wp.array(dtype=float)
    k: float


@wp.kernel
def _scaled(offset: int, h: Holder, by: float, shift: wp.vec3, out: wp.array(dtype=float)):
    i = wp.tid() + offset
    out[i] = h.a[i] * h.k * by + shift[1]


def _holder(values, k: float) -> Holder:
    h = Holder()
    h.a = wp.array(np.asarray(values, np.float32), dtype=float)
    h.k = k
    return h


def _run(h, by, shift, out, n=8):
    launch.launch(_scaled, n, [0, h, by, shift, out], "cpu")
    return out.numpy().copy()


def test_a_packed_launch_follows_what_it_is_given():
    """A replayed launch reads the struct's fields as they are now, a new array, a new scalar and
    a vector changed in place: each call gives what ``wp.launch`` would."""
    n = 8
    h = _holder(np.arange(n), 2.0)
    shift = wp.vec3(0.0, 0.5, 0.0)
    out = wp.zeros(n, dtype=float)
    assert np.array_equal(_run(h, 1.0, shift, out), np.arange(n) * 2.0 + 0.5)
    assert np.array_equal(_run(h, 1.0, shift, out), np.arange(n) * 2.0 + 0.5)  # replayed
    h.a = wp.array(np.full(n, 3.0, np.float32), dtype=float)  # a field pointed elsewhere
    assert np.array_equal(_run(h, 1.0, shift, out), np.full(n, 6.5))
    h.k = 4.0  # a scalar field
    assert np.array_equal(_run(h, 1.0, shift, out), np.full(n, 12.5))
    assert np.array_equal(_run(h, 0.5, shift, out), np.full(n, 6.5))  # a scalar argument
    shift[1] = 1.5  # the same vector object, changed
    assert np.array_equal(_run(h, 0.5, shift, out), np.full(n, 7.5))
    other = wp.zeros(n, dtype=float)
    assert np.array_equal(_run(h, 0.5, shift, other), np.full(n, 7.5))  # another output array
    assert np.array_equal(_run(h, 0.5, shift, out, n=4)[:4], np.full(4, 7.5))  # another size
    assert np.array_equal(_run(h, np.float32(2.0), shift, out), np.full(n, 25.5))  # not keyed: packed anew
    launch.launch(_scaled, 0, [0, h, 1.0, shift, out], "cpu")  # an empty launch: nothing to pack or run


def test_packed_launches_are_bounded(monkeypatch):
    monkeypatch.setattr(launch, "PACKED", 4)
    h, shift, out = _holder(np.ones(8), 1.0), wp.vec3(0.0), wp.zeros(8, dtype=float)
    for k in range(10):
        assert _run(h, float(k), shift, out)[0] == k
    assert len(launch._local.packed) <= 4


@wp.kernel
def _blend(offset: int, a: wp.array(dtype=float), out: wp.array(dtype=float)):
    i = wp.tid() + offset
    out[i] = 0.5 * (out[i] + a[i])


@pytest.mark.parametrize("worth, split", [(1.0e3, False), (1.0e-12, True)])
def test_a_kernel_is_split_only_where_a_whole_launch_takes_long(monkeypatch, worth, split):
    """Its first launch loads it, the next COST_SAMPLES are timed whole; then it is split where
    the fastest of them, per element, times its size exceeds SPLIT_WORTH."""
    launched = []
    real = launch._run_split
    monkeypatch.setattr(launch, "_run_split", lambda packed: launched.append(len(packed)) or real(packed))
    monkeypatch.setattr(launch, "get_threads", lambda: 2)
    monkeypatch.setattr(launch, "SPLIT_WORTH", worth)
    monkeypatch.setattr(launch, "_cost", {})
    monkeypatch.setattr(launch, "_loaded", set())
    n = 10_000
    a = wp.array(np.arange(n, dtype=np.float32), dtype=float)
    out = wp.zeros(n, dtype=float)
    expected = np.zeros(n, np.float32)
    for k in range(2 + launch.COST_SAMPLES):
        launch.launch_particles(_blend, n, [a, out], "cpu")
        expected = np.float32(0.5) * (expected + np.arange(n, dtype=np.float32))
        assert launched == ([2] if split and k == 1 + launch.COST_SAMPLES else [])
        launched.clear()
    assert np.array_equal(out.numpy(), expected)


@wp.kernel
def _inverse(x: float, out: wp.array(dtype=float)):
    out[wp.tid()] = 1.0 / x


def test_floats_are_keyed_by_their_bits():
    """-0.0 == 0.0 in Python, but 1 / -0.0 is -inf: a launch packed for one is not the other's."""
    out = wp.zeros(2, dtype=float)
    launch.launch(_inverse, 2, [0.0, out], "cpu")
    assert np.all(np.isposinf(out.numpy()))
    launch.launch(_inverse, [2], [-0.0, out], "cpu")  # and a dim given as a list, as wp.launch takes
    assert np.all(np.isneginf(out.numpy()))


def test_another_threads_launches_run_while_this_one_records_a_graph():
    """Warp's capture of a CPU graph is process-wide: the frame writer's thread, launching while
    the main thread records, runs its launches at once (packed or not) and records nothing."""
    import threading

    n = 8
    h, shift = _holder(np.arange(n), 1.0), wp.vec3(0.0)
    out, other = wp.zeros(n, dtype=float), wp.zeros(n, dtype=float)
    _run(h, 1.0, shift, out)  # packed before
    errors = []

    def writer():
        try:
            launch.launch(_scaled, n, [0, h, 1.0, shift, out], "cpu")  # replayed
            launch.launch(_scaled, n, [0, h, np.float32(2.0), shift, other], "cpu")  # not keyed
        except Exception as e:  # noqa: BLE001 - the test reports it
            errors.append(e)

    out.zero_()
    with launch.recording(), wp.ScopedCapture(device="cpu", force_module_load=False):
        t = threading.Thread(target=writer)
        t.start()
        t.join()
    assert not errors, errors
    assert np.array_equal(out.numpy(), np.arange(n)) and np.array_equal(other.numpy(), 2.0 * np.arange(n))


def test_a_launch_packed_in_one_build_is_not_replayed_in_another(monkeypatch):
    """The key holds Warp's mode: a launch packed for the release build is packed anew in debug."""
    h, shift, out = _holder(np.ones(8), 1.0), wp.vec3(0.0), wp.zeros(8, dtype=float)
    dev = wp.get_device("cpu")
    release = launch._packed(_scaled, 8, [0, h, 1.0, shift, out], dev)
    monkeypatch.setattr(wp.config, "mode", "debug")
    debug = launch._packed(_scaled, 8, [0, h, 1.0, shift, out], dev)
    assert debug is not release  # packed anew, as wp.launch would load the module anew


def _split_blend(n: int, parts: int):
    """Packed launches of ``_blend`` over ``parts`` disjoint ranges, and its arrays (kept by the
    caller: a packed launch holds their pointers only)."""
    a = wp.array(np.arange(n, dtype=np.float32), dtype=float)
    out = wp.zeros(n, dtype=float)
    launch.launch(_blend, n, [0, a, out], "cpu")  # loaded
    out.zero_()
    cpu = wp.get_device("cpu")
    return [launch._launchable(_blend, c, [s, a, out], cpu) for s, c in launch.chunks(n, parts)], a, out


def test_a_split_launch_hands_its_chunks_to_helper_threads_and_waits_for_them():
    """Every chunk runs once, the same bits as one launch; an error on a helper thread reaches the
    caller once every helper is done, and the helpers run the next split launch as before."""
    n = 40_000
    packed, _a, out = _split_blend(n, 4)
    launch._run_split(packed)
    assert np.array_equal(out.numpy(), np.float32(0.5) * np.arange(n, dtype=np.float32))
    real, ran = launch._run, []

    def failing(p):
        ran.append(p)
        if p is packed[2]:
            raise RuntimeError("chunk 2")
        real(p)

    try:
        launch._run = failing
        with pytest.raises(RuntimeError, match="chunk 2"):
            launch._run_split(packed)
    finally:
        launch._run = real
    assert len(ran) == 4 and not launch._busy.locked()
    out.zero_()
    launch._run_split(packed)
    assert np.array_equal(out.numpy(), np.float32(0.5) * np.arange(n, dtype=np.float32))


def test_a_split_launch_while_another_thread_holds_the_helpers_runs_here():
    """The frame writer's thread may split a launch while the step's does: the second runs its
    chunks itself, one after another, with the same result."""
    import threading

    n = 40_000
    packed, _a, out = _split_blend(n, 2)
    where = []
    real = launch._run
    try:
        launch._run = lambda p: where.append(threading.current_thread().name) or real(p)
        with launch._busy:  # as if another thread's split launch were running
            launch._run_split(packed)
    finally:
        launch._run = real
    assert where == [threading.current_thread().name] * 2
    assert np.array_equal(out.numpy(), np.float32(0.5) * np.arange(n, dtype=np.float32))


def test_a_forked_process_makes_its_own_helpers():
    """A process forked from one with helper threads has none of them, and its locks may have been
    held by one of its parent's threads: it starts afresh. A changed thread count lets the old
    helpers end."""
    launch._workers_for(1)
    parent, busy = list(launch._workers), launch._busy
    busy.acquire()  # as if the frame writer's split launch were running at the fork
    try:
        launch._after_fork_in_child()
        child = launch._workers_for(1)
        assert child and not any(w is p for w in child for p in parent) and not launch._busy.locked()
    finally:
        busy.release()
    kept = launch.get_threads()
    launch.set_threads(kept + 1)
    assert launch._workers == []
    launch.set_threads(kept)
    packed, _a, out = _split_blend(20_000, 2)
    launch._run_split(packed)
    assert np.array_equal(out.numpy(), np.float32(0.5) * np.arange(20_000, dtype=np.float32))


def test_an_interrupted_wait_waits_for_its_helper_before_raising(monkeypatch):
    """Ctrl-C while the caller waits for a helper: the interrupt is raised once the helper's chunk
    is written, and the next split launch waits for its own chunk (a wait cut short would leave
    the helper's next one returning early)."""
    import threading
    import time

    n = 40_000
    packed, _a, out = _split_blend(n, 2)
    real, gate = launch._run, threading.Event()

    def slow_helper(p):
        if threading.current_thread() is not threading.main_thread():
            gate.wait(5.0)
        real(p)

    class Done:  # the helper's done lock, interrupted once as Ctrl-C interrupts acquire()
        def __init__(self, lock):
            self.lock, self.interrupted = lock, False

        def acquire(self):
            if not self.interrupted:
                self.interrupted = True
                threading.Timer(0.05, gate.set).start()
                raise KeyboardInterrupt
            return self.lock.acquire()

        def release(self):
            self.lock.release()

    (worker,) = launch._workers_for(1)
    monkeypatch.setattr(worker, "_done", Done(worker._done))
    monkeypatch.setattr(launch, "_run", slow_helper)
    t0 = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        launch._run_split(packed)
    assert time.perf_counter() - t0 >= 0.04  # it waited for the helper
    half = np.float32(0.5) * np.arange(n, dtype=np.float32)
    assert np.array_equal(out.numpy(), half)  # both chunks written
    monkeypatch.undo()
    out.zero_()
    launch._run_split(packed)
    assert np.array_equal(out.numpy(), half) and not launch._busy.locked()


def test_a_kernel_kept_whole_is_split_once_its_launches_run_long(monkeypatch):
    """A kernel whose first launches found little to do (the viscosity's sub-steps before a step
    needs them) is kept whole, timed still, and split once the median of its RECENT latest whole
    launches ran longer than SPLIT_WORTH (launches alternating between none and much work, as a
    sub-step needed every other step, are split); one long launch among short ones (the machine
    busy) is not enough."""
    launched, clock = [], {"t": 0.0, "step": 1.0e-6}
    real = launch._run_split
    monkeypatch.setattr(launch, "_run_split", lambda packed: launched.append(len(packed)) or real(packed))
    monkeypatch.setattr(launch, "get_threads", lambda: 2)
    monkeypatch.setattr(launch, "SPLIT_WORTH", 1.0e-3)
    monkeypatch.setattr(launch, "_cost", {})
    monkeypatch.setattr(launch, "_loaded", set())

    def perf_counter():  # each reading a launch's length after the last
        clock["t"] += clock["step"]
        return clock["t"]

    monkeypatch.setattr(launch.time, "perf_counter", perf_counter)
    n = 10_000
    a, out = wp.array(np.ones(n, np.float32), dtype=float), wp.zeros(n, dtype=float)

    def run(times: int, seconds: float):
        clock["step"] = seconds / 2.0  # a launch is read between two readings
        for _ in range(times):
            launch.launch_particles(_blend, n, [a, out], "cpu")

    run(1 + launch.COST_SAMPLES, 1.0e-5)  # loaded, then timed: light
    for _ in range(3):
        run(3, 1.0e-5)
        run(1, 5.0e-3)
    assert launched == []  # one long launch in every RECENT: kept whole
    run(1, 1.0e-5)  # now every other launch is long
    run(1, 5.0e-3)
    assert launched == []  # those ran whole, timed: the latest RECENT hold two long ones
    run(1, 1.0e-5)
    run(1, 5.0e-3)
    assert launched == [2, 2]


@pytest.mark.parametrize("method", ["iisph", "dfsph", "wcsph"])
def test_a_steady_step_packs_no_launch_anew(monkeypatch, method):
    """Once a run's launches are packed, each method's steps replay them, a free body's too: an
    argument made anew each step (a vector of the gravity, once) would pack its launch every step,
    20-70 us of Python each."""
    from warp_iisph import Box, Scene, Simulation

    scene = Scene(spacing=0.05, tank=Box((0.0, 0.0, 0.0), (1.0, 0.6, 0.4)), name="steady")
    scene.add_fluid_box((0.0, 0.0, 0.0), (0.4, 0.4, 0.4))
    scene.physics.viscosity, scene.physics.method = 0.05, method
    scene.add_body(Box((0.6, 0.0, 0.1), (0.75, 0.15, 0.25), name="crate"), density=500.0)
    sim = Simulation(scene, "cpu", history=1)
    for _ in range(12):  # every launch packed, the grid's reorder included
        sim.step()
    packed, real = [], wp.launch
    monkeypatch.setattr(wp, "launch", lambda kernel, *a, **k: packed.append(kernel.key) or real(kernel, *a, **k))
    for _ in range(5):
        sim.step()
    assert packed == []
