"""Validation against physics, with the default settings: the two committed measurements the README
quotes.

1. Martin & Moyce (1952) dam break: a water column a = 0.3 m wide and 2a high against the x = 0
   wall of a 6a x 3a x 0.5a tank (quasi-2D slab), nx particles across the column (nx 20, 30, 40).
   The surge front Z = x/a against T = t sqrt(2g/a) is compared, without any time shift, with both
   of the paper's series (a = 2.25 in and 1.125 in): the mean of |Z_sim / Z_exp - 1| over each
   series' points with T <= 3.
2. Resting tank: 0.4 x 0.8 x 0.2 m, water 0.6 m deep, spacing 2 cm (6,000 particles). After 2 s
   of settling, every step for 0.5 s: the slope of pressure against depth fitted over the
   interior particles (at least two spacings from every wall and the floor) in units of rho0 g,
   mean and largest speed, and the compression of the bottom layer (mean rho/rho0 - 1 of the
   particles within one spacing of the floor).

Writes benchmarks/results/validation.json and validation.png (Z against T beside the experiment;
the slope per step within the +-3 % band).

    python benchmarks/validation.py [--nx 20,30,40] [--quick] [--peer] [--workers N | --scheduler ADDRESS]

--peer runs SPlisHSPlasH's IISPH (the `bench` extra, peer_splishsplash.py) on the same Martin &
Moyce set-up at each nx in the same run, its front measured and scored as ours.

--quick (the test suite's): nx 10 up to T = 1.5, and a 0.24 x 0.4 x 0.2 m tank at 4 cm settled
0.5 s and measured 0.2 s.

The runs are the variants of one sweep (warp_iisph.run.cluster): one after another in this
process by default, or side by side with --workers N (a Dask LocalCluster) or --scheduler ADDRESS.
"""

import argparse
import functools
import subprocess
import time

import numpy as np
import peer_splishsplash
import warp as wp
from common import RESULTS, check_cluster_options, cluster_options, header, measure_all, pyplot, save

from warp_iisph import Box, DivergenceError, Scene, Simulation
from warp_iisph.analysis.dam_break import load_martin_moyce, surge_front
from warp_iisph.analysis.hydrostatic import hydrostatic_slope

G, RHO0 = 9.81, 1000.0


def martin_moyce(nx: int, a: float = 0.3, t_max: float = 3.0) -> dict:
    """The front curve at nx particles across the column, errors against both series."""
    h = a / nx
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (6 * a, 3 * a, 0.5 * a)), name="martin_moyce")
    scene.add_fluid_box((0.0, 0.0, 0.0), (a, 2 * a, 0.5 * a))
    sim = Simulation(scene, "cpu", history=4096)
    ref = load_martin_moyce()
    scale = np.sqrt(2 * G / a)
    T_exp = sorted({float(T) for pts in ref.values() for T in pts[:, 0] if T <= t_max})
    Ts = sorted(set(T_exp) | set(np.round(np.arange(0.25, t_max + 1e-9, 0.25), 3).tolist()))
    curve, diverged, t0 = [(0.0, surge_front(sim.positions, h) / a)], None, time.perf_counter()
    compression, iterations = [], []
    try:
        for T in Ts:
            sim.advance(T / scale - sim.time)
            curve.append((T, surge_front(sim.positions, h) / a))
    except DivergenceError as err:
        diverged = str(err)
    for s in sim.stats:
        compression.append(s["compression"])
        iterations.append(s["iterations"])
    T_sim, Z_sim = (np.array(c) for c in zip(*curve))
    row = {
        "nx": nx,
        "a": a,
        "spacing": h,
        "particles": sim.n_particles,
        "T": T_sim.tolist(),
        "Z": Z_sim.tolist(),
        "diverged": diverged,
        "steps": sim.step_count,
        "wall_seconds": time.perf_counter() - t0,
        "mean_compression": float(np.mean(compression)),
        "mean_iterations": float(np.mean(iterations)),
        "wall_corrections": int(sum(s["wall_corrections"] for s in sim.stats)),
    }
    return {**row, **front_scores(T_sim, Z_sim, ref, t_max, diverged)}


def front_scores(T_sim, Z_sim, ref, t_max, diverged=None) -> dict:
    """Mean |Z_sim / Z_exp - 1| against each series' points with T <= t_max, and the point errors."""
    out = {}
    for name, pts in ref.items():
        pts = pts[pts[:, 0] <= t_max]
        if diverged and T_sim[-1] < pts[-1, 0]:
            out[f"error_{name}"] = None
            continue
        err = np.interp(pts[:, 0], T_sim, Z_sim) / pts[:, 1] - 1.0
        out[f"error_{name}"] = float(np.mean(np.abs(err)))
        out[f"errors_{name}"] = err.tolist()
    return out


def peer_martin_moyce(nx: int, t_max: float = 3.0) -> dict | None:
    """SPlisHSPlasH's IISPH on the same set-up (a = peer_splishsplash.MM_WIDTH, 0.3 m as ours),
    scored as ours; ``None`` when it is not installed. The errors are scored on its front at every
    step; the record keeps that curve thinned to every 0.05 in T."""
    a = peer_splishsplash.MM_WIDTH
    duration = t_max / np.sqrt(2 * G / a) + 0.01
    t0 = time.perf_counter()
    try:
        rec = peer_splishsplash.run(duration=duration, scene="martin_moyce", nx=nx)
    except (RuntimeError, subprocess.TimeoutExpired) as err:  # the peer's failure is a result, not ours
        return {"nx": nx, "failed": str(err)[-300:], "run_seconds": time.perf_counter() - t0}
    if rec is None:
        return None
    T, Z = np.array(rec.pop("T")), np.array(rec.pop("Z"))
    keep = np.searchsorted(T, np.arange(0.0, t_max + 1e-9, 0.05)).clip(0, len(T) - 1)
    return {
        **rec,
        "T": T[keep].tolist(),
        "Z": Z[keep].tolist(),
        "run_seconds": time.perf_counter() - t0,
        **front_scores(T, Z, load_martin_moyce(), t_max),
    }


def resting_tank(
    h: float = 0.02, size=(0.4, 0.8, 0.2), depth: float = 0.6, settle: float = 2.0, measure: float = 0.5, **physics
) -> dict:
    """Per-step hydrostatic slope, speeds and bottom compression of water at rest (``physics``:
    settings other than the defaults, for studies; the validation itself uses none)."""
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), size), name="resting_tank")
    scene.add_fluid_box((0.0, 0.0, 0.0), (size[0], depth, size[2]))
    for key, value in physics.items():
        setattr(scene.physics, key, value)
    scene.physics.validate()
    sim = Simulation(scene, "cpu", history=16)
    t0 = time.perf_counter()
    rows, diverged = [], None
    try:
        while sim.time < settle - 1e-9:
            sim.step()
        while sim.time < settle + measure - 1e-9:
            rec = sim.step()
            x, p, rho = sim.state.x.numpy(), sim.state.p.numpy(), sim.state.rho.numpy()
            speed = np.linalg.norm(sim.state.v.numpy(), axis=1)
            bottom = x[:, 1] < h
            rows.append(
                {
                    "t": sim.time,
                    "dt": rec["dt"],
                    "iterations": rec["iterations"],
                    "slope": hydrostatic_slope(x, p, h, (0.0, 0.0, 0.0), size, RHO0, G),
                    "mean_speed": float(speed.mean()),
                    "max_speed": float(speed.max()),
                    "bottom_compression": float(rho[bottom].mean() / RHO0 - 1.0),
                    "compression": rec["compression"],
                    "wall_corrections": rec["wall_corrections"],
                }
            )
    except DivergenceError as err:
        diverged = str(err)
    out = {
        "spacing": h,
        "tank": list(size),
        "water_depth": depth,
        "particles": sim.n_particles,
        "physics": physics,
        "diverged": diverged,
        "settle_s": settle,
        "measure_s": measure,
        "eta": sim.physics.eta,
        "steps": rows,
        "wall_seconds": time.perf_counter() - t0,
    }
    if not rows:
        return out
    slope = np.array([r["slope"] for r in rows])
    dt = np.array([r["dt"] for r in rows])
    return {
        **out,
        "slope_min": float(slope.min()),
        "slope_max": float(slope.max()),
        "slope_mean": float(slope.mean()),
        "steps_within_3_percent": float(np.mean(np.abs(slope - 1.0) <= 0.03)),
        "mean_speed_max": max(r["mean_speed"] for r in rows),
        "max_speed_max": max(r["max_speed"] for r in rows),
        "bottom_compression_max": max(r["bottom_compression"] for r in rows),
        "mean_iterations": float(np.mean([r["iterations"] for r in rows])),
        # dt^2 g H / h^2: how far gravity moves the column's weight in a step, in spacings
        "step_number": float(np.median(dt) ** 2 * G * depth / h**2),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--nx", default="20,30,40", help="particles across the Martin & Moyce column")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--peer", action="store_true", help="SPlisHSPlasH's IISPH on the same Martin & Moyce set-up")
    cluster_options(ap)
    args = ap.parse_args()
    check_cluster_options(ap, args)
    wp.config.log_level = wp.LOG_WARNING
    t_max = 3.0
    tank = {}
    if args.quick:
        args.nx, t_max = "10", 1.5
        tank = {"h": 0.04, "size": (0.24, 0.4, 0.2), "depth": 0.28, "settle": 0.5, "measure": 0.2}
    nxs = [int(v) for v in args.nx.split(",")]
    calls = [functools.partial(martin_moyce, nx, t_max=t_max) for nx in nxs]
    calls += [functools.partial(peer_martin_moyce, nx, t_max=t_max) for nx in (nxs if args.peer else ())]
    calls.append(functools.partial(resting_tank, **tank))
    kinds = iter([("ours", nx) for nx in nxs] + [("peer", nx) for nx in (nxs if args.peer else ())] + [("rest", None)])
    runs, peers, missing_peer, rests = [], [], [], []

    def report(r):
        kind, nx = next(kinds)
        if kind == "ours":
            runs.append(r)
            errs = ", ".join(
                f"{k[6:]} {100 * v:.1f} %" for k, v in r.items() if k.startswith("error_") and v is not None
            )
            print(
                f"Martin & Moyce nx {nx} ({r['particles']} particles): front error {errs} (T <= {t_max:g}); "
                f"mean compression {100 * r['mean_compression']:.3f} %, {r['steps']} steps, "
                f"{r['wall_seconds']:.0f} s" + (f"; DIVERGED: {r['diverged']}" if r["diverged"] else "")
            )
        elif kind == "rest":
            rests.append(r)
        elif missing_peer:
            pass  # said once
        elif r is None:
            missing_peer.append(True)
            print("SPlisHSPlasH is not installed (the bench extra): no peer runs")
        elif "failed" in r:
            peers.append(r)
            print(f"SPlisHSPlasH IISPH, Martin & Moyce nx {nx}: failed: {r['failed']}")
        else:
            peers.append(r)
            print(
                f"SPlisHSPlasH IISPH, Martin & Moyce nx {nx} ({r['particles']} particles): front error "
                + ", ".join(
                    f"{k[6:]} {100 * v:.1f} %" for k, v in r.items() if k.startswith("error_") and v is not None
                )
                + f"; mean compression {100 * r['mean_compression']:.3f} %, {r['steps']} steps"
                + (f"; {r['escaped']} particles left the tank through its walls" if r["escaped"] else "")
            )

    measure_all(args, calls, report)
    (rest,) = rests
    print(
        f"resting tank ({rest['particles']} particles), {len(rest['steps'])} steps after {rest['settle_s']:g} s: "
        f"slope / rho0 g {rest['slope_min']:.3f} .. {rest['slope_max']:.3f} "
        f"({100 * rest['steps_within_3_percent']:.0f} % of "
        f"steps within 3 %), mean speed <= {100 * rest['mean_speed_max']:.2f} cm/s, "
        f"max speed <= {100 * rest['max_speed_max']:.1f} cm/s, "
        f"bottom compression <= {100 * rest['bottom_compression_max']:.3f} %"
    )
    record = header(
        "validation",
        reference="Martin & Moyce 1952; hydrostatics",
        t_max=t_max,
        runs=runs,
        resting_tank=rest,
        peer_runs=peers,
    )
    chart(runs, rest, load_martin_moyce(), t_max, save(record, args.out, "validation", args.quick), peers)


def chart(runs, rest, ref, t_max, path, peers=()):
    plt = pyplot()

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [1.2, 1]})
    for (name, pts), marker in zip(ref.items(), ("s", "o")):
        pts = pts[pts[:, 0] <= t_max + 0.2]
        ax.plot(
            pts[:, 0],
            pts[:, 1],
            marker,
            mfc="none",
            ms=7,
            color="k",
            label=f"Martin & Moyce, a = {name[2]}.{name[3:]} in",
        )
    for r in runs:
        errs = ", ".join(f"{100 * r[k]:.1f} %" for k in sorted(r) if k.startswith("error_") and r[k] is not None)
        (line,) = ax.plot(r["T"], r["Z"], "-", label=f"IISPH nx = {r['nx']} ({r['particles']} particles): {errs}")
        for q in peers:
            if q["nx"] == r["nx"] and "failed" not in q:
                errs = ", ".join(
                    f"{100 * q[k]:.1f} %" for k in sorted(q) if k.startswith("error_") and q[k] is not None
                )
                leak = f" ({q['escaped']} particles left the tank)" if q["escaped"] else ""
                ax.plot(
                    q["T"],
                    q["Z"],
                    "--",
                    color=line.get_color(),
                    lw=1,
                    label=f"SPlisHSPlasH IISPH nx = {q['nx']}: {errs}{leak}",
                )
    ax.set_xlabel("T = t sqrt(2g/a)")
    ax.set_ylabel("Z = front / a")
    ax.set_xlim(0, t_max + 0.1)
    ax.set_title("Dam break, a = 0.3 m: surge front (mean |error|: a = 1.125 in, 2.25 in)")
    ax.legend(fontsize=7, loc="upper left")
    t = [s["t"] for s in rest["steps"]]
    bx.axhspan(0.97, 1.03, color="0.9", label="within 3 % of rho0 g")
    bx.plot(t, [s["slope"] for s in rest["steps"]], ".-", ms=3, lw=0.7, label="fitted dp/d(depth) / rho0 g, every step")
    bx.axhline(1.0, color="k", lw=0.6)
    bx.set_xlabel("t (s)")
    bx.set_ylabel("pressure slope / rho0 g")
    bx.set_title(f"Resting tank ({rest['particles']} particles), after {rest['settle_s']:g} s")
    bx.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
