"""SPHERIC Test 2 (the MARIN dam break onto a box, Kleefsman et al. 2005): the experiment's data and
the scores a run's probes get against it.

The data (``data/spheric_test2_marin.csv``, 1 kHz, 0-7.39 s): pressures ``P1`` .. ``P8`` (Pa) on
the box, P1-P4 on its face towards the water, P5-P8 on its top, and the water heights
``H_x0.496`` .. ``H_x2.638`` (m) at four gauges named by their x. The bundled scene
``spheric_test2`` places probes of the same names where the sensors are.

Scores, per sensor: the arrival of the first impact (the first rise above 1 kPa, interpolated
between samples), the mean over the plateau that follows (0.6-1.2 s), the peak with the
sampling rate it was found at (a peak depends on the rate and on the sensor's size as much as on
the flow, so it is reported, not scored); per gauge the RMS of the difference over 0-2 s (the
run's series interpolated at the experiment's samples) as a fraction of the initial depth 0.55 m.

Where a delay is made, reported beside the scores (not targets): the front's arrival at each gauge
downstream of the column (its level's first rise above 1 cm), and each sensor's arrival counted
from the front's passage at the gauge nearest the column (x = 1.488 m, 0.5 m from the gate), which
leaves out whatever the release itself delays or hurries. Beside these, two readings that say
which part of the flow is late: the time each downstream gauge's level first rises above 1, 3 and
5 cm (the front's thin tip against the water behind it; a particle 1-2.5 cm across cannot make a
tip thinner than itself), and the time the gauge in the column (x = 2.638 m, 0.65 m behind the
gate) first reads 1, 2 and 3 cm below its start (the release as the column feels it: where those
agree with the experiment's, the two time origins agree). That gauge also gives the lead of a
clock over the release: its level over 20-100 ms set against the exact release's, ``start - (1/2)
A_0 (t + lead)^2`` with ``A_0`` the top's acceleration there at the instant of release (2.03 m/s^2:
:func:`.release.release_surface_acceleration`, the fastest any gate lets it fall). A run released
at its t = 0 reads a lead near zero; a lead in the experiment's says its clock started after its
column began to fall.
"""

from __future__ import annotations

import csv
from importlib import resources

import numpy as np

from . import trapezoid
from .release import release_surface_acceleration

MARIN = "spheric_test2_marin.csv"
DEPTH = 0.55  # the water column's initial depth (m)
IMPACT = 1000.0  # a first impact is the first rise above this (Pa)
PLATEAU = (0.6, 1.2)  # the window of the plateau after the impact (s)
GAUGE_WINDOW = (0.0, 2.0)  # the window of the gauges' RMS error (s)
FRONT = 0.01  # the front has reached a gauge when its level first rises above this (m)
FRONT_DEPTHS = (0.01, 0.03, 0.05)  # the levels (m) whose first rise at each downstream gauge is reported
COLUMN = "H_x2.638"  # the gauge in the column, behind the gate
COLUMN_DROPS = (0.01, 0.02, 0.03)  # how far (m) below its start the column's level is reported falling
# the column (x from the gate at 1.992 m to the back wall at 3.22 m) and its gauge's distance from the back wall
COLUMN_WIDTH, COLUMN_GAUGE_FROM_BACK = 3.22 - 1.992, 3.22 - 2.638
LEAD_WINDOW = (0.02, 0.1)  # the column gauge's fall fitted for a clock's lead (s): 1-15 mm, a linear response
DOWNSTREAM = ("H_x1.488", "H_x0.992", "H_x0.496")  # the gauges the front reaches, nearest the column first
PRESSURES = tuple(f"P{k}" for k in range(1, 9))
FACE = PRESSURES[:4]  # P1-P4, on the box's face towards the water: the ones the targets score
GAUGES = ("H_x0.496", "H_x0.992", "H_x1.488", "H_x2.638")
# the targets of issue 29 at the finest resolution: arrival within 0.02 s, plateau within 15 %, the
# gauges' RMS within 5 % of the depth upstream of the box and 10 % behind it (x = 0.496)
ARRIVAL_TOLERANCE = 0.02
PLATEAU_TOLERANCE = 0.15
GAUGE_TOLERANCE = {"H_x0.496": 0.10, "H_x0.992": 0.05, "H_x1.488": 0.05, "H_x2.638": 0.05}


def load_marin() -> dict[str, np.ndarray]:
    """The experiment: ``{"t": times (s), "P1": ..., "H_x0.496": ...}``."""
    text = resources.files("warp_iisph.analysis.data").joinpath(MARIN).read_text()
    rows = list(csv.reader(line for line in text.splitlines() if line and not line.startswith("#")))
    head, values = rows[0], np.asarray(rows[1:], dtype=np.float64)
    out = {("t" if name == "t_s" else name): values[:, k] for k, name in enumerate(head)}
    return out


def arrival(t: np.ndarray, p: np.ndarray, threshold: float = IMPACT) -> float | None:
    """The time ``p`` first rises above ``threshold``, interpolated between the samples around it;
    ``None`` when it never does."""
    above = np.nonzero(p > threshold)[0]
    if len(above) == 0:
        return None
    k = int(above[0])
    if k == 0:
        return float(t[0])
    return float(t[k - 1] + (threshold - p[k - 1]) / (p[k] - p[k - 1]) * (t[k] - t[k - 1]))


def first_drop(t: np.ndarray, h: np.ndarray, drop: float, start: float) -> float | None:
    """The time ``h`` first falls ``drop`` below ``start``, interpolated; ``None`` when it never does."""
    return arrival(t, start - h, drop)


def window_mean(t: np.ndarray, y: np.ndarray, window=PLATEAU) -> float | None:
    """The time average of ``y`` over ``window`` (trapezoids over the samples in it)."""
    inside = (t >= window[0]) & (t <= window[1])
    if inside.sum() < 2:
        return None
    return float(trapezoid(y[inside], t[inside]) / (t[inside][-1] - t[inside][0]))


def peak(t: np.ndarray, p: np.ndarray, window=(0.0, 2.0)) -> dict:
    """The largest value over ``window``, when, and the sampling rate it was found at (1/s)."""
    inside = (t >= window[0]) & (t <= window[1])
    k = int(np.argmax(np.where(inside, p, -np.inf)))
    rate = (inside.sum() - 1) / (t[inside][-1] - t[inside][0]) if inside.sum() > 1 else 0.0
    return {"value": float(p[k]), "t": float(t[k]), "rate": float(rate)}


def gauge_rms(t: np.ndarray, h: np.ndarray, t_exp: np.ndarray, h_exp: np.ndarray, window=GAUGE_WINDOW) -> float | None:
    """RMS of ``h`` (interpolated at the experiment's samples) less the experiment's, over
    ``window``, as a fraction of :data:`DEPTH`; ``None`` when the run does not cover the window."""
    if len(t) < 2 or t[-1] < window[1] - 0.01:
        return None
    inside = (t_exp >= max(window[0], t[0])) & (t_exp <= window[1])
    diff = np.interp(t_exp[inside], t, h) - h_exp[inside]
    return float(np.sqrt(np.mean(diff**2)) / DEPTH)


def score(series: dict[str, tuple[np.ndarray, np.ndarray]], reference: dict | None = None) -> dict:
    """Every sensor and gauge of ``series`` (name -> (times, values)) scored against the
    experiment, beside the experiment's own values; each target's pass or fail."""
    ref = reference if reference is not None else load_marin()
    out = {}
    # the experiment's front at each downstream gauge; a sensor's transit counts from the first
    fronts = {name: arrival(ref["t"], ref[name], FRONT) for name in DOWNSTREAM}
    start = DOWNSTREAM[0]
    front_sim = arrival(*series[start], FRONT) if start in series else None
    front_exp = fronts[start]
    for name in PRESSURES:
        if name not in series:
            continue
        t, p = series[name]
        got = {"arrival": arrival(t, p), "plateau": window_mean(t, p), "peak": peak(t, p)}
        exp = {
            "arrival": arrival(ref["t"], ref[name]),
            "plateau": window_mean(ref["t"], ref[name]),
            "peak": peak(ref["t"], ref[name]),
        }
        row = {"sim": got, "experiment": exp}
        if got["arrival"] is not None:
            row["arrival_error"] = got["arrival"] - exp["arrival"]
        if got["plateau"] is not None:
            row["plateau_error"] = got["plateau"] / exp["plateau"] - 1.0
        if got["arrival"] is not None and front_sim is not None:
            row["transit"] = {"sim": got["arrival"] - front_sim, "experiment": exp["arrival"] - front_exp}
            row["transit_error"] = row["transit"]["sim"] - row["transit"]["experiment"]
        if name in FACE:
            row["arrival_ok"] = row.get("arrival_error") is not None and abs(row["arrival_error"]) <= ARRIVAL_TOLERANCE
            row["plateau_ok"] = row.get("plateau_error") is not None and abs(row["plateau_error"]) <= PLATEAU_TOLERANCE
        out[name] = row
    for name in GAUGES:
        if name not in series:
            continue
        t, h = series[name]
        rms = gauge_rms(t, h, ref["t"], ref[name])
        out[name] = {"rms": rms, "rms_ok": rms is not None and rms <= GAUGE_TOLERANCE[name]}
        if name in DOWNSTREAM:
            front = {"sim": arrival(t, h, FRONT), "experiment": fronts[name]}
            out[name]["front"] = front
            if front["sim"] is not None:
                out[name]["front_error"] = front["sim"] - front["experiment"]
        out[name].update(delay_readings(name, t, h, ref))
    return out


def delay_readings(name: str, t: np.ndarray, h: np.ndarray, reference: dict) -> dict:
    """The readings that say where a delay is made, for gauge ``name`` of a run (``t``, ``h``)
    beside the experiment (``reference``, :func:`load_marin`): a downstream gauge's
    ``front_depths``, the column's gauge's ``drops`` and ``lead``; nothing for the others."""
    t_exp, h_exp = reference["t"], reference[name]
    if name in DOWNSTREAM:
        return {"front_depths": front_depths(t, h, t_exp, h_exp)}
    if name == COLUMN:
        return {"drops": column_drops(t, h, t_exp, h_exp), "lead": timed(column_lead(t, h), column_lead(t_exp, h_exp))}
    return {}


def timed(sim: float | None, experiment: float | None) -> dict:
    """A run's time and the experiment's, and their difference where both are known."""
    out = {"sim": sim, "experiment": experiment}
    if sim is not None and experiment is not None:
        out["error"] = sim - experiment
    return out


def front_depths(t, h, t_exp, h_exp) -> dict:
    """At a downstream gauge: when its level first rises above each of :data:`FRONT_DEPTHS`, the
    run's and the experiment's (keys in cm)."""
    return {f"{100 * d:g}": timed(arrival(t, h, d), arrival(t_exp, h_exp, d)) for d in FRONT_DEPTHS}


def column_drops(t, h, t_exp, h_exp) -> dict:
    """At the column's gauge: when its level first falls each of :data:`COLUMN_DROPS` below its
    start (its median over the first 30 ms, before the fall: the experiment's gauge reads 0.547 m
    at rest), the run's and the experiment's (keys in cm)."""

    def fall(t, h, d):
        return first_drop(t, h, d, float(np.median(h[t < t[0] + 0.03])))

    return {f"{100 * d:g}": timed(fall(t, h, d), fall(t_exp, h_exp, d)) for d in COLUMN_DROPS}


def column_lead(t: np.ndarray, h: np.ndarray) -> float | None:
    """How long before its t = 0 a column's release began, from its gauge at x = 2.638 m: the
    ``lead`` (s) whose ``start - (1/2) A_0 (t + lead)^2`` fits the level over :data:`LEAD_WINDOW`
    in least squares (the start fitted with it: the level at rest is not read before the fall),
    ``A_0`` the exact release's acceleration of the top there (see the module); ``None`` without
    samples in the window or where no lead within 0.1 s fits (the best at the search's edge).
    Searched over -0.1 .. 0.1 s in 0.1 ms steps (the fit is not linear in the lead)."""
    inside = (t >= LEAD_WINDOW[0]) & (t <= LEAD_WINDOW[1])
    if inside.sum() < 5:
        return None
    a0 = float(release_surface_acceleration(COLUMN_GAUGE_FROM_BACK, COLUMN_WIDTH, DEPTH))
    leads = np.arange(-1000, 1001) * 1e-4
    fall = 0.5 * a0 * np.clip(t[inside][None, :] + leads[:, None], 0.0, None) ** 2
    misfit = np.var(h[inside][None, :] + fall, axis=1)  # the best start for each lead is the mean
    best = int(np.argmin(misfit))
    return None if best in (0, len(leads) - 1) else float(leads[best])
