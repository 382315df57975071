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
leaves out whatever the release itself delays or hurries.
"""

from __future__ import annotations

import csv
from importlib import resources

import numpy as np

from . import trapezoid

MARIN = "spheric_test2_marin.csv"
DEPTH = 0.55  # the water column's initial depth (m)
IMPACT = 1000.0  # a first impact is the first rise above this (Pa)
PLATEAU = (0.6, 1.2)  # the window of the plateau after the impact (s)
GAUGE_WINDOW = (0.0, 2.0)  # the window of the gauges' RMS error (s)
FRONT = 0.01  # the front has reached a gauge when its level first rises above this (m)
DOWNSTREAM = ("H_x1.488", "H_x0.992", "H_x0.496")  # the gauges the front reaches, nearest the column first
PRESSURES = tuple(f"P{k}" for k in range(1, 9))
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
        if name in ("P1", "P2", "P3", "P4"):
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
    return out
