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
    real = launch._submit
    monkeypatch.setattr(launch, "_submit", lambda parts, jobs: launched.append(parts) or real(parts, jobs))
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
