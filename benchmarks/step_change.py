"""Resting water through a change of the step length: the 0.6 m tank (0.4 x 0.8 x 0.2 m, 2 cm, 6,000
particles) settled 2 s at the CFL rule's step (the last ones fitted to land on 2 s), then stepped
by hand 6 times at 2 ms and 18 times back at the step it settled at. The hydrostatic slope (rho0 g)
at each of those 24 steps and its largest departure from their mean, for the defaults and for
tighter solves (smaller eta, higher iteration floors) and the half warm start: what part of the
kick at a step-length change is the solve's unconverged error. docs/pressure_solve.md discusses the
results.

Writes benchmarks/results/step_change.json and step_change.png.

    python benchmarks/step_change.py [--quick] [--workers N]
"""

import argparse
import functools
import time

import numpy as np
import warp as wp
from common import RESULTS, check_cluster_options, cluster_options, header, measure_all, pyplot, save, saved, warm_once

# physics settings besides the defaults; each settles with its own settings
VARIANTS = [
    {},
    {"min_iterations": 5},
    {"min_iterations": 6},
    {"min_iterations": 8},
    {"min_iterations": 20},
    {"min_iterations": 40},
    {"eta": 3e-4},
    {"eta": 1e-4},
    {"eta": 3e-5, "max_iterations": 1000},
    {"eta": 1e-5, "max_iterations": 2000},
    {"warm_start": "half"},
    {"short": 2.5e-3},
    {"short": 1.5e-3},
    {"short": 1.5e-3, "eta": 3e-5, "max_iterations": 1000},
]
QUICK = [{}, {"min_iterations": 8}, {"warm_start": "half"}]  # --quick's variants
SHORT = 2.0e-3  # s: the step taken by hand, unless a variant names its own ("short")


def name(settings: dict) -> str:
    shown = {k: v for k, v in settings.items() if k != "max_iterations"}
    if "short" in shown:
        shown["short"] = f"{1000 * shown['short']:g} ms"
    return ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in shown.items()) or "defaults"


def step_change(settings: dict, quick: bool) -> dict:
    from warp_iisph import Box, Physics, Scene, Simulation
    from warp_iisph.analysis.hydrostatic import hydrostatic_slope

    warm_once()
    physics = {k: v for k, v in settings.items() if k != "short"}
    short = settings.get("short", SHORT)
    h, tank, depth = (0.04, (0.4, 0.8, 0.2), 0.6) if quick else (0.02, (0.4, 0.8, 0.2), 0.6)
    scene = Scene(spacing=h, tank=Box((0, 0, 0), tank), physics=Physics(**physics), name="resting_tank")
    scene.add_fluid_box((0, 0, 0), (tank[0], depth, tank[2]))
    sim = Simulation(scene, "cpu")
    t0 = time.perf_counter()
    sim.advance(0.5 if quick else 2.0)
    cfl_step = sim.stats[-1]["dt"]  # the CFL rule's step, as fitted to land on the end time

    def slope(rec):
        assert rec["escaped"] == rec["non_finite"] == rec["wall_corrections"] == 0
        return hydrostatic_slope(sim.positions, sim.pressures, h, (0, 0, 0), tank, 1000.0, 9.81)

    before = [slope(sim.step(cfl_step)) for _ in range(3)]
    steps = [short] * 6 + [cfl_step] * 18
    slopes = np.asarray([slope(sim.step(dt)) for dt in steps])
    its = [s["iterations"] for s in sim.stats[-len(steps) :]]
    return {
        "settings": settings,
        "name": name(settings),
        "particles": sim.n_particles,
        "cfl_step": cfl_step,
        "steps": steps,
        "short_step": short,
        "slope_before": float(np.mean(before)),
        # the first short step's jump of the slope, and that over (dt_before / dt_after)^2 - 1: the
        # share of the resting pressure the solve draws from the state's compression, which it
        # turns into pressure as 1 / dt^2
        "first_jump": float(slopes[0] - np.mean(before)),
        "jump_per_stiffening": float((slopes[0] - np.mean(before)) / ((cfl_step / short) ** 2 - 1.0)),
        "slopes": slopes.tolist(),
        "spread": float(np.abs(slopes / slopes.mean() - 1.0).max()),
        "iterations": its,
        "iterations_per_step": float(np.mean(its)),
        "wall_seconds": time.perf_counter() - t0,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="4 cm tank, settled 0.5 s, three of the variants")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--replot", action="store_true", help="draw the chart again from the result file, run nothing")
    cluster_options(ap)
    args = ap.parse_args()
    check_cluster_options(ap, args)
    wp.config.log_level = wp.LOG_WARNING
    if args.replot:
        record, png = saved(args.out, "step_change", args.quick)
        chart(record["runs"], png)
        return
    rows = []

    def report(r):
        rows.append(r)
        print(
            f"{r['name']:>28}: slope {r['slope_before']:.4f} before, {min(r['slopes']):.4f}..{max(r['slopes']):.4f} "
            f"through {1000 * r['short_step']:g} ms and back to {1000 * r['cfl_step']:.2f} ms: within "
            f"{100 * r['spread']:.2f} % of its mean, {r['iterations_per_step']:.1f} iterations/step; first jump "
            f"{100 * r['first_jump']:+.2f} %, {r['jump_per_stiffening']:.4f} per unit of (dt / dt_short)^2 - 1"
        )

    variants = QUICK if args.quick else VARIANTS
    measure_all(args, [functools.partial(step_change, v, args.quick) for v in variants], report)
    record = header("step_change", short_step=SHORT, variants=variants, runs=rows)
    chart(rows, save(record, args.out, "step_change", args.quick))


def chart(rows, path):
    plt = pyplot()
    fig, (ax, bx, cx) = plt.subplots(1, 3, figsize=(18, 4.8))
    for k, r in enumerate(rows):
        colour = plt.cm.tab20(k % 20)
        ax.plot(np.arange(1, len(r["slopes"]) + 1), r["slopes"], "o-", ms=3, color=colour, label=r["name"])
        bx.semilogx(r["iterations_per_step"], 100 * r["spread"], "o", color=colour)
        bx.annotate(r["name"], (r["iterations_per_step"], 100 * r["spread"]), fontsize=7, xytext=(4, 2),
                    textcoords="offset points")  # fmt: skip
        ratio = (r["cfl_step"] / r.get("short_step", SHORT)) ** 2 - 1.0
        if "first_jump" in r:
            cx.plot(ratio, 100 * r["first_jump"], "o", color=colour)
            cx.annotate(r["name"], (ratio, 100 * r["first_jump"]), fontsize=7, xytext=(4, 2),
                        textcoords="offset points")  # fmt: skip
    ax.axvspan(0.5, 6.5, color="0.9", zorder=0)
    ax.set_xlabel("step (shaded: the shorter step by hand; then the CFL step again)")
    ax.set_ylabel("hydrostatic slope / rho0 g")
    ax.set_title("0.6 m resting tank through a change of the step length")
    ax.legend(fontsize=7)
    bx.axhline(1.0, color="0.5", ls=":", lw=1)
    bx.set_xlabel("pressure iterations per step (log)")
    bx.set_ylabel("largest departure of the slope from its mean (%)")
    bx.set_title("the kick against the solve's cost")
    plain = [r for r in rows if "first_jump" in r and set(r["settings"]) <= {"short"}]  # the defaults' three steps
    if len(plain) > 1:
        x = np.array([(r["cfl_step"] / r["short_step"]) ** 2 - 1.0 for r in plain])
        c = float(np.dot(x, [r["first_jump"] for r in plain]) / np.dot(x, x))
        xs = np.linspace(0.0, x.max(), 10)
        cx.plot(xs, 100 * c * xs, "--", color="0.4", lw=1, label=f"defaults: {c:.4f} x ((dt / dt_short)^2 - 1)")
        cx.legend(fontsize=7, loc="upper left")
    cx.set_xlabel("(dt before / dt after)^2 - 1")
    cx.set_ylabel("first step's jump of the slope (% of rho0 g)")
    cx.set_title("the jump grows as the solve's stiffness 1 / dt^2")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
