"""The pressure solve's warm starts and schemes, side by side on the same cases in one run: what
each costs in iterations and what it leaves (compression in a dam break, motion and pressure of
water at rest). The package's solve is relaxed Jacobi from the hydrostatic pressure (gated by the
advected density); the others are twins kept for measurement (benchmarks/solve_variants.py).
docs/pressure_solve.md discusses the results.

Cases:
1. Resting tank 0.4 x 0.8 x 0.2 m, water 0.6 m deep, 2 cm spacing (6,000 particles): settled for
   2 s, then run frame by frame (30 frames/s) for 0.5 s: iterations per step, the hydrostatic
   slope at every step (its spread around its own mean), mean and largest speed.
2. The 32,768-particle dam break (dam_break_cube), first 0.5 s, at eta 0.1 % and 0.03 %:
   iterations per step and per simulated second, mean compression, wall time.

Writes benchmarks/results/pressure_solve.json and pressure_solve.png.

    python benchmarks/pressure_solve.py [--quick] [--workers N]
"""

import argparse
import functools
import math
import time

import numpy as np
import warp as wp
from common import (
    RESULTS,
    check_cluster_options,
    cluster_options,
    header,
    measure_all,
    pyplot,
    save,
    saved,
    warm_once,
)

VARIANTS = [
    ("jacobi", "hydrostatic"),
    ("jacobi", "half"),
    ("jacobi", "full"),
    ("jacobi", "half_hydrostatic"),
    ("chebyshev", "half"),
    ("bb", "half"),
    ("bb", "full"),
    ("cg", "full"),
    ("twolevel", "hydrostatic"),
]


def simulation(scene, scheme, warm):
    import solve_variants

    import warp_iisph.sph.solvers as solvers
    from warp_iisph import Simulation

    scene.physics.warm_start = "half" if warm == "full" else warm  # its iteration floor follows
    scene.physics.validate()
    original = solvers.SOLVERS["iisph"]
    solvers.SOLVERS["iisph"] = lambda model: solve_variants.VariantIISPH(model, warm, scheme)
    try:
        return Simulation(scene, "cpu")
    finally:
        solvers.SOLVERS["iisph"] = original


def resting(scheme, warm, quick):
    from warp_iisph import Box, Scene
    from warp_iisph.analysis.hydrostatic import hydrostatic_slope

    warm_once()
    h, tank, depth = (0.04, (0.4, 0.8, 0.2), 0.6) if quick else (0.02, (0.4, 0.8, 0.2), 0.6)
    settle, measure = (0.5, 0.1) if quick else (2.0, 0.5)
    scene = Scene(spacing=h, tank=Box((0, 0, 0), tank), name="resting_tank")
    scene.add_fluid_box((0, 0, 0), (tank[0], depth, tank[2]))
    sim = simulation(scene, scheme, warm)
    out = {"case": "resting", "scheme": scheme, "warm": warm, "particles": sim.n_particles, "diverged": None}
    t0 = time.perf_counter()
    try:
        sim.advance(settle)
        rows = []

        def measure_step(rec):
            speed = np.linalg.norm(sim.velocities, axis=1)
            slope = hydrostatic_slope(sim.positions, sim.pressures, h, (0, 0, 0), tank, 1000.0, 9.81)
            rows.append((rec["iterations"], slope, float(speed.mean()), float(speed.max())))

        first = int(math.ceil(sim.time * 30.0)) + 1
        for frame in range(first, first + int(round(measure * 30))):
            sim.advance(frame / 30.0 - sim.time, callback=measure_step)
        its, slopes, mean_speed, max_speed = (np.asarray(c) for c in zip(*rows))
        out.update(
            iterations_per_step=float(its.mean()),
            slope_mean=float(slopes.mean()),
            slope_min=float(slopes.min()),
            slope_max=float(slopes.max()),
            slope_spread=float(np.abs(slopes / slopes.mean() - 1.0).max()),
            mean_speed=float(mean_speed.max()),
            max_speed=float(max_speed.max()),
        )
    except Exception as e:  # a variant that blows up is a result
        out["diverged"] = str(e)
    out["wall_seconds"] = time.perf_counter() - t0
    return out


def dam_break(scheme, warm, eta, quick):
    from warp_iisph.scene import load_scene

    warm_once()
    duration = 0.1 if quick else 0.5
    over = [f"physics.eta={eta}"] + (["spacing=0.06"] if quick else [])
    sim = simulation(load_scene("dam_break_cube", over), scheme, warm)
    out = {"case": "dam_break", "scheme": scheme, "warm": warm, "eta": eta, "particles": sim.n_particles}
    t0 = time.perf_counter()
    try:
        sim.advance(duration)
        out["diverged"] = None
    except Exception as e:
        out["diverged"] = str(e)
    wall = time.perf_counter() - t0
    st = sim.stats
    its = np.array([s["iterations"] for s in st])
    out.update(
        simulated_seconds=sim.time,
        steps=len(st),
        iterations_per_step=float(its.mean()) if len(st) else None,
        iterations_per_simulated_second=float(its.sum() / sim.time) if sim.time else None,
        mean_compression=float(np.mean([s["compression"] for s in st])) if len(st) else None,
        put_back=int(sum(s["wall_corrections"] + s["obstacle_corrections"] for s in st)),
        wall_seconds_per_simulated_second=wall / sim.time if sim.time else None,
    )
    return out


def label(r):
    return f"{r['scheme']}, {r['warm']} warm start"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="4 cm resting tank, the dam break at 6 cm for 0.1 s")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--replot", action="store_true", help="draw the chart again from the result file, run nothing")
    cluster_options(ap)
    args = ap.parse_args()
    check_cluster_options(ap, args)
    wp.config.log_level = wp.LOG_WARNING
    if args.replot:
        record, png = saved(args.out, "pressure_solve", args.quick)
        chart(record["runs"], png)
        return
    calls = [functools.partial(resting, s, w, args.quick) for s, w in VARIANTS]
    calls += [functools.partial(dam_break, s, w, eta, args.quick) for eta in (1e-3, 3e-4) for s, w in VARIANTS]
    rows = []

    def report(r):
        rows.append(r)
        if r["case"] == "resting":
            if r["diverged"]:
                print(f"resting, {label(r)}: DIVERGED: {r['diverged']}")
            else:
                print(
                    f"resting, {label(r)}: {r['iterations_per_step']:.1f} iterations/step, slope "
                    f"{r['slope_min']:.3f}..{r['slope_max']:.3f} (within {100 * r['slope_spread']:.1f} % of its mean), "
                    f"mean speed <= {100 * r['mean_speed']:.2f} cm/s, max <= {100 * r['max_speed']:.1f} cm/s"
                )
        elif r["iterations_per_step"] is None:
            print(f"dam break eta {100 * r['eta']:g} %, {label(r)}: DIVERGED at the first step: {r['diverged']}")
        else:
            end = f"; DIVERGED: {r['diverged']}" if r["diverged"] else ""
            print(
                f"dam break eta {100 * r['eta']:g} %, {label(r)}: {r['iterations_per_step']:.2f} iterations/step, "
                f"{r['iterations_per_simulated_second']:.0f}/simulated s, mean compression "
                f"{100 * r['mean_compression']:.4f} %, {r['wall_seconds_per_simulated_second']:.1f} s per simulated s, "
                f"{r['put_back']} put back{end}"
            )

    measure_all(args, calls, report)
    record = header("pressure_solve", variants=[list(v) for v in VARIANTS], runs=rows)
    chart(rows, save(record, args.out, "pressure_solve", args.quick))


def chart(rows, path):
    plt = pyplot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(15, 6.0), gridspec_kw={"width_ratios": [1.0, 1.15], "wspace": 0.9})
    colours = {v: f"C{i}" for i, v in enumerate(VARIANTS)}
    for r in rows:
        if r["case"] != "dam_break" or r["diverged"] or not r["iterations_per_step"]:
            continue
        c = colours[(r["scheme"], r["warm"])]
        ax.loglog(100 * r["mean_compression"], r["iterations_per_simulated_second"], "o" if r["eta"] > 5e-4 else "s",
                  color=c, label=f"{label(r)} (eta {100 * r['eta']:g} %)")  # fmt: skip
    ax.set_xlabel("mean compression (%)")
    ax.set_ylabel("pressure iterations per simulated second")
    ax.set_title("32k dam break, first 0.5 s: iterations against compression\n(circles eta 0.1 %, squares 0.03 %)")
    handles = {}
    for h, lab in zip(*ax.get_legend_handles_labels()):
        handles.setdefault(lab.split(" (eta")[0], h)
    ax.legend(handles.values(), handles.keys(), fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    lost = sorted({label(r) for r in rows if r["case"] == "dam_break" and r["diverged"]})
    if lost:
        ax.text(1.02, 0.0, "diverged:\n" + "\n".join(lost), transform=ax.transAxes, fontsize=7, va="bottom")
    rest = [r for r in rows if r["case"] == "resting"]
    names = [label(r) for r in rest]
    speeds = [100 * r["mean_speed"] if not r["diverged"] else np.nan for r in rest]
    bars = bx.barh(names, speeds, color=[colours[(r["scheme"], r["warm"])] for r in rest])
    bx.set_xscale("log")
    bx.set_ylim(-0.6, len(rest) - 0.4)  # a diverged variant's empty bar still gets its row
    finite = [v for v in speeds if np.isfinite(v)]
    bx.set_xlim(0.5 * min(finite), 60 * max(finite))  # room for the labels
    for b, r in zip(bars, rest):
        if r["diverged"]:
            text = "diverged"
        else:
            text = f"{r['iterations_per_step']:.1f} it/step, slope +-{100 * r['slope_spread']:.1f} %"
        x = b.get_width() if not r["diverged"] else bx.get_xlim()[0]
        bx.text(x, b.get_y() + b.get_height() / 2, " " + text, va="center", fontsize=7)
    bx.set_xlabel("largest mean speed while at rest (cm/s, log)")
    bx.set_title("Resting tank, frame by frame: motion, iterations, pressure spread")
    fig.subplots_adjust(left=0.06, right=0.97, bottom=0.1, top=0.86)
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
