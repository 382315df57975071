"""Which Mitsuba 3 variant renders here: CUDA where an NVIDIA driver runs it, LLVM where a libLLVM
of version 16 or newer is found, else scalar; a forced one that cannot run is refused in one line."""

from __future__ import annotations

import glob
import os
import re

from ..engine.devices import native_stderr
from ..engine.signals import deferred
from ..run.folder import RunError

EXTRA = "pip install 'warp_iisph[render]'  (Mitsuba 3, pyoidn, imageio)"


class RenderUnavailable(RuntimeError):
    """The render extra (or a library it needs) is missing; the message says what to install."""


def llvm_libraries() -> list[tuple[int, str]]:
    """(major version, path) of the libLLVM shared libraries Dr.Jit could load."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        path = os.environ["DRJIT_LIBLLVM_PATH"]
        m = re.search(r"LLVM[-.]?(\d+)", os.path.basename(path))
        return [(int(m.group(1)) if m else 99, path)]
    found = {}
    for d in (
        "/usr/lib",
        "/usr/lib64",
        "/usr/local/lib",
        "/usr/lib/x86_64-linux-gnu",
        "/usr/lib/aarch64-linux-gnu",
        "/opt/homebrew/opt/llvm/lib",
    ):
        for path in (
            glob.glob(os.path.join(d, "libLLVM*.so*"))
            + glob.glob(os.path.join(d, "llvm-*", "lib", "libLLVM*.so*"))
            + glob.glob(os.path.join(d, "libLLVM*.dylib"))
        ):
            m = re.search(r"libLLVM[-.](?:so\.)?(\d+)", os.path.basename(path))
            if m:
                found.setdefault(int(m.group(1)), path)
    return sorted(found.items())


def choose_variant(device_hint: str | None = None, forced: str | None = None) -> tuple[str, str]:
    """The fastest Mitsuba variant that works here, and a line saying why."""
    try:
        with deferred():  # Ctrl-C while it loads: raised once it has
            import mitsuba as mi
    except ImportError:
        raise RenderUnavailable(f"the render extra is not installed: {EXTRA}") from None
    if forced:
        if forced not in mi.variants():
            raise RunError(f"--variant {forced!r}: must be one of {', '.join(mi.variants())}")
        why = _cannot_run(forced)
        if why is None:
            try:
                with deferred(), native_stderr():
                    mi.set_variant(forced)
            except Exception as e:  # noqa: BLE001 - Dr.Jit raises many kinds for a backend it cannot start
                why = (str(e).strip().splitlines() or [type(e).__name__])[0]
        if why is not None:
            raise RunError(f"--variant {forced}: cannot run on this machine: {why}")
        return forced, f"{forced} (asked for)"
    notes = []
    if device_hint != "cpu" and "cuda_ad_rgb" in mi.variants() and _cuda_present():
        try:
            with deferred(), native_stderr():
                mi.set_variant("cuda_ad_rgb")
            return "cuda_ad_rgb", "cuda_ad_rgb (GPU)"
        except Exception as e:  # noqa: BLE001 - any failure falls back to the CPU
            notes.append(f"cuda_ad_rgb failed ({str(e).splitlines()[0]})")
    libs = llvm_libraries()
    good = [(v, p) for v, p in libs if v >= 16]
    if "llvm_ad_rgb" in mi.variants() and good:
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", good[-1][1])
        try:
            with deferred(), native_stderr():
                mi.set_variant("llvm_ad_rgb")
            return "llvm_ad_rgb", f"llvm_ad_rgb (libLLVM {good[-1][0]}, vectorised on the CPU)"
        except Exception as e:  # noqa: BLE001
            notes.append(f"llvm_ad_rgb failed ({str(e).splitlines()[0]})")
    elif libs:
        notes.append(
            f"llvm_ad_rgb needs libLLVM >= 16 and this machine has only libLLVM {', '.join(str(v) for v, _ in libs)} "
            "(Debian's libllvm15 crashes it); install libllvm16 or newer (e.g. apt install libllvm17) or point "
            "DRJIT_LIBLLVM_PATH at one"
        )
    else:
        notes.append("llvm_ad_rgb needs libLLVM >= 16, none found (e.g. apt install libllvm17)")
    with deferred():
        mi.set_variant("scalar_rgb")
    return "scalar_rgb", "scalar_rgb (slowest)" + ("; " + "; ".join(notes) if notes else "")


def _cannot_run(variant: str) -> str | None:
    """Why a Mitsuba variant cannot run here (``None``: it may): its backend's driver or library
    is missing (a libLLVM older than 16 crashes the process, so it is not tried)."""
    if variant.startswith("cuda") and not _cuda_present():
        return "it needs an NVIDIA driver (libcuda), and none is installed"
    if variant.startswith("llvm"):
        libs = llvm_libraries()
        good = [(v, p) for v, p in libs if v >= 16]
        if not good:
            have = f"only libLLVM {', '.join(str(v) for v, _ in libs)}" if libs else "no libLLVM"
            return (
                f"it needs libLLVM >= 16 and this machine has {have} (Debian's libllvm15 crashes it); "
                "install libllvm16 or newer, or point DRJIT_LIBLLVM_PATH at one"
            )
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", good[-1][1])
    return None


def _cuda_present() -> bool:
    try:
        import ctypes

        ctypes.CDLL("libcuda.so.1")
        return True
    except OSError:
        return False


def use_variant(variant: str) -> None:
    """Set Mitsuba's ``variant`` (the one :func:`choose_variant` chose) in this process."""
    import mitsuba as mi

    if variant == "llvm_ad_rgb":
        good = [p for v, p in llvm_libraries() if v >= 16]
        if good:
            os.environ.setdefault("DRJIT_LIBLLVM_PATH", good[-1])
    mi.set_variant(variant)
