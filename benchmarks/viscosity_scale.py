"""What the default viscosity does to a dam break's front, at the scale of the experiment that
checks it: the measurements behind docs/physics.md 6.6.

The default viscosity is a fixed kinematic viscosity, 0.01 m^2/s (`physics.viscosity = 0.05` in
the report's form), ten thousand times water's. A flow's Reynolds number, and with it how much the
viscosity slows the flow, then depends on the scene's size, where water's would not.

1. Martin & Moyce at nx particles across the column (validation.py's set-up) at a = 0.3 m (the
   validation's size) and at a = 2.25 in = 0.05715 m (the experiment's own column), at the default
   viscosity and without viscosity: the front's errors against both series (unshifted, with the
   declared offset Delta T = 0.175, the best offset) and its speed dZ/dT over 1.4 <= T <= 3.
   Without viscosity the dimensionless front does not depend on the size, as an inviscid flow's
   must not.
2. A layer 0.1 m deep and 0.6 m long, launched along a free-slip floor at 2 m/s (1 cm spacing):
   its mean velocity (what the walls take from it: a free-slip floor takes nothing) and how fast
   its front runs ahead of it (Ritter's ideal: 2 sqrt(g d) = 1.98 m/s), at the default viscosity
   and without.
3. SPHERIC Test 2 (the bundled scene) at --spacings for --duration s at each of --viscosities: the
   sensors' arrivals, the plateaus (where the run reaches 1.2 s), the gauges and the front's
   depths, scored as validation.py scores them.

Writes benchmarks/results/viscosity_scale.json (the parts not run this time kept from the file
there) and viscosity_scale.png.

    python benchmarks/viscosity_scale.py [--parts martin_moyce,layer,spheric] [--nx 20]
        [--spacings 0.025,0.016667] [--viscosities 0.05,0.01,0] [--duration 2.0] [--tag NAME]

--tag stores the SPHERIC runs under NAME (default "spheric"), so a run at another spacing or
duration sits beside the others in the same file.
"""

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import validation
import warp as wp
from common import RESULTS, header, keep_parts, pyplot, save, saved

from warp_iisph import Physics, Simulation
from warp_iisph.analysis import spheric as marin
from warp_iisph.analysis.dam_break import load_martin_moyce
from warp_iisph.scene import load_scene

PARTS = ("martin_moyce", "layer", "spheric")
EXPERIMENT_A = 0.05715  # Martin & Moyce's larger column, 2.25 in
DEFAULT_MU = Physics().viscosity


def martin_moyce(nx: int, a: float, mu: float) -> dict:
    r = validation.martin_moyce(nx, a=a, viscosity=mu)
    keys = ("nx", "a", "spacing", "particles", "steps", "wall_seconds", "diverged", "T", "Z")
    out = {k: r[k] for k in keys}
    for series in ("a_2250", "a_1125"):
        for k in ("error_", "error_shifted_", "best_offset_", "error_best_", "speed_error_"):
            out[k + series] = r.get(k + series)
    return {"viscosity": mu, **out}


LAYER = """
name = "sliding_layer"
spacing = {spacing}
[tank]
lower = [0.0, 0.0, 0.0]
upper = [3.0, 0.4, 0.2]
[[fluids]]
lower = [0.2, 0.0, 0.0]
upper = [0.8, 0.1, 0.2]
"""


def sliding_layer(mu: float, spacing: float = 0.01, speed: float = 2.0, duration: float = 0.4) -> dict:
    """The layer launched at ``speed``: its mean velocity and its front every 50 ms."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sliding_layer.toml"
        path.write_text(LAYER.format(spacing=spacing))
        scene = load_scene(str(path), [f"physics.viscosity={mu!r}"])
    sim = Simulation(scene, "cpu", history=4)
    v = sim.state.v.numpy()
    v[: sim.state.n, 0] = speed
    sim.state.v.assign(v)
    t0, rows = time.perf_counter(), [(0.0, speed, float(sim.positions[:, 0].max()))]
    while sim.time < duration - 1e-9:
        sim.advance(0.05)
        rows.append((sim.time, float(sim.velocities[:, 0].mean()), float(sim.positions[:, 0].max())))
    t, u, front = (np.array(c) for c in zip(*rows))
    ahead = float((front[-1] - front[-3]) / (t[-1] - t[-3]) - u[-1])  # the front's lead, last 0.1 s
    return {
        "viscosity": mu,
        "spacing": spacing,
        "particles": sim.n_particles,
        "wall_seconds": time.perf_counter() - t0,
        "t": t.tolist(),
        "mean_velocity": u.tolist(),
        "front": front.tolist(),
        "front_lead": ahead,
        "ritter_lead": 2.0 * float(np.sqrt(9.81 * 0.1)),
    }


def spheric(spacing: float, mu: float, duration: float) -> dict:
    r = validation.spheric(spacing, duration, overrides=(f"physics.viscosity={mu!r}",))
    sc = r["scores"]
    row = {
        "viscosity": mu,
        "spacing": spacing,
        "duration": duration,
        "particles": r["particles"],
        "steps": r["steps"],
        "wall_seconds": r["wall_seconds"],
        "diverged": r["diverged"],
        "arrival_error": {p: sc[p].get("arrival_error") for p in marin.FACE},
        "transit_error": {p: sc[p].get("transit_error") for p in marin.FACE},
        "front_depths": {g: sc[g].get("front_depths") for g in marin.DOWNSTREAM},
        "column_drops": sc[marin.COLUMN].get("drops"),
    }
    if duration >= marin.PLATEAU[1]:
        row["plateau_error"] = {p: sc[p].get("plateau_error") for p in marin.FACE}
    if duration >= marin.GAUGE_WINDOW[1]:
        row["gauge_rms"] = {g: sc[g].get("rms") for g in marin.GAUGES}
    keep = validation._thinned(np.asarray(r["t"]), 0.005)
    row["t"] = [r["t"][k] for k in keep]
    row["series"] = {n: [r["series"][n][k] for k in keep] for n in (*marin.FACE, *marin.GAUGES)}
    return row


def ms(x):
    return "-" if x is None else f"{1e3 * x:+.0f}"


def pct(x):
    return "-" if x is None else f"{1e2 * x:+.0f}"


def describe_spheric(r: dict) -> str:
    line = (
        f"SPHERIC {r['spacing']:.4g} m, viscosity {r['viscosity']:g}, {r['duration']:g} s: arrivals P1-P4 "
        + " / ".join(ms(r["arrival_error"][p]) for p in marin.FACE)
        + " ms; front at x = 1.488 (1 / 3 / 5 cm) "
        + " / ".join(ms(r["front_depths"]["H_x1.488"][k].get("error")) for k in ("1", "3", "5"))
        + " ms"
    )
    if "plateau_error" in r:
        line += "; plateaus " + " / ".join(pct(r["plateau_error"][p]) for p in marin.FACE) + " %"
    if "gauge_rms" in r:
        line += "; gauges " + " / ".join(f"{100 * r['gauge_rms'][g]:.1f}" for g in marin.GAUGES) + " %"
    return line + f" ({r['particles']:,} particles, {r['wall_seconds']:.0f} s)"


def chart(record: dict, path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(22, 5.2))
    ax = axes[0]
    ref = load_martin_moyce()
    for name, pts in ref.items():
        pts = pts[pts[:, 0] <= 3.2]
        ax.plot(
            pts[:, 0], pts[:, 1], "k" + ("o" if name == "a_2250" else "s"), ms=4, mfc="none", label=f"experiment {name}"
        )
    for r in record.get("martin_moyce", []):
        style = "-" if r["viscosity"] > 0 else "--"
        ax.plot(
            r["T"],
            r["Z"],
            style,
            label=f"a = {r['a']:.3g} m, viscosity {r['viscosity']:g}: speed {pct(r['speed_error_a_2250'])} %",
        )
    ax.set(
        xlabel="T = t sqrt(2g/a)",
        ylabel="Z = x/a",
        title="Martin & Moyce, unshifted: the size matters with viscosity",
        xlim=(0, 3.2),
    )
    ax.legend(fontsize=7)
    ax = axes[1]
    for r in record.get("layer", []):
        ax.plot(
            r["t"],
            np.asarray(r["front"]) - 0.8 - 2.0 * np.asarray(r["t"]),
            label=f"viscosity {r['viscosity']:g}: lead {r['front_lead']:.2f} m/s",
        )
    if record.get("layer"):
        t = np.asarray(record["layer"][0]["t"])
        lead = record["layer"][0]["ritter_lead"]
        ax.plot(t, lead * t, "k:", label=f"Ritter (ideal), {lead:.2f} m/s")
    ax.set(xlabel="t (s)", ylabel="front ahead of the layer's motion (m)", title="A 0.1 m layer sliding at 2 m/s, 1 cm")
    ax.legend(fontsize=8)
    ax = axes[2]
    runs = [r for key in record if key.startswith("spheric") for r in record[key]]
    for spacing in sorted({r["spacing"] for r in runs}, reverse=True):
        rows = sorted((r for r in runs if r["spacing"] == spacing), key=lambda r: r["viscosity"])
        for k, p in enumerate(marin.FACE):
            ax.plot(
                [r["viscosity"] for r in rows],
                [1e3 * (r["arrival_error"][p] or np.nan) for r in rows],
                ("*" if spacing < 0.015 else "o") + "-",
                ms=10 if spacing < 0.015 else 6,
                color=f"C{k}",
                alpha=0.4 + 0.6 * (spacing < 0.02),
                label=f"{p}, {spacing:.3g} m",
            )
    ax.axhspan(-20, 20, color="0.9", label="target +-20 ms")
    ax.set(xlabel="physics.viscosity (report's form; the default 0.05)", ylabel="arrival - experiment's (ms)")
    ax.set_title("SPHERIC Test 2: first impact's arrival")
    ax.legend(fontsize=6, ncol=2)
    ax = axes[3]
    for spacing in sorted({r["spacing"] for r in runs if "plateau_error" in r}, reverse=True):
        rows = sorted(
            (r for r in runs if r["spacing"] == spacing and "plateau_error" in r), key=lambda r: r["viscosity"]
        )
        mu = [r["viscosity"] for r in rows]
        alpha = 0.4 + 0.6 * (spacing < 0.02)
        for k, p in enumerate(marin.FACE):
            ax.plot(
                mu,
                [100 * r["plateau_error"][p] for r in rows],
                "o-",
                color=f"C{k}",
                alpha=alpha,
                label=f"{p} plateau, {spacing:.3g} m",
            )
        if all("gauge_rms" in r for r in rows):
            ax.plot(
                mu,
                [100 * r["gauge_rms"]["H_x0.496"] for r in rows],
                "s--",
                color="k",
                alpha=alpha,
                label=f"gauge behind the box (RMS), {spacing:.3g} m",
            )
    ax.axhspan(-15, 15, color="0.9", label="plateau target +-15 %")
    ax.axhline(10, color="k", lw=0.8, ls=":")
    ax.set(
        xlabel="physics.viscosity",
        ylabel="% (plateau error; gauge RMS / 0.55 m)",
        title="SPHERIC Test 2: plateaus and the gauge behind the box",
    )
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", default=",".join(PARTS))
    ap.add_argument("--nx", type=int, default=20)
    ap.add_argument("--spacings", default="0.025,0.016667")
    ap.add_argument("--viscosities", default="0.05,0.01,0")
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--tag", default="spheric", help="the record's key for this run's SPHERIC runs")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--replot", action="store_true", help="redraw the chart from the saved file, running nothing")
    args = ap.parse_args()
    if args.replot:
        record, path = saved(args.out, "viscosity_scale")
        chart(record, path)
        return
    parts = args.parts.split(",")
    if any(p not in PARTS for p in parts) or not args.tag.startswith("spheric"):
        ap.error(f"--parts among {', '.join(PARTS)}; --tag starting with 'spheric'")
    wp.config.log_level = wp.LOG_WARNING
    record = header("viscosity_scale")
    mus = [float(v) for v in args.viscosities.split(",")]
    if "martin_moyce" in parts:
        record["martin_moyce"] = []
        for a in (0.3, EXPERIMENT_A):
            for mu in (DEFAULT_MU, 0.0):
                r = martin_moyce(args.nx, a, mu)
                record["martin_moyce"].append(r)
                print(
                    f"Martin & Moyce nx {args.nx}, a = {a:g} m, viscosity {mu:g}: unshifted "
                    f"{pct(r['error_a_2250'])} / {pct(r['error_a_1125'])} %, with Delta T 0.175 "
                    f"{100 * r['error_shifted_a_2250']:.1f} / {100 * r['error_shifted_a_1125']:.1f} %, best offset "
                    f"{r['best_offset_a_2250']:.3f}, speed {pct(r['speed_error_a_2250'])} / "
                    f"{pct(r['speed_error_a_1125'])} %",
                    flush=True,
                )
    if "layer" in parts:
        record["layer"] = []
        for mu in (DEFAULT_MU, 0.0):
            r = sliding_layer(mu)
            record["layer"].append(r)
            print(
                f"layer, viscosity {mu:g}: mean velocity {r['mean_velocity'][0]:.3f} -> "
                f"{r['mean_velocity'][-1]:.4f} m/s "
                f"in {r['t'][-1]:.2f} s; front's lead {r['front_lead']:.2f} m/s (Ritter {r['ritter_lead']:.2f})",
                flush=True,
            )
    if "spheric" in parts:
        record[args.tag] = []
        for spacing in (float(v) for v in args.spacings.split(",")):
            for mu in mus:
                r = spheric(spacing, mu, args.duration)
                record[args.tag].append(r)
                print(describe_spheric(r), flush=True)
    # the parts and SPHERIC tags not run this time kept, each with the day it was measured
    path = Path(args.out) / "viscosity_scale.json"
    tags = {k for k in json.loads(path.read_text()) if k.startswith("spheric")} if path.is_file() else set()
    kept = {k: (k,) for k in ("martin_moyce", "layer", *sorted(tags | {args.tag}))}
    keep_parts(record, args.out, "viscosity_scale", kept, {k for k in kept if k in record}, False)
    chart(record, save(record, args.out, "viscosity_scale", False))


if __name__ == "__main__":
    main()
