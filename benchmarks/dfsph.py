"""DFSPH against IISPH on the 32,768-particle dam break (a 0.96 m cube of water in a 4 x 3 x 1.5 m
tank, spacing 3 cm, eta 0.1 %, as benchmarks/thread_scaling.py runs it): fixed steps of 5, 9, 10
and 11 ms (the neighbours of 10 ms show whether holding it is a margin or luck), and the CFL
rule (CFL 0.5, dt <= 5 ms), each for 2 simulated seconds with 2 threads; a fixed step is taken
as it is (physics.substeps = false: the methods' own limits). Per
run: the time reached (a run stops at a divergence: a particle faster than the derived limit,
outside the tank or not finite), the mean and worst compression max(rho/rho0 - 1, 0) the
particles reached, mean iterations (DFSPH: both solves), the containment's last-line
corrections, and wall seconds per simulated second. Writes benchmarks/results/dfsph.json and .png.

    python benchmarks/dfsph.py [--duration 2.0] [--threads 2] [--cases 0.005,0.009,0.01,0.011,cfl] [--quick] [--replot]
"""

import argparse
import time

import numpy as np
from common import RESULTS, header, pyplot, save, saved, warm_up

from warp_iisph import DivergenceError, Simulation, scenes
from warp_iisph.engine.launch import set_threads

METHODS = ("iisph", "dfsph")


def run(method: str, case: str, particles: int, duration: float) -> dict:
    """One run of the dam break; ``case`` is a fixed dt in seconds or ``cfl``."""
    dt = None if case == "cfl" else float(case)
    sim = Simulation(
        scenes.dam_break_cube(
            particles=particles, method=method, eta=1e-3, cfl=0.5, dt_max=5e-3, dt=dt, substeps=False
        ),
        "cpu",
    )
    diverged = None
    t0 = time.perf_counter()
    try:
        sim.advance(duration)
    except DivergenceError as e:
        diverged = e.reason
    wall = time.perf_counter() - t0
    st = sim.stats
    comp = [s["compression"] for s in st]
    return {
        "method": method,
        "case": case,
        "dt": dt,
        "particles": sim.n_particles,
        "spacing": sim.model.spacing,
        "reached_s": sim.time,
        "diverged": diverged,
        "steps": len(st),
        "mean_compression": float(np.mean(comp)),
        "max_compression": float(np.max(comp)),
        "mean_iterations": float(np.mean([s["iterations"] for s in st])),
        "mean_divergence_iterations": float(np.mean([s["divergence_iterations"] for s in st]))
        if method == "dfsph"
        else None,
        "unconverged_steps": sum(
            s["iterations"] >= sim.physics.max_iterations and s["density_error"] > sim.physics.eta for s in st
        ),
        "wall_corrections": sum(s["wall_corrections"] for s in st),
        "obstacle_corrections": sum(s["obstacle_corrections"] for s in st),
        "corrected_steps": sum(bool(s["wall_corrections"] or s["obstacle_corrections"]) for s in st),
        "max_velocity": max(s["max_velocity"] for s in st),
        "velocity_limit": sim.loop.velocity_limit,
        "wall_seconds": wall,
        "wall_seconds_per_simulated_second": wall / sim.time if sim.time > 0 else None,
    }


def label(case: str) -> str:
    return "CFL 0.5" if case == "cfl" else f"dt {1e3 * float(case):g} ms"


def chart(rows: list, duration: float, path) -> None:
    plt = pyplot()

    cases = list(dict.fromkeys(r["case"] for r in rows))
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4))
    width = 0.38
    x = np.arange(len(cases))
    for k, method in enumerate(METHODS):
        by = {r["case"]: r for r in rows if r["method"] == method}
        pos = x + (k - 0.5) * width
        for ax, key, scale in (
            (axes[0], "reached_s", 1.0),
            (axes[1], "mean_compression", 100.0),
            (axes[2], "wall_seconds_per_simulated_second", 1.0),
        ):
            vals = [scale * (by[c][key] or 0.0) if c in by else 0.0 for c in cases]
            bars = ax.bar(pos, vals, width, label=method.upper(), color=("tab:blue", "tab:orange")[k])
            for b, c in zip(bars, cases):
                if c in by and by[c]["diverged"]:
                    b.set_hatch("//")
                    b.set_edgecolor("black")
        for c, p in zip(cases, pos):  # iterations per step over the speed bars
            if c in by:
                r = by[c]
                it = r["mean_iterations"] + (r["mean_divergence_iterations"] or 0.0)
                axes[2].annotate(
                    f"{it:.1f} it",
                    (p, r["wall_seconds_per_simulated_second"] or 0.0),
                    ha="center",
                    va="bottom",
                    fontsize=7,
                )
    axes[0].axhline(duration, color="gray", ls=":")
    axes[0].set_ylabel("simulated seconds reached (hatched: diverged)")
    axes[1].set_ylabel("mean compression (%)")
    axes[1].set_yscale("log")
    axes[1].axhline(0.1, color="gray", ls=":", label="eta")
    axes[2].set_ylabel("wall s per simulated s")
    for ax in axes:
        ax.set_xticks(x)
        ax.set_xticklabels([label(c) for c in cases])
    axes[0].legend(fontsize=8)
    axes[1].legend(fontsize=8)
    fig.suptitle(f"Dam break, {rows[0]['particles']:,} particles: DFSPH against IISPH")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--particles", type=int, default=32768, help="in the 0.96 m cube (32,768: a 3 cm spacing)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--cases", default="0.005,0.009,0.01,0.011,cfl", help="fixed steps in seconds, and cfl for the CFL rule"
    )
    ap.add_argument("--quick", action="store_true", help="4,096 particles, 0.1 s (under a minute)")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--replot", action="store_true", help="redraw the chart from the JSON already in --out")
    args = ap.parse_args()
    if args.replot:
        record, png = saved(args.out, "dfsph")
        chart(record["results"], record["duration"], png)
        return
    if args.quick:
        args.particles, args.duration, args.cases = 4096, 0.1, "0.005,0.01,cfl"
    set_threads(args.threads)
    for method in METHODS:
        warm_up(method=method)  # compile outside the timing
    rows = []
    for case in args.cases.split(","):
        for method in METHODS:
            r = run(method, case, args.particles, args.duration)
            rows.append(r)
            div = f"{r['mean_divergence_iterations']:.1f}" if r["mean_divergence_iterations"] is not None else "-"
            print(
                f"{label(case):>9} {method:>5}: "
                f"reached {r['reached_s']:.3f} s{' (diverged: ' + r['diverged'] + ')' if r['diverged'] else ''}, "
                f"{r['steps']} steps, compression mean {100 * r['mean_compression']:.3f} % "
                f"max {100 * r['max_compression']:.2f} %, "
                f"iterations {r['mean_iterations']:.1f} + divergence {div}, corrections {r['wall_corrections']} in "
                f"{r['corrected_steps']} steps, {r['wall_seconds_per_simulated_second']:.1f} s per simulated s",
                flush=True,
            )
    record = header(
        "dfsph",
        scene="dam_break_cube",
        spacing=rows[0]["spacing"],
        duration=args.duration,
        threads=args.threads,
        eta=1e-3,
        eta_divergence=1e-3,
        results=rows,
    )
    chart(rows, args.duration, save(record, args.out, "dfsph", args.quick))


if __name__ == "__main__":
    main()
