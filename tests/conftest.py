import os
import signal
from pathlib import Path

import pytest

# Warp's kernel cache lives in a git-ignored folder of the repository during tests.
os.environ.setdefault("WARP_CACHE_PATH", str(Path(__file__).resolve().parents[1] / ".warp_cache"))

import warp as wp  # noqa: E402

wp.config.log_level = wp.LOG_WARNING
wp.config.kernel_cache_dir = os.environ["WARP_CACHE_PATH"]
wp.init()


def pytest_sessionstart(session):
    """Compile the package's kernels before the first test, on every core. Warp compiles a module
    at its first launch, one after another: a fresh clone's run spent 66 s on them, 31 s on 2
    cores this way; from the cache, loading them takes a fraction of a second. The viewers (they
    import Blender's module) and the entry points are left to their tests."""
    import importlib
    import pkgutil

    import warp_iisph
    from warp_iisph.engine.launch import available_cores

    left = ("warp_iisph.view", "warp_iisph.scene.bundled")
    for info in pkgutil.walk_packages(warp_iisph.__path__, "warp_iisph."):
        if not info.name.endswith("__main__") and not info.name.startswith(left):
            importlib.import_module(info.name)
    wp.load_module("warp_iisph", device="cpu", recursive=True, max_workers=available_cores())


def finish(proc, timeout: float = 60) -> tuple[str, str]:
    """``proc.communicate`` that never leaves the child running: killed if it outlives ``timeout``."""
    import subprocess

    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise


def terminal_signals() -> None:
    """For a child process that the tests interrupt: Ctrl-C as in a terminal. A shell without job
    control starts background jobs with SIGINT ignored, and Python then never raises
    KeyboardInterrupt; the child gets the default back before it starts."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def cuda_available() -> bool:
    return wp.is_cuda_available()


requires_cuda = pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device on this machine")


# --- tiny runs with meshes, for the viewers and exporters (each test module gets its own) -----------


def collapsing_block():
    """Water 0.2 m wide and 0.24 m high against one wall of a 0.4 x 0.5 x 0.4 m tank (4 cm
    spacing): it collapses, so every frame differs (water at rest would stay at rest)."""
    from warp_iisph.scene import Box, Scene

    scene = Scene(spacing=0.04, tank=Box((0.0, 0.0, 0.0), (0.4, 0.5, 0.4)), name="collapsing_block")
    scene.add_fluid_box((0.0, 0.0, 0.0), (0.2, 0.24, 0.4))
    return scene


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A collapsing block of 300 particles, 0.1 s at 30 frames/s: 4 particle and mesh frames."""
    from warp_iisph.run.runner import run_scene

    out = tmp_path_factory.mktemp("view") / "run"
    scene = collapsing_block()
    scene.output.mesh = True
    record = run_scene(scene, out, duration=0.1, fps=30, progress=False)
    assert record["ended"] == "completed"
    return out


PILLAR = ((0.14, 0.0, 0.14), (0.26, 0.3, 0.26))


@pytest.fixture(scope="module")
def obstacle_run(tmp_path_factory):
    """Shallow water around a box pillar that rises above it: 2 particle and mesh frames."""
    from warp_iisph import scenes
    from warp_iisph.run.runner import run_scene
    from warp_iisph.scene import Box

    out = tmp_path_factory.mktemp("obstacle") / "run"
    scene = scenes.hydrostatic_tank(spacing=0.04, width=0.4, depth=0.4, water_height=0.12)
    scene.tank.upper = (0.4, 0.5, 0.4)
    scene.add_obstacle(Box(*PILLAR))
    scene.output.mesh = True
    record = run_scene(scene, out, duration=1 / 30, fps=30, progress=False)
    assert record["ended"] == "completed" and record["obstacles"] == "obstacles.obj"
    return out


@pytest.fixture
def conditional_body_allocations(monkeypatch) -> list:
    """On CUDA a conditional body of a graph (capture_while, capture_if) may not allocate:
    wp.utils.array_sum, array_scan, HashGrid.build and every array constructor fail there. On the
    CPU they work, so this makes them fail while a conditional body is being recorded, and returns
    the list of what was called there: the CPU catches a regression without a GPU."""
    import warp_iisph.engine.launch as launch

    depth, calls = [0], []

    def conditional(real):
        def wrapped(condition, *args, **kwargs):
            depth[0] += 1
            try:
                return real(condition, *args, **kwargs)
            finally:
                depth[0] -= 1

        return wrapped

    def forbidden(name, real):
        def wrapped(*args, **kwargs):
            if launch.is_recording() and depth[0]:
                calls.append(name)
                raise RuntimeError(f"{name} inside a conditional graph body: it allocates on CUDA")
            return real(*args, **kwargs)

        return wrapped

    monkeypatch.setattr(wp, "capture_while", conditional(wp.capture_while))
    monkeypatch.setattr(wp, "capture_if", conditional(wp.capture_if))
    monkeypatch.setattr(wp.utils, "array_sum", forbidden("array_sum", wp.utils.array_sum))
    monkeypatch.setattr(wp.utils, "array_scan", forbidden("array_scan", wp.utils.array_scan))
    monkeypatch.setattr(wp.HashGrid, "build", forbidden("HashGrid.build", wp.HashGrid.build))
    for name in ("empty", "zeros", "full", "empty_like", "zeros_like", "full_like", "clone"):  # any allocation
        monkeypatch.setattr(wp, name, forbidden(f"wp.{name}", getattr(wp, name)))
    return calls
