"""Speed against accuracy: the Martin & Moyce dam break (a = 0.1 m, a/h = 15, free-slip walls as
in the bundled scene, to T = 3.2) with WCSPH at several fixed dt and stiffness values and IISPH at
eta = 1 %, 0.1 %, 0.01 % with several CFL factors and fixed dt. Accuracy on two axes: the mean
density error (mean over particles of max(rho/rho0 - 1, 0), averaged over steps) and the mean
surge-front error against Martin & Moyce (T <= 3); cost: wall seconds per simulated second on
this CPU. Runs that diverge are listed with the reason. Writes
benchmarks/results/speed_accuracy.json and .png; the chart marks the Pareto front (the runs no
other run beats on both cost and accuracy).

    python benchmarks/speed_accuracy.py [--resolution 15] [--quick] [--workers N | --scheduler ADDRESS]

Each configuration is a variant of one sweep (warp_iisph.run.cluster): one after another in this
process by default, or side by side with --workers N (a Dask LocalCluster) or --scheduler
ADDRESS, where the cost axis is then distorted by the runs beside each one.
"""

import argparse
import functools

import numpy as np
import warp as wp
from common import (
    RESULTS,
    check_cluster_options,
    cluster_options,
    header,
    martin_moyce_front,
    measure_all,
    pyplot,
    save,
    warm_once,
)

from warp_iisph import DivergenceError
from warp_iisph.analysis.dam_break import front_errors

FRICTION = 0.0  # the bundled martin_moyce scene's walls are free-slip


def configurations(quick: bool) -> list[dict]:
    if quick:
        return [{"method": "wcsph", "stiffness": 5e4, "dt": 2e-4}, {"method": "iisph", "eta": 1e-3, "cfl": 0.5}]
    runs = [{"method": "wcsph", "stiffness": k, "dt": dt} for k in (1e4, 5e4, 2e5) for dt in (1e-4, 2e-4, 4e-4)]
    runs += [{"method": "iisph", "eta": eta, "cfl": cfl} for eta in (1e-2, 1e-3, 1e-4) for cfl in (0.25, 0.5, 1.0)]
    runs += [{"method": "iisph", "eta": 1e-3, "dt": dt} for dt in (1e-3, 2e-3, 4e-3)]
    return runs


def label(c: dict) -> str:
    if c["method"] == "wcsph":
        return f"WCSPH k={c['stiffness'] / 1e3:g} kPa dt={1e3 * c['dt']:g} ms"
    step = f"dt={1e3 * c['dt']:g} ms" if "dt" in c else f"CFL {c['cfl']:g}"
    return f"IISPH eta={100 * c['eta']:g}% {step}"


def measure(resolution: int, config: dict) -> dict:
    warm_once(method=config["method"])  # in a worker of a cluster: its kernels loaded outside the timing
    physics = dict(config)
    if "dt" not in physics:
        physics["dt_max"] = 5e-3
    row = {**config, "label": label(config)}
    try:
        T, Z, sim, wall = martin_moyce_front(resolution, boundary_viscosity=FRICTION, **physics)
    except DivergenceError as e:
        return {**row, "diverged": str(e)}
    st = sim.stats
    e = front_errors(T, Z)
    return {
        **row,
        "particles": sim.n_particles,
        "steps": len(st),
        "wall_seconds_per_simulated_second": wall / sim.time,
        "mean_density_error": float(np.mean([s["compression"] for s in st])),
        "max_density_error": float(np.max([s["compression"] for s in st])),
        "front_error": float(np.mean(np.abs(e))),
        "mean_iterations": float(np.mean([s["iterations"] for s in st])),
    }


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats on both coordinates (lower is better), by cost."""
    order = sorted(range(len(points)), key=lambda i: points[i])
    front, best = [], float("inf")
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def chart(rows, path):
    from matplotlib.ticker import ScalarFormatter

    plt = pyplot()
    ok = [r for r in rows if "diverged" not in r]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, key, name in (
        (axes[0], "mean_density_error", "mean density error (%)"),
        (axes[1], "front_error", "surge-front error vs experiment (%)"),
    ):
        for method, marker, color in (("wcsph", "s", "tab:orange"), ("iisph", "o", "tab:blue")):
            r = [x for x in ok if x["method"] == method]
            ax.scatter(
                [x["wall_seconds_per_simulated_second"] for x in r],
                [100 * x[key] for x in r],
                marker=marker,
                color=color,
                label=method.upper(),
                zorder=3,
            )
            for x in r:
                ax.annotate(
                    x["label"].split(" ", 1)[1],
                    (x["wall_seconds_per_simulated_second"], 100 * x[key]),
                    fontsize=6,
                    textcoords="offset points",
                    xytext=(4, 2),
                )
        pts = [(x["wall_seconds_per_simulated_second"], x[key]) for x in ok]
        front = [pts[i] for i in pareto(pts)]
        ax.step(
            [p[0] for p in front],
            [100 * p[1] for p in front],
            where="post",
            color="gray",
            ls="--",
            label="Pareto front",
        )
        ax.set_xscale("log")
        ax.set_yscale("log")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_formatter(ScalarFormatter())
            axis.set_minor_formatter(ScalarFormatter())
            axis.get_minor_formatter().set_scientific(False)
        ax.tick_params(which="minor", labelsize=7)
        ax.set_xlabel("cost: wall s per simulated s (CPU)")
        ax.set_ylabel(name)
        ax.legend(fontsize=8)
    failed = [x["label"] for x in rows if "diverged" in x]
    if failed:
        fig.text(0.01, 0.01, "diverged: " + "; ".join(failed), fontsize=7)
    axes[0].set_title("Incompressibility against cost")
    axes[1].set_title("Agreement with Martin & Moyce against cost")
    fig.tight_layout(rect=(0, 0.04 if failed else 0, 1, 1))
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=15, help="a/h")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    cluster_options(ap)
    args = ap.parse_args()
    check_cluster_options(ap, args)
    if args.quick:
        args.resolution = 8
    wp.config.log_level = wp.LOG_WARNING
    if args.workers is None and args.scheduler is None:
        warm_once(method="iisph")
        warm_once(method="wcsph")
    rows = []
    print(f"{'run':<38} {'s/sim s':>8} {'density err %':>13} {'front err %':>11} {'steps':>6} {'iters':>5}")

    def report(r):
        rows.append(r)
        if "diverged" in r:
            print(f"{r['label']:<38} diverged: {r['diverged']}")
        else:
            print(
                f"{r['label']:<38} {r['wall_seconds_per_simulated_second']:>8.2f} "
                f"{100 * r['mean_density_error']:>13.3f} "
                f"{100 * r['front_error']:>11.1f} {r['steps']:>6} {r['mean_iterations']:>5.1f}"
            )

    measure_all(args, [functools.partial(measure, args.resolution, c) for c in configurations(args.quick)], report)
    ok = [r for r in rows if "diverged" not in r]
    for key in ("mean_density_error", "front_error"):
        front = pareto([(r["wall_seconds_per_simulated_second"], r[key]) for r in ok])
        for i in front:
            ok[i].setdefault("pareto", []).append(key)
        print(f"Pareto front on {key}: " + ", ".join(ok[i]["label"] for i in front))
    record = header(
        "speed_accuracy",
        scene=f"martin_moyce (a = 0.1 m, a/h = {args.resolution}, 4 particles deep)",
        wall_friction=FRICTION,
        reference="Martin & Moyce 1952, T <= 3",
        results=rows,
    )
    chart(rows, save(record, args.out, "speed_accuracy", args.quick))


if __name__ == "__main__":
    main()
