"""Water at rest, per step: how the pressure's hydrostatic slope depends on the step and the
method (a study behind docs/physics.md, round 4; the validation's own resting tank is case 1).

IISPH's pressure at rest is set where its Jacobi iteration stops: the solve ends once the mean
predicted compression is at most eta, and what is left is a long wave (compression growing with
depth). A long-wave density error e asks for about rho0 e H^2 / dt^2 of pressure to be removed in
one step, so the slope's scatter from step to step shrinks as the step number dt^2 g H / h^2
grows, up to where the column stops resting. Cases (tank 0.4 m wide, 0.2 m deep, spacing 2 cm):

1. IISPH defaults, water 0.6 m deep (the validation's tank): the CFL rule's step from rest
2. IISPH, fixed 5 ms (SPlisHSPlasH's longest CFL step) taken as it is, 0.6 m
3. IISPH, fixed 5 ms with substeps (the default: cut where it is longer than the rest allows), 0.6 m
4. IISPH defaults, 1.2 m deep
5. IISPH, fixed 4.1 ms taken as it is, 1.2 m deep (one spacing at the free-fall speed)
6. IISPH, fixed 5 ms with substeps, 1.2 m deep
7. DFSPH defaults, 0.6 m
8. WCSPH defaults, 0.6 m

Each settles 2 s and is measured every step for 0.5 s. Writes
benchmarks/results/resting_tank.json and resting_tank.png.

    python benchmarks/resting_tank.py [--quick]
"""

import argparse

import warp as wp
from common import RESULTS, header, pyplot, save
from validation import resting_tank

CASES = [
    ("IISPH, defaults, 0.6 m", {}, 0.6),
    ("IISPH, fixed 5 ms as it is, 0.6 m", {"dt": 0.005, "substeps": False}, 0.6),
    ("IISPH, fixed 5 ms, substeps, 0.6 m", {"dt": 0.005}, 0.6),
    ("IISPH, defaults, 1.2 m", {}, 1.2),
    ("IISPH, fixed 4.1 ms as it is, 1.2 m", {"dt": 0.0041, "substeps": False}, 1.2),
    ("IISPH, fixed 5 ms, substeps, 1.2 m", {"dt": 0.005}, 1.2),
    ("DFSPH, defaults, 0.6 m", {"method": "dfsph"}, 0.6),
    ("WCSPH, defaults, 0.6 m", {"method": "wcsph"}, 0.6),
]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="4 cm spacing, settle 0.5 s, measure 0.1 s")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    h, settle, measure = (0.04, 0.5, 0.1) if args.quick else (0.02, 2.0, 0.5)
    rows = []
    for label, physics, depth in CASES:
        r = resting_tank(h=h, size=(0.4, depth + 0.2, 0.2), depth=depth, settle=settle, measure=measure, **physics)
        r["label"] = label
        rows.append(r)
        if r["steps"]:
            print(
                f"{label} ({r['particles']} particles): slope / rho0 g {r['slope_min']:.3f} .. {r['slope_max']:.3f} "
                f"({100 * r['steps_within_3_percent']:.0f} % of steps within 3 %), step number {r['step_number']:.2f}, "
                f"{r['mean_iterations']:.1f} iterations, mean speed <= {100 * r['mean_speed_max']:.2f} cm/s, "
                f"max <= {100 * r['max_speed_max']:.1f} cm/s, "
                f"bottom compression <= {100 * r['bottom_compression_max']:.3f} %, "
                f"{r['wall_seconds']:.0f} s" + (f"; DIVERGED: {r['diverged']}" if r["diverged"] else "")
            )
        else:
            print(f"{label}: DIVERGED before the measurement: {r['diverged']}")
    record = header("resting_tank", spacing=h, settle_s=settle, measure_s=measure, runs=rows)
    chart(rows, save(record, args.out, "resting_tank", args.quick))


def chart(rows, path):
    plt = pyplot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 4.8))
    ax.axhspan(0.97, 1.03, color="0.9", label="within 3 % of rho0 g")
    for r in rows:
        if not r["steps"]:
            continue
        t = [s["t"] for s in r["steps"]]
        ax.plot(
            t,
            [s["slope"] for s in r["steps"]],
            ".-",
            ms=2,
            lw=0.6,
            label=f"{r['label']}: {r['slope_min']:.2f}..{r['slope_max']:.2f} (dt^2 gH/h^2 {r['step_number']:.2f})",
        )
        bx.semilogy(t, [s["mean_speed"] for s in r["steps"]], "-", lw=0.8, label=r["label"])
    ax.set_ylim(0.8, 1.2)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("fitted dp/d(depth) / rho0 g (clipped to 0.8..1.2)")
    ax.set_title("Resting tank: the pressure's slope, every step")
    ax.legend(fontsize=6.5, loc="lower left")
    bx.set_xlabel("t (s)")
    bx.set_ylabel("mean speed (m/s)")
    bx.set_title("Mean speed, every step")
    bx.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
