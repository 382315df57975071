import os
from pathlib import Path

import pytest

# Warp's kernel cache lives in a git-ignored folder of the repository during tests.
os.environ.setdefault("WARP_CACHE_PATH", str(Path(__file__).resolve().parents[1] / ".warp_cache"))

import warp as wp  # noqa: E402

wp.config.log_level = wp.LOG_WARNING
wp.config.kernel_cache_dir = os.environ["WARP_CACHE_PATH"]
wp.init()


def cuda_available() -> bool:
    return wp.is_cuda_available()


requires_cuda = pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device on this machine")
