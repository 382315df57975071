"""Every kernel module compiles for CUDA on a machine without a GPU (Warp's NVRTC), quickly: the
CPU runs the tests, so a kernel that only CUDA's compiler refuses, or that takes it minutes to
compile, would otherwise first show on a GPU (sph/rigid.py once took NVRTC 367 s for sm_90)."""

import importlib
import pkgutil
import time

import pytest
import warp as wp

# H100 and H200 (the project's GPUs) are sm_90; a module that compiles in a second here taking a
# minute means unrolled loops or adjoint code compiled for nothing
ARCH = 90
SLOWEST = 60.0


def _kernel_modules() -> list[str]:
    import warp_iisph

    left = ("warp_iisph.view", "warp_iisph.scene.bundled")
    names = []
    for info in pkgutil.walk_packages(warp_iisph.__path__, "warp_iisph."):
        if info.name.endswith("__main__") or info.name.startswith(left):
            continue
        importlib.import_module(info.name)
        if wp.get_module(info.name).kernels:
            names.append(info.name)
    return names


def test_every_kernel_module_carries_no_adjoint_code():
    """Nothing is differentiated: Warp's default backward pass would only cost compile time."""
    names = _kernel_modules()
    assert "warp_iisph.sph.rigid" in names and "warp_iisph.sph.solvers.iisph" in names
    assert [n for n in names if wp.get_module(n).options["enable_backward"] is not False] == []
    assert wp.get_module("warp_iisph.sph.rigid").options["max_unroll"] == 1  # one thread a body


def test_every_kernel_module_compiles_for_cuda_quickly(tmp_path):
    if ARCH not in wp.get_cuda_supported_archs():  # a Warp built without CUDA compiles nothing for it
        pytest.skip(f"this Warp cannot compile CUDA code for sm_{ARCH}")
    names = _kernel_modules()
    seconds = {}
    for name in names:
        t0 = time.perf_counter()
        wp.compile_aot_module(name, arch=ARCH, module_dir=tmp_path, use_ptx=True)
        seconds[name] = time.perf_counter() - t0
    assert len(list(tmp_path.glob("*.ptx"))) >= len(names)
    slow = {k: round(v, 1) for k, v in seconds.items() if v > SLOWEST}
    assert not slow, f"modules NVRTC took over {SLOWEST:.0f} s to compile: {slow}"
