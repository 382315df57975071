"""Thread scaling of the CPU path (the report's Figure 5): the 32,768-particle dam break
(IISPH, eta 0.1 %, CFL 0.5, dt <= 5 ms) with 1, 2, ... threads; wall time per simulated second
and ms per stage for each count, and its mean actual compression. Beside it, in the same run on
the same cores, SPlisHSPlasH's IISPH and DFSPH on the same dam break with 2 threads
(benchmarks/peer_splishsplash.py; the `bench` extra, skipped when not installed). Writes
benchmarks/results/thread_scaling.json and .png (thread_scaling_0.5s.json for ``--duration
0.5``). ``--matched iisph:3e-4,dfsph:5e-4`` adds runs of ours with 2 threads at other methods
and tolerances, to set beside the peers at a like compression (``iisph-half:1e-3``: IISPH with
``physics.warm_start = "half"``; without one, the default start).

    python benchmarks/thread_scaling.py [--duration 1.0] [--threads 1,2] [--no-peer]
        [--matched METHOD:ETA,...] [--quick]
"""

import argparse
import time

import numpy as np
import peer_splishsplash
from common import RESULTS, header, pyplot, save, warm_up

from warp_iisph import Simulation, scenes
from warp_iisph.engine.launch import available_cores, set_threads


def stem(duration: float) -> str:
    """The result file's name: thread_scaling for the default 1 s, with the duration otherwise
    (the first 0.5 s, the issue's other window, as thread_scaling_0.5s)."""
    return "thread_scaling" if duration == 1.0 else f"thread_scaling_{duration:g}s"


def run(
    threads: int, spacing: float, duration: float, method: str = "iisph", eta: float = 1e-3, warm_start=None
) -> dict:
    set_threads(threads)
    scene = scenes.dam_break_cube(spacing=spacing, method=method, eta=eta, cfl=0.5, dt_max=5e-3, warm_start=warm_start)
    sim = Simulation(scene, "cpu")
    t0 = time.perf_counter()
    sim.advance(duration)
    wall = time.perf_counter() - t0
    st = sim.stats
    stages = {k: float(np.median([s["ms"][k] for s in st])) for k in st[0]["ms"]}
    return {
        "method": method,
        "warm_start": sim.physics.pressure_start() if method == "iisph" else None,  # resolved
        "eta": eta,
        "threads": threads,
        "particles": sim.n_particles,
        "wall_seconds": wall,
        "wall_seconds_per_simulated_second": wall / sim.time,
        "steps": len(st),
        "mean_iterations": float(np.mean([s["iterations"] for s in st])),
        "mean_density_error": float(np.mean([s["compression"] for s in st])),
        "median_ms_per_step": {**stages, "total": float(np.median([sum(s["ms"].values()) for s in st]))},
    }


def chart(results: list, peers: list, path, matched: list = ()) -> None:
    plt = pyplot()

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    th = [r["threads"] for r in results]
    a.plot(
        th,
        [r["wall_seconds_per_simulated_second"] for r in results],
        "o-",
        label=f"warp_iisph IISPH ({100 * results[0]['mean_density_error']:.3f} %)",
    )
    for r, marker in zip(matched, "sD^v<>ph"):
        a.plot(
            [r["threads"]],
            [r["wall_seconds_per_simulated_second"]],
            marker,
            label=f"warp_iisph {r['method'].upper()}{' ' + r['warm_start'] if r['warm_start'] else ''} "
            f"eta {r['eta']:g} ({100 * r['mean_density_error']:.3f} %)",
        )
    for p, style in zip(peers, ("--", ":")):
        a.axhline(
            p["wall_seconds_per_simulated_second"],
            color="gray",
            ls=style,
            label=f"SPlisHSPlasH {p['method'].upper()}, {p['threads']} threads ({100 * p['mean_compression']:.3f} %)",
        )
    a.set_xlabel("threads")
    a.set_ylabel("wall s per simulated s")
    a.set_xticks(th)
    a.set_ylim(bottom=0)
    a.legend(fontsize=8)
    a.set_title(f"Dam break, {results[0]['particles']:,} particles")
    stages = [k for k in results[0]["median_ms_per_step"] if k != "total"]
    bottom = np.zeros(len(results))
    for k in stages:
        v = np.array([r["median_ms_per_step"][k] for r in results])
        b.bar([str(t) for t in th], v, bottom=bottom, label=k)
        bottom += v
    b.set_xlabel("threads")
    b.set_ylabel("median ms per step")
    b.legend(fontsize=8)
    b.set_title("Time per stage")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--spacing", type=float, default=0.03)
    ap.add_argument("--threads", default=",".join(str(t) for t in sorted({1, 2, available_cores()})))
    ap.add_argument("--no-peer", action="store_true", help="skip SPlisHSPlasH")
    ap.add_argument("--matched", default="", help="extra 2-thread runs of ours, METHOD[-WARM_START]:ETA,...")
    ap.add_argument("--quick", action="store_true", help="a coarse, short run (under a minute)")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.duration = 0.01  # a few steps of the full-size scene
        args.no_peer = True
    warm_up()  # compile outside the timing
    results = [run(int(t), args.spacing, args.duration) for t in args.threads.split(",")]
    print(f"{results[0]['particles']} particles, {args.duration} s simulated, CPU")
    print(f"{'threads':>7} {'s/sim s':>8} {'speed-up':>8} {'steps':>6} {'iters':>6}  median ms per step")
    for r in results:
        ms = ", ".join(f"{k} {v:.1f}" for k, v in r["median_ms_per_step"].items())
        print(
            f"{r['threads']:>7} {r['wall_seconds_per_simulated_second']:>8.1f} "
            f"{results[0]['wall_seconds'] / r['wall_seconds']:>8.2f} {r['steps']:>6} {r['mean_iterations']:>6.2f}  {ms}"
        )
    peers = []
    if not args.no_peer and peer_splishsplash.available():
        for method in ("iisph", "dfsph"):
            p = peer_splishsplash.run(args.duration, threads=2, method=method, spacing=args.spacing)
            peers.append(p)
            print(
                f"{p['tool']} {method.upper()}, 2 threads: "
                f"{p['wall_seconds_per_simulated_second']:.1f} s/sim s, {p['steps']} steps, "
                f"{p['mean_iterations']:.2f} iterations, mean compression {100 * p['mean_compression']:.3f} %"
            )
    elif not args.no_peer:
        print("SPlisHSPlasH: not installed (pip install 'warp_iisph[bench]'), skipped")
    for r in results:
        print(f"warp_iisph, {r['threads']} threads: mean compression {100 * r['mean_density_error']:.3f} %")
    matched = []
    for item in filter(None, args.matched.split(",")):
        method, eta = item.split(":")
        method, _, warm = method.partition("-")  # iisph-half: IISPH with that warm start
        r = run(2, args.spacing, args.duration, method, float(eta), warm or None)
        matched.append(r)
        print(
            f"warp_iisph {method.upper()}{' (' + warm + ' warm start)' if warm else ''} eta {float(eta):g}, 2 threads: "
            f"{r['wall_seconds_per_simulated_second']:.1f} s/sim s, "
            f"{r['steps']} steps, {r['mean_iterations']:.2f} iterations, "
            f"mean compression {100 * r['mean_density_error']:.3f} %"
        )
    record = header(
        "thread_scaling",
        scene="dam_break_cube",
        spacing=args.spacing,
        duration=args.duration,
        available_cores=available_cores(),
        results=results,
        peers=peers,
        matched=matched,
    )
    chart(
        results,
        peers,
        save(record, args.out, "thread_scaling" if args.quick else stem(args.duration), args.quick),
        matched,
    )


if __name__ == "__main__":
    main()
