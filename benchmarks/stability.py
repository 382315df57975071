"""Where methods fail, and what a too-large fixed step does.

1. The largest fixed time step at which WCSPH and IISPH stay stable on the Martin & Moyce dam
   break (a = 0.2 m), per resolution, found by bisection, each step taken as it is
   (``physics.substeps = false``). A run of 0.6 s is stable when it has no NaN, no particle
   outside the tank, a mean density error (over particles and steps, of max(rho/rho0 - 1, 0))
   below 1 %, and a max speed below 3x the free-fall speed of the column; with the CFL number
   dt * v_ref / h (v_ref = sqrt(2 g 2a)) of each limit.
2. The 32,768-particle dam break (scenes.dam_break_cube) at a fixed 5 ms and 10 ms for 2 s with
   the defaults, where a fixed step longer than IISPH can take is cut into substeps (counted per
   step), and with every step taken as it is (substeps off); every step's particles put back
   within the tank by the last line (warp_iisph/sph/containment.py: what the pressure solver
   left undone), compression and iterations.

Writes benchmarks/results/stability.json and .png.

    python benchmarks/stability.py [--spacings 0.04,0.02,0.0133] [--fixed 0.005,0.01] [--quick]
        [--workers N | --scheduler ADDRESS]

--quick: one resolution (h = 4 cm) over 0.3 s, and the dam break at 6 cm (4,096 particles) for
0.3 s.

Each bisection (a method at a resolution) and each dam break is a variant of one sweep
(warp_iisph.run.cluster): one after another in this process by default, or side by side with
--workers N (a Dask LocalCluster) or --scheduler ADDRESS.
"""

import argparse
import functools
import time

import numpy as np
import warp as wp
from common import RESULTS, check_cluster_options, cluster_options, header, measure_all, pyplot, save

from warp_iisph import DivergenceError, Simulation, scenes

G, A = 9.81, 0.2
CRITERIA = {"duration_s": 0.6, "max_mean_density_error": 0.01, "max_speed_over_free_fall": 3.0}


def stable(method: str, h: float, dt: float, duration: float) -> tuple[bool, str]:
    sim = Simulation(scenes.martin_moyce(spacing=h, a=A, depth=0.1, method=method, dt=dt, substeps=False), "cpu")
    v_ff = np.sqrt(2 * G * 2 * A)
    try:
        sim.advance(duration)
    except DivergenceError as e:
        return False, e.reason
    comp = float(np.mean([s["compression"] for s in sim.stats]))
    vmax = max(s["max_velocity"] for s in sim.stats)
    if comp > CRITERIA["max_mean_density_error"]:
        return False, f"mean density error {100 * comp:.2f} %"
    if vmax > CRITERIA["max_speed_over_free_fall"] * v_ff:
        return False, f"max speed {vmax:.2f} m/s"
    return True, ""


def largest_stable_dt(method: str, h: float, lo: float, hi: float, steps: int, duration: float) -> dict:
    """Bisection in log(dt) between a stable ``lo`` and an unstable ``hi``."""
    ok, why = stable(method, h, lo, duration)
    if not ok:
        return {"dt_max": None, "note": f"unstable even at {lo:g} s: {why}"}
    ok, why_hi = stable(method, h, hi, duration)
    if ok:
        return {"dt_max": hi, "note": f"stable up to the largest step tried, {hi:g} s"}
    for _ in range(steps):
        mid = float(np.sqrt(lo * hi))
        ok, why = stable(method, h, mid, duration)
        if ok:
            lo = mid
        else:
            hi, why_hi = mid, why
    return {"dt_max": lo, "first_unstable": hi, "failure": why_hi}


def fixed_step_dam_break(dt: float, duration: float, particles: int = 32768, substeps: bool = True) -> dict:
    """The dam break (a 0.96 m cube of water) at a fixed ``dt`` with the defaults (``substeps``
    false: every step taken as it is): per-step records and totals."""
    sim = Simulation(scenes.dam_break_cube(particles=particles, dt=dt, substeps=substeps), "cpu", history=1)
    spacing = sim.model.spacing
    steps, stopped, t0 = [], None, time.perf_counter()
    try:
        while sim.time < duration - 1e-9:
            r = sim.step()
            steps.append(
                {
                    k: r[k]
                    for k in (
                        "t",
                        "dt",
                        "substeps",
                        "iterations",
                        "density_error",
                        "compression",
                        "max_velocity",
                        "wall_corrections",
                        "obstacle_corrections",
                    )
                }
            )
    except DivergenceError as err:
        stopped = str(err)
    corr = [s["wall_corrections"] + s["obstacle_corrections"] for s in steps]
    return {
        "fixed_dt": dt,
        "substeps": substeps,
        "spacing": spacing,
        "particles": sim.n_particles,
        "duration": duration,
        "t_reached": sim.time,
        "stopped": stopped,
        "steps": len(steps),
        "wall_seconds": time.perf_counter() - t0,
        "fixed_steps": int(round(sim.time / dt)),
        "substepped_steps": sum(s["substeps"] > 1 for s in steps),
        "most_substeps": max((s["substeps"] for s in steps), default=1),
        "corrections": int(sum(corr)),
        "steps_with_corrections": int(sum(c > 0 for c in corr)),
        "most_corrections_in_a_step": int(max(corr, default=0)),
        "mean_compression": float(np.mean([s["compression"] for s in steps])) if steps else None,
        "max_compression": float(np.max([s["compression"] for s in steps])) if steps else None,
        "mean_iterations": float(np.mean([s["iterations"] for s in steps])) if steps else None,
        "max_speed": float(np.max([s["max_velocity"] for s in steps])) if steps else None,
        "per_step": steps,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacings", default="0.04,0.02,0.0133")
    ap.add_argument("--steps", type=int, default=7, help="bisection steps")
    ap.add_argument("--fixed", default="0.005,0.01", help="fixed steps (s) of the 32k dam break")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    cluster_options(ap)
    args = ap.parse_args()
    check_cluster_options(ap, args)
    duration = CRITERIA["duration_s"]
    dam_particles, dam_duration = 32768, 2.0
    if args.quick:
        args.spacings, args.steps, duration = "0.04", 3, 0.3
        dam_particles, dam_duration = 4096, 0.3
    wp.config.log_level = wp.LOG_WARNING
    v_ref = np.sqrt(2 * G * 2 * A)
    limits = [(method, float(h)) for h in args.spacings.split(",") for method in ("wcsph", "iisph")]
    fixed = [(float(v), s) for v in args.fixed.split(",") for s in (True, False)]
    calls = [functools.partial(largest_stable_dt, method, h, 1e-4, 2e-2, args.steps, duration) for method, h in limits]
    calls += [functools.partial(fixed_step_dam_break, dt, dam_duration, dam_particles, s) for dt, s in fixed]
    rows, dam = [], []

    def report(r):
        if len(rows) < len(limits):
            method, h = limits[len(rows)]
            r.update(
                {
                    "method": method,
                    "spacing": h,
                    "a_over_h": A / h,
                    "cfl_at_limit": None if r["dt_max"] is None else r["dt_max"] * v_ref / h,
                }
            )
            rows.append(r)
            dt = "none" if r["dt_max"] is None else f"{1e3 * r['dt_max']:.2f} ms (CFL {r['cfl_at_limit']:.2f})"
            print(f"{method:>5} h = {h:g} m: largest stable dt {dt}; fails by: {r.get('failure', r.get('note', ''))}")
            return
        dt, substeps = fixed[len(dam)]
        dam.append(r)
        print(
            f"dam break ({r['particles']} particles) at a fixed {1e3 * dt:g} ms{'' if substeps else ', no substeps'}: "
            f"reached {r['t_reached']:.3f} s"
            + (f" (STOPPED: {r['stopped']})" if r["stopped"] else "")
            + f" in {r['steps']} steps ({r['substepped_steps']} of them substeps, "
            f"up to {r['most_substeps']} per fixed step); "
            f"{r['corrections']} particles put back in {r['steps_with_corrections']} steps "
            f"(at most {r['most_corrections_in_a_step']} "
            f"in one); mean compression {100 * r['mean_compression']:.3f} %, {r['mean_iterations']:.1f} iterations, "
            f"{r['wall_seconds']:.0f} s"
        )

    measure_all(args, calls, report)
    record = header(
        "stability",
        scene="martin_moyce (a = 0.2 m, 0.1 m deep)",
        criteria={**CRITERIA, "duration_s": duration},
        wcsph_stiffness_pa=50000,
        iisph_eta=1e-3,
        results=rows,
        dam_break_fixed_dt={"scene": "dam_break_cube (a 0.96 m cube of water in a 4 x 3 x 1.5 m tank)", "runs": dam},
    )
    chart(rows, dam, save(record, args.out, "stability", args.quick))


def chart(rows, dam, path):
    plt = pyplot()

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.5))
    for method, marker in (("wcsph", "s-"), ("iisph", "o-")):
        pts = [(r["a_over_h"], 1e3 * r["dt_max"]) for r in rows if r["method"] == method and r["dt_max"]]
        if pts:
            x, y = zip(*pts)
            ax.plot(x, y, marker, label=method.upper())
            for xi, yi, r in zip(x, y, [r for r in rows if r["method"] == method and r["dt_max"]]):
                ax.annotate(
                    f"CFL {r['cfl_at_limit']:.2f}", (xi, yi), textcoords="offset points", xytext=(5, 5), fontsize=8
                )
    ax.set_yscale("log")
    ax.set_xlabel("resolution a/h")
    ax.set_ylabel("largest stable fixed dt (ms), no substeps")
    ax.set_title("Dam break: largest stable time step")
    ax.legend()
    for r, colour in zip(dam, ("C0", "C1", "C3", "C4", "C2", "C5")):
        t = [s["t"] for s in r["per_step"]]
        corr = [s["wall_corrections"] + s["obstacle_corrections"] for s in r["per_step"]]
        name = f"fixed {1e3 * r['fixed_dt']:g} ms" + ("" if r.get("substeps", True) else ", no substeps")
        bx.plot(
            t,
            corr,
            ".",
            ms=3,
            color=colour,
            label=f"{name}: particles put back per step ({r['corrections']} in all"
            + ("" if r["stopped"] is None else f"; stopped at {r['t_reached']:.2f} s")
            + ")",
        )
        if r.get("substeps", True):
            bx.plot(
                t,
                [s["substeps"] for s in r["per_step"]],
                "-",
                lw=0.8,
                color=colour,
                alpha=0.6,
                label=f"{name}: substeps per fixed step",
            )
    bx.set_xlabel("t (s)")
    bx.set_ylabel("count")
    bx.set_title(f"Dam break, {dam[0]['particles']} particles, fixed steps" if dam else "")
    bx.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
