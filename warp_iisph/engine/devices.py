"""Devices: what a user types (``cpu``, ``cuda``, ``cuda:1``) as the Warp device it means, and Warp's start-up."""

from __future__ import annotations

import os
import sys
import tempfile
from contextlib import contextmanager


def device_name(name: str) -> str:
    """The Warp alias of a device a user names: ``cuda`` is the first GPU, ``cuda:0``."""
    return "cuda:0" if name == "cuda" else name


def checked_device(name: str, option: str = "--device") -> str:
    """``device_name(name)``, after checking that this machine has it (``ValueError`` naming
    ``option`` and the choices otherwise)."""
    import warp as wp

    device = device_name(name)
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise ValueError(f"{option} {name}: no CUDA device is available on this machine; use cpu")
    try:
        wp.get_device(device)
    except (RuntimeError, ValueError):
        known = ", ".join(["cpu", "cuda"] + [d.alias for d in wp.get_cuda_devices()])
        raise ValueError(f"{option} {name}: unknown device; choose one of {known}") from None
    return device


# What Warp's native library prints at start-up on a machine without an NVIDIA driver: on such a
# machine the CPU is the device, and a command that asks for CUDA says so itself.
NO_DRIVER = "Could not find or load the NVIDIA CUDA driver"


@contextmanager
def native_stderr():
    """What native code writes to stderr (file descriptor 2) inside the block, caught instead of
    shown: yields a list that holds the text once the block is done (a library that fails says
    so in many lines of its own, and the caller reports it in one)."""
    caught: list[str] = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no stderr to catch
        yield caught
        return
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            yield caught
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            caught.append(capture.read().decode(errors="replace"))


def init_warp() -> None:
    """``wp.init()`` without Warp's native no-driver warning on stderr (anything else it prints
    there is passed on)."""
    import warp as wp
    from warp._src import context

    if context.runtime is not None:
        return
    with native_stderr() as caught:
        wp.init()
    for line in "".join(caught).splitlines(keepends=True):
        if NO_DRIVER not in line:
            sys.stderr.write(line)
