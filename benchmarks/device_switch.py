"""Device switch: the same dam break (a 0.96 m cube of water in a 4 x 3 x 1.5 m tank, IISPH,
eta 0.1 %, CFL 0.5, dt <= 5 ms) at several particle counts on each device asked for: wall ms
per step, wall seconds per simulated second, particle-steps per second and the speed-up of
each device over the CPU. A device that is not present is reported and skipped. Writes
benchmarks/results/device_switch.json and .png.

    python benchmarks/device_switch.py [--devices cpu,cuda] [--counts 10000,30000,100000] [--duration 0.25] [--quick]
"""

import argparse
import time

import numpy as np
import warp as wp

from common import RESULTS, header, pyplot, save, warm_up
from warp_iisph import Simulation, scenes


def run(device: str, count: int, duration: float, graph: bool = False) -> dict:
    sim = Simulation(scenes.dam_break_cube(particles=count, eta=1e-3, cfl=0.5, dt_max=5e-3), device, graph=graph)
    sim.step()  # the graph path records its graph on the first advance; keep set-up out of the timing
    sim.advance(sim.next_dt())
    steps0, t_sim0 = sim.step_count, sim.time
    t0 = time.perf_counter()
    sim.advance(duration)
    wall = time.perf_counter() - t0
    st = sim.stats[steps0:]
    return {
        "device": device,
        "graph": graph,
        "particles": sim.n_particles,
        "spacing": sim.model.spacing,
        "simulated_seconds": sim.time - t_sim0,
        "steps": len(st),
        "wall_seconds": wall,
        "ms_per_step": 1e3 * wall / len(st),
        "wall_seconds_per_simulated_second": wall / (sim.time - t_sim0),
        "particle_steps_per_second": sim.n_particles * len(st) / wall,
        "mean_iterations": float(np.mean([s["iterations"] for s in st])),
        "mean_density_error": float(np.mean([s["compression"] for s in st])),
        "median_stage_ms": {k: float(np.median([s["ms"][k] for s in st])) for k in st[0]["ms"]},
    }


def chart(rows, path):
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for dev, marker in (("cpu", "s-"), ("cuda", "o-")):
        r = [x for x in rows if x["device"] == dev]
        if r:
            n = [x["particles"] for x in r]
            a.plot(n, [x["ms_per_step"] for x in r], marker, label=dev)
            b.plot(n, [x["particle_steps_per_second"] for x in r], marker, label=dev)
    for ax, label in ((a, "wall ms per step"), (b, "particle-steps per second")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("fluid particles")
        ax.set_ylabel(label)
        ax.legend()
    a.set_title("Dam break, IISPH eta 0.1 %, CFL 0.5")
    b.set_title("Throughput")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devices", default="cpu,cuda")
    ap.add_argument("--counts", default="10000,30000,100000")
    ap.add_argument("--duration", type=float, default=0.25, help="simulated seconds per run")
    ap.add_argument("--graph", action="store_true", help="replay graph-captured steps (warp_iisph.graph) instead of plain launches")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.counts, args.duration = "2000,8000", 0.05
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    devices, missing = [], []
    for d in args.devices.split(","):
        (devices if d == "cpu" or (d == "cuda" and wp.is_cuda_available()) else missing).append(d)
    for d in missing:
        print(f"device {d}: not present on this machine, skipped")
    rows = []
    for dev in devices:
        warm_up(dev)
        for count in (int(c) for c in args.counts.split(",")):
            rows.append(run(dev, count, args.duration, args.graph))
    cpu = {r["particles"]: r for r in rows if r["device"] == "cpu"}
    print(f"{'device':>6} {'particles':>9} {'steps':>5} {'ms/step':>8} {'s/sim s':>8} {'Mpart-steps/s':>13} {'iters':>5} {'vs cpu':>6}")
    for r in rows:
        r["speed_up_over_cpu"] = cpu[r["particles"]]["wall_seconds"] / r["wall_seconds"] if r["device"] != "cpu" and r["particles"] in cpu else None
        up = f"{r['speed_up_over_cpu']:.1f}x" if r["speed_up_over_cpu"] else "-"
        print(f"{r['device']:>6} {r['particles']:>9} {r['steps']:>5} {r['ms_per_step']:>8.1f} {r['wall_seconds_per_simulated_second']:>8.1f} "
              f"{r['particle_steps_per_second'] / 1e6:>13.2f} {r['mean_iterations']:>5.2f} {up:>6}")
    record = header("device_switch", devices[0], scene="dam_break_cube", duration=args.duration, graph=args.graph,
                    devices_missing=missing, results=rows)
    if "cuda" in devices:
        record["cuda_device_name"] = wp.get_device("cuda:0").name
    chart(rows, save(record, args.out, "device_switch_graph" if args.graph else "device_switch", args.quick))


if __name__ == "__main__":
    main()
