"""Checks every scene value goes through: one-line ``ValueError`` naming the key and its range."""

from __future__ import annotations

import dataclasses
import functools
import math
import unicodedata

import numpy as np

# Largest coordinate a scene may use (metres): float32 positions keep 0.1 mm steps out to 1 km.
MAX_COORDINATE = 1.0e3
# Most particles a scene may hold: Warp indexes arrays with 32-bit integers.
MAX_PARTICLES = 2**31 - 1
# Most fluid blocks, obstacles, emitters or sinks a scene may list (fluid blocks are checked for
# overlap pair by pair).
MAX_ITEMS = 1000
# Longest scene name (characters): it names the output folder runs/NAME, and the folders a run is
# staged in beside it (.NAME.new-PID) must stay within the file system's 255 bytes.
MAX_NAME = 100


class SceneFileError(ValueError):
    """A scene file that cannot be used; the message is one line naming the file and the key."""


class Record:
    """A scene's data class that can be frozen (:func:`freeze`): the copy a ``Simulation`` keeps
    refuses changes, since it was validated once and a change would reach the run unchecked
    (setting a field to the value it has, as validating it again does, is no change)."""

    def __setattr__(self, name, value):
        if not name.startswith("_") and dataclasses.is_dataclass(self):
            keys = _keys(type(self))
            if name not in keys:  # a misspelt key would be ignored without a word
                raise AttributeError(
                    f"{type(self).__name__}.{name}: no such key; the keys are {', '.join(sorted(keys))}"
                )
        if self.__dict__.get("_frozen") and not name.startswith("_") and not _same(self.__dict__.get(name), value):
            raise AttributeError(f"{type(self).__name__}.{name}: {READ_ONLY}")
        object.__setattr__(self, name, value)


@functools.lru_cache(maxsize=None)
def _keys(cls) -> frozenset:
    """A record class's keys (its dataclass fields), read once per class."""
    return frozenset(f.name for f in dataclasses.fields(cls))


def _same(a, b) -> bool:
    if type(a) is not type(b):
        return False
    try:
        return bool(np.all(a == b))
    except (TypeError, ValueError, OverflowError):
        return a is b


READ_ONLY = "read-only, a Simulation's own validated copy of the scene; change the Scene and build a new Simulation"


class FrozenList(list):
    """A frozen record's list (``scene.probes``, a body's ``fixed_axes``): reads as a list, refuses
    every change in place (``AttributeError``), as the record's own fields do."""

    def _refuse(self, *args, **kwargs):
        raise AttributeError(f"this list is {READ_ONLY}")

    append = extend = insert = remove = pop = clear = sort = reverse = _refuse
    __setitem__ = __delitem__ = __iadd__ = __imul__ = _refuse

    def __reduce_ex__(self, protocol):  # copies and pickles rebuild it whole, never by appends
        return (FrozenList, (list(self),))


def _frozen_list(items: list) -> FrozenList:
    """``items`` and the lists within it (a motion's keys) as :class:`FrozenList`."""
    return FrozenList(_frozen_list(i) if type(i) is list else i for i in items)


def freeze(value) -> None:
    """Freeze a :class:`Record` and every record it holds (in fields, lists and tuples); a
    record's lists become :class:`FrozenList`."""
    if isinstance(value, (list, tuple)):
        for item in value:
            freeze(item)
    elif isinstance(value, Record):
        for key, item in list(vars(value).items()):
            if type(item) is list:
                item = _frozen_list(item)
                object.__setattr__(value, key, item)
            freeze(item)
        object.__setattr__(value, "_frozen", True)


def _number(value) -> float:
    """``float(value)``, refusing booleans (TOML's true would pass as 1) and strings."""
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise TypeError
    return float(value)


def shown(values, digits: int = 4) -> str:
    """Numbers for a message, ``[a, b, c]`` to ``digits`` significant digits."""
    return "[" + ", ".join(f"{float(v):.{digits}g}" for v in values) + "]"


def floats(values) -> tuple:
    """Plain Python floats (NumPy's scalars would print as np.float64(...) in messages and files)."""
    return tuple(float(v) for v in values)


def vec3(value, name: str) -> np.ndarray:
    """Three finite numbers ``[x, y, z]``: exactly that shape (a nested ``[[x, y, z]]`` is refused,
    not flattened)."""
    try:
        if isinstance(value, (str, bytes, bool)) or any(isinstance(c, (bool, np.bool_, str)) for c in value):
            raise TypeError
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} = {value!r}: must be three numbers [x, y, z]") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} = {value!r}: must be three finite numbers [x, y, z]")
    return arr


def magnitude(v: np.ndarray) -> float:
    """A finite vector's length, scaled first so that no square overflows (a component near 1e308
    would read as inf, and NumPy would warn on stderr)."""
    top = float(np.max(np.abs(v)))
    if top == 0.0:
        return 0.0
    with np.errstate(over="ignore"):
        return top * float(np.linalg.norm(v / top))


def unit(value, name: str, what: str) -> np.ndarray:
    """A direction: three finite numbers, not all zero, scaled to length 1 (``what`` says what it
    is, for the message). One already of length 1 (to rounding) is kept as it is: normalising
    again moves a last bit, and a resumed run, validated from run.json, must see the direction
    the run recorded."""
    v = vec3(value, name)
    top = float(np.max(np.abs(v)))
    if top == 0.0:
        raise ValueError(f"{name} = {value!r}: must be non-zero ({what})")
    if top <= 1.0 and abs(float(np.dot(v, v)) - 1.0) < 1e-12:
        return v
    v = v / top
    return v / np.linalg.norm(v)


def box_corners(lower, upper, name: str) -> tuple[tuple, tuple]:
    """A box's ``lower`` and ``upper`` corners (points; upper above lower on every axis)."""
    lo = position(lower, f"{name}.lower")
    hi = position(upper, f"{name}.upper")
    if np.any(hi <= lo):
        raise ValueError(f"{name}: upper {floats(hi)} must exceed lower {floats(lo)} on every axis")
    return floats(lo), floats(hi)


def position(value, name: str) -> np.ndarray:
    """A point in the scene (metres): three finite numbers within ``MAX_COORDINATE`` of the origin."""
    arr = vec3(value, name)
    if np.any(np.abs(arr) > MAX_COORDINATE):
        raise ValueError(f"{name} = {value!r}: coordinates must lie within {MAX_COORDINATE:g} m of the origin")
    return arr


def positive(value, name: str, unit: str) -> float:
    try:
        v = _number(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} = {value!r}: must be a number > 0 ({unit})") from None
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} = {value!r}: must be > 0 ({unit})")
    return v


def in_range(value, name: str, lo: float, hi: float, unit: str, lo_open=False, hi_open=False) -> float:
    lb = "(" if lo_open else "["
    rb = ")" if hi_open else "]"
    try:
        v = _number(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} = {value!r}: must be a number in {lb}{lo:g}, {hi:g}{rb} ({unit})") from None
    lo_ok = v > lo if lo_open else v >= lo
    hi_ok = v < hi if hi_open else v <= hi
    if not (math.isfinite(v) and lo_ok and hi_ok):
        raise ValueError(f"{name} = {value!r}: must be in {lb}{lo:g}, {hi:g}{rb} ({unit})")
    return v


def flag(value, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} = {value!r}: must be true or false")
    return bool(value)


def folder_name(value, name: str) -> str:
    """A plain folder name (what a scene's ``name`` becomes: ``runs/NAME``): a string of at most
    :data:`MAX_NAME` characters, not empty, no path separator, not ``.`` or ``..`` nor starting
    with ``.`` (hidden, and the run's staging folders beside it are ``.NAME.new-PID``), no control
    characters."""
    if not isinstance(value, str):
        raise ValueError(f"{name} = {value!r}: must be a string (a folder name)")
    why = None
    if not value.strip():
        why = "must not be empty"
    elif "/" in value or "\\" in value:
        why = "must not contain a path separator (/ or \\)"
    elif value.startswith("."):
        why = "must not start with '.' (no '.', '..' or hidden folders)"
    elif any(unicodedata.category(c) in ("Cc", "Cs", "Zl", "Zp") for c in value):
        why = "must not contain control characters or line breaks"
    elif len(value) > MAX_NAME or len(value.encode("utf-8", "surrogatepass")) > 2 * MAX_NAME:
        why = f"must be at most {MAX_NAME} characters and {2 * MAX_NAME} bytes in UTF-8"
    if why:
        raise ValueError(f"{name} = {value[: 2 * MAX_NAME]!r}: {why}; it names the output folder runs/NAME")
    return value
