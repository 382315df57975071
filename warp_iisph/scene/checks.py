"""Checks every scene value goes through: one-line ``ValueError`` naming the key and its range."""

from __future__ import annotations

import math

import numpy as np


class SceneFileError(ValueError):
    """A scene file that cannot be used; the message is one line naming the file and the key."""


def vec3(value, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r}: must be three numbers [x, y, z]") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} = {value!r}: must be three finite numbers [x, y, z]")
    return arr


def positive(value, name: str, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r}: must be a number > 0 ({unit})") from None
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} = {value!r}: must be > 0 ({unit})")
    return v


def in_range(value, name: str, lo: float, hi: float, unit: str, lo_open=False, hi_open=False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r}: must be a number") from None
    lo_ok = v > lo if lo_open else v >= lo
    hi_ok = v < hi if hi_open else v <= hi
    if not (math.isfinite(v) and lo_ok and hi_ok):
        lb = "(" if lo_open else "["
        rb = ")" if hi_open else "]"
        raise ValueError(f"{name} = {value!r}: must be in {lb}{lo:g}, {hi:g}{rb} ({unit})")
    return v

