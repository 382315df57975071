"""Dam-break validation: surge-front position against T beside Martin & Moyce (1952), at several
resolutions, with the default physics (viscosity 0.05, free-slip walls) and without viscosity.
The column is a = 0.1 m wide, 2a high, in a slab 4 particles deep. Writes
benchmarks/results/validation.json and .png.

    python benchmarks/validation.py [--resolutions 10,15,20] [--quick]
"""

import argparse

import numpy as np
import warp as wp

from common import RESULTS, header, martin_moyce_front, pyplot, save
from warp_iisph import DivergenceError
from warp_iisph.analysis.dam_break import front_errors, load_martin_moyce

G, A = 9.81, 0.1


def front_curve(resolution: int, viscosity: float):
    T, Z, sim, _ = martin_moyce_front(resolution, a=A, viscosity=viscosity)
    return T, Z, sim.n_particles


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolutions", default="10,15,20", help="a/h values")
    ap.add_argument("--viscosity", type=float, default=0.05, help="viscosity of the first series, m^2/s (the default)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.resolutions = "10"
    wp.config.log_level = wp.LOG_WARNING
    ref = load_martin_moyce()
    rows = []
    for res in (int(r) for r in args.resolutions.split(",")):
        for viscosity in (args.viscosity, 0.0):
            try:
                T, Z, n = front_curve(res, viscosity)
            except DivergenceError as err:  # the inviscid thin slab can lose a particle through its side walls
                rows.append({"a_over_h": res, "viscosity": viscosity, "diverged": str(err), "mean_abs_error": None})
                print(f"a/h = {res:>3}, viscosity {viscosity:g} m^2/s: {err}")
                continue
            e = front_errors(T, Z, ref)
            rows.append({"a_over_h": res, "particles": n, "viscosity": viscosity, "T": T.tolist(), "Z": Z.tolist(),
                         "mean_abs_error": float(np.mean(np.abs(e))), "max_abs_error": float(np.max(np.abs(e)))})
            print(f"a/h = {res:>3} ({n:>5} particles), viscosity {viscosity:g} m^2/s: front error against the experiment "
                  f"mean {100 * rows[-1]['mean_abs_error']:.1f} %, worst {100 * rows[-1]['max_abs_error']:.1f} % (T <= 3)")
    record = header("validation", reference="Martin & Moyce 1952", runs=rows)
    chart(rows, ref, save(record, args.out, "validation", args.quick))


def chart(rows, ref, path):
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(7, 5))
    for name, pts in ref.items():
        pts = pts[pts[:, 0] <= 3.2]
        ax.plot(pts[:, 0], pts[:, 1], "o", mfc="none", ms=6, label=f"Martin & Moyce, series {name}")
    for r in rows:
        if r.get("diverged"):
            continue
        style = "-" if r["viscosity"] > 0 else ":"
        ax.plot(r["T"], r["Z"], style, label=f"IISPH a/h = {r['a_over_h']}, viscosity {r['viscosity']:g}")
    ax.set_xlabel("T = t sqrt(2g/a)")
    ax.set_ylabel("Z = front / a")
    ax.set_xlim(0, 3.2)
    ax.set_ylim(0.8, 5.0)
    ax.legend(fontsize=7)
    ax.set_title("Dam-break surge front")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
