"""Whether a simulation state (``Simulation.checkpoint``'s arrays) makes sense for a scene, checked
in full before any of it is used: a restore then either takes the whole state or leaves the
simulation as it was.

Each check raises ``ValueError`` saying what makes no sense, in words a caller can put after the
state's name (a run's checkpoint file, ``checkpoint:`` for the Python API): keys missing, arrays of
the wrong shape or kind, non-finite particles, ids repeated or beyond the next one, a time or step
count out of range, particles outside the scene's domain, free bodies' state that is not one
finite row per body with unit quaternions (or present where the scene has none), and the
emitters' and sinks' clocks and which of the nozzles' last layers came in.
"""

from __future__ import annotations

import math

import numpy as np

from ..scene.checks import MAX_PARTICLES
from ..scene.settings import METHODS
from ..setup.model import PARTICLE_FIELDS
from .flows import RECENT

# a scene with free bodies: their state (Simulation.checkpoint), by key and width
BODY_KEYS = {
    "bodies_position": 3,
    "bodies_orientation": 4,
    "bodies_velocity": 3,
    "bodies_momentum": 3,
    "bodies_acceleration": 3,
    "bodies_angular_acceleration": 3,
    "bodies_coupled": 3,
    "bodies_coupled_angular": 3,
}


def scalar(state: dict, key: str, kind: str):
    """``state[key]`` as one value of ``kind`` (``"int"``, or NumPy's kind letters: ``"f"``, ``"U"``)."""
    a = np.asarray(state[key])
    if a.shape != () or not (np.issubdtype(a.dtype, np.integer) if kind == "int" else a.dtype.kind in kind):
        raise ValueError(f"{key} is {a.dtype}{list(a.shape)}, not one {'integer' if kind == 'int' else 'value'}")
    return a.item()


def array(state: dict, key: str, shape: tuple, integer: bool = False) -> np.ndarray:
    """``state[key]`` as an array of ``shape``, integers or finite floats."""
    a = np.asarray(state[key])
    ok = np.issubdtype(a.dtype, np.integer) if integer else np.issubdtype(a.dtype, np.floating)
    if a.shape != shape or not ok:
        raise ValueError(f"{key} is {a.dtype}{list(a.shape)}, not {'integers' if integer else 'floats'}{list(shape)}")
    if not integer and not np.all(np.isfinite(a)):
        raise ValueError(f"{key} holds non-finite values")
    return a


def check_state(state: dict, scene, domain=None, carried=()) -> tuple[float, int, int]:
    """Check ``state`` against ``scene`` (the particles within ``domain``, ``(lower, upper)``,
    where given; the solver's ``carried`` warm starts); returns its time, step count and next id."""
    for key in (*PARTICLE_FIELDS, "time", "step_count", "method", "max_speed2"):
        if key not in state:
            raise ValueError(f"has no {key}")
    time, steps = scalar(state, "time", "f"), scalar(state, "step_count", "int")
    method = scalar(state, "method", "U")
    if method not in METHODS:
        raise ValueError(f"method = {method!r}: not one of {', '.join(METHODS)}")
    if not (math.isfinite(time) and time >= 0.0):
        raise ValueError(f"time = {time!r}: must be finite and >= 0")
    if steps < 0:
        raise ValueError(f"step_count = {steps}: must be >= 0")
    x = np.asarray(state["x"])
    n = len(x) if x.ndim >= 1 else -1
    next_id = scalar(state, "next_id", "int") if "next_id" in state else n
    if not 0 <= n <= next_id <= MAX_PARTICLES:
        raise ValueError(f"next_id = {next_id}: must be at least the particle count ({n}) and at most {MAX_PARTICLES}")
    x = array(state, "x", (n, 3))
    array(state, "v", (n, 3))
    if np.any(array(state, "rho", (n,)) < 0.0):
        raise ValueError("rho holds negative densities")
    array(state, "p", (n,))
    ids = array(state, "id", (n,), integer=True)
    if n and (ids.min() < 0 or ids.max() >= next_id or len(np.unique(ids)) != n):
        raise ValueError(f"id: {n} particle ids must be distinct and in [0, next_id = {next_id})")
    for name in carried:
        if f"carried_{name}" not in state:
            raise ValueError(f"has no {name} (the {method} solver's warm start)")
    for key in [k for k in state if k.startswith("carried_")]:
        array(state, key, (n,))
    if np.any(array(state, "max_speed2", (1,)) < 0.0):
        raise ValueError("max_speed2 must be >= 0")
    if "sub_left" in state or "sub_done" in state:  # a fixed step being cut (older states: none)
        if np.any(array(state, "sub_left", (1,)) < 0.0) or np.any(array(state, "sub_done", (1,), integer=True) < 0):
            raise ValueError("sub_left and sub_done must be >= 0")
    if scene.bodies:  # the free bodies' state: one row per body, finite, unit quaternions
        for key, width in BODY_KEYS.items():
            if key not in state:
                raise ValueError(f"has no {key} (the free bodies' state)")
            array(state, key, (len(scene.bodies), width))
        if np.any(np.abs(np.linalg.norm(state["bodies_orientation"], axis=1) - 1.0) > 1e-6):
            raise ValueError("bodies_orientation holds quaternions that are not of unit length")
    elif any(k.startswith("bodies_") for k in state):
        raise ValueError("holds free bodies' state; the scene has no bodies")
    if scene.emitters or scene.sinks:
        for key in ("flows_next_time", "flows_next_check", "flows_counts"):
            if key not in state:
                raise ValueError(f"has no {key} (the emitters' and sinks' clocks)")
        if np.any(array(state, "flows_next_time", (len(scene.emitters),)) < 0.0):
            raise ValueError("flows_next_time must be >= 0")
        if not scalar(state, "flows_next_check", "f") >= 0.0:
            raise ValueError("flows_next_check must be >= 0")
        if np.any(array(state, "flows_counts", (4,), integer=True) < 0):
            raise ValueError("flows_counts must be >= 0")
        if "flows_poured_recently" in state:  # older states have none
            recent = array(state, "flows_poured_recently", (len(scene.emitters),), integer=True)
            if np.any((recent < 0) | (recent >= 2**RECENT)):
                raise ValueError(f"flows_poured_recently must hold {RECENT} bits a nozzle (0 to {2**RECENT - 1})")
    if domain is not None and outside(x, domain):
        raise ValueError("holds particles outside the scene's domain; not a state of this scene")
    return float(time), int(steps), int(next_id)


def outside(x: np.ndarray, domain) -> bool:
    """Whether any of the positions ``x`` lies outside ``domain``, ``(lower, upper)``."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in domain)
    return bool(len(x)) and bool(np.any(x < lo) or np.any(x > hi))
