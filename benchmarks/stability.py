"""Where methods fail: the largest fixed time step at which WCSPH and IISPH stay stable on the
Martin & Moyce dam break (a = 0.2 m), per resolution, found by bisection. A run of 0.6 s is
stable when it has no NaN, no particle outside the tank, a mean density error (over particles
and steps, of max(rho/rho0 - 1, 0)) below 1 %, and a max speed below 3x the free-fall speed of
the column. Writes benchmarks/results/stability.json and .png, with the CFL number
dt * v_ref / h (v_ref = sqrt(2 g 2a)) of each limit.

    python benchmarks/stability.py [--spacings 0.04,0.02,0.0133] [--quick]
"""

import argparse

import numpy as np
import warp as wp

from common import RESULTS, header, pyplot, save
from warp_iisph import DivergenceError, Simulation, scenes

G, A = 9.81, 0.2
CRITERIA = {"duration_s": 0.6, "max_mean_density_error": 0.01, "max_speed_over_free_fall": 3.0}


def stable(method: str, h: float, dt: float, duration: float) -> tuple[bool, str]:
    sim = Simulation(scenes.martin_moyce(spacing=h, a=A, depth=0.1, method=method, dt=dt), "cpu")
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


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacings", default="0.04,0.02,0.0133")
    ap.add_argument("--steps", type=int, default=7, help="bisection steps")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    duration = CRITERIA["duration_s"]
    if args.quick:
        args.spacings, args.steps, duration = "0.04", 3, 0.2
    wp.config.log_level = wp.LOG_WARNING
    v_ref = np.sqrt(2 * G * 2 * A)
    rows = []
    for h in (float(s) for s in args.spacings.split(",")):
        for method in ("wcsph", "iisph"):
            r = largest_stable_dt(method, h, 1e-4, 2e-2, args.steps, duration)
            r.update({"method": method, "spacing": h, "a_over_h": A / h,
                      "cfl_at_limit": None if r["dt_max"] is None else r["dt_max"] * v_ref / h})
            rows.append(r)
            dt = "none" if r["dt_max"] is None else f"{1e3 * r['dt_max']:.2f} ms (CFL {r['cfl_at_limit']:.2f})"
            print(f"{method:>5} h = {h:g} m: largest stable dt {dt}; fails by: {r.get('failure', r.get('note', ''))}")
    record = header("stability", scene="martin_moyce (a = 0.2 m, 0.1 m deep)", criteria={**CRITERIA, "duration_s": duration},
                    wcsph_stiffness_pa=50000, iisph_eta=1e-3, results=rows)
    chart(rows, save(record, args.out, "stability", args.quick))


def chart(rows, path):
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for method, marker in (("wcsph", "s-"), ("iisph", "o-")):
        pts = [(r["a_over_h"], 1e3 * r["dt_max"]) for r in rows if r["method"] == method and r["dt_max"]]
        if pts:
            x, y = zip(*pts)
            ax.plot(x, y, marker, label=method.upper())
            for xi, yi, r in zip(x, y, [r for r in rows if r["method"] == method and r["dt_max"]]):
                ax.annotate(f"CFL {r['cfl_at_limit']:.2f}", (xi, yi), textcoords="offset points", xytext=(5, 5), fontsize=8)
    ax.set_yscale("log")
    ax.set_xlabel("resolution a/h")
    ax.set_ylabel("largest stable fixed dt (ms)")
    ax.set_title("Dam break: largest stable time step")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
