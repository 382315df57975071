"""Device names: what a user types (``cpu``, ``cuda``, ``cuda:1``) as the Warp device it means."""

from __future__ import annotations


def device_name(name: str) -> str:
    """The Warp alias of a device a user names: ``cuda`` is the first GPU, ``cuda:0``."""
    return "cuda:0" if name == "cuda" else name


def checked_device(name: str) -> str:
    """``device_name(name)``, after checking that this machine has it (``ValueError`` naming the
    choices otherwise)."""
    import warp as wp

    device = device_name(name)
    if device.startswith("cuda") and not wp.is_cuda_available():
        raise ValueError(f"--device {name}: no CUDA device is available on this machine; use --device cpu")
    try:
        wp.get_device(device)
    except (RuntimeError, ValueError):
        known = ", ".join(["cpu", "cuda"] + [d.alias for d in wp.get_cuda_devices()])
        raise ValueError(f"--device {name}: unknown device; choose one of {known}") from None
    return device
