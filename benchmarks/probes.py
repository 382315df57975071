"""What probes cost: SPHERIC Test 2 (the bundled scene, 43k particles at 2.5 cm) stepped over the
same stretch of its flow (from a state taken at 0.3 s, as the water reaches the box) without
probes, with its eight pressure sensors and four level gauges sampled every step, and with its
force probe on the box as well. The particles are bitwise the same in the three (the probes only
read), so the steps are the same: the cost is the difference in wall seconds per step, the median
over --repeat interleaved repeats. Target (issue 29): sensors and gauges every step at most 3 %.

Writes benchmarks/results/probes.json and probes.png.

    python benchmarks/probes.py [--spacing 0.025] [--steps 150] [--repeat 5] [--quick]
"""

import argparse
import time

import numpy as np
import warp as wp
from common import RESULTS, header, pyplot, save

from warp_iisph import Simulation
from warp_iisph.scene import load_scene

VARIANTS = ("none", "sensors", "sensors+force")


def scene_of(variant: str, spacing: float):
    scene = load_scene("spheric_test2", [f"spacing={spacing!r}", "output.probe_interval=0"])
    if variant == "none":
        scene.probes = []
    elif variant == "sensors":
        scene.probes = [p for p in scene.probes if p.kind != "force"]
    return scene


def measure(variant: str, spacing: float, state: dict, steps: int) -> dict:
    sim = Simulation(scene_of(variant, spacing), "cpu", history=steps + 8)
    sim.restore(state)
    sim.step()  # loads the probes' kernels outside the timing
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    wall = time.perf_counter() - t0
    return {
        "variant": variant,
        "steps": steps,
        "seconds_per_step": wall / steps,
        "probes": len(sim.scene.probes),
        "samples": len(sim.probes),
        "x_digest": float(np.sum(sim.positions, dtype=np.float64)),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacing", type=float, default=0.025)
    ap.add_argument("--start", type=float, default=0.3, help="simulated seconds before the timed stretch")
    ap.add_argument("--steps", type=int, default=150, help="steps timed per repeat")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="5 cm, 20 steps, 2 repeats (the test suite's)")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.spacing, args.start, args.steps, args.repeat = 0.05, 0.1, 20, 2
    wp.config.log_level = wp.LOG_WARNING
    lead = Simulation(scene_of("none", args.spacing), "cpu", history=1)
    lead.advance(args.start)
    state = lead.checkpoint()
    rows = []
    for rep in range(args.repeat):
        for variant in VARIANTS if rep % 2 == 0 else VARIANTS[::-1]:  # interleaved, either way round
            rows.append({**measure(variant, args.spacing, state, args.steps), "repeat": rep})
    digests = {r["x_digest"] for r in rows}
    median = {v: float(np.median([r["seconds_per_step"] for r in rows if r["variant"] == v])) for v in VARIANTS}
    cost = {v: median[v] / median["none"] - 1.0 for v in VARIANTS[1:]}
    for v in VARIANTS:
        extra = f" ({100 * cost[v]:+.1f} %)" if v in cost else ""
        print(f"{v:14s} {1e3 * median[v]:8.1f} ms per step{extra}")
    print(f"the runs' particles agree to the bit: {len(digests) == 1}")
    record = header(
        "probes",
        spacing=args.spacing,
        particles=lead.n_particles,
        start=args.start,
        median_seconds_per_step=median,
        cost=cost,
        same_particles=len(digests) == 1,
        runs=rows,
    )
    path = save(record, args.out, "probes", args.quick)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for k, v in enumerate(VARIANTS):
        times = [1e3 * r["seconds_per_step"] for r in rows if r["variant"] == v]
        ax.plot([k] * len(times), times, "o", mfc="none")
        ax.plot([k - 0.2, k + 0.2], [1e3 * median[v]] * 2, "k-")
    ax.set_xticks(range(len(VARIANTS)), [f"{v}\n{100 * cost[v]:+.1f} %" if v in cost else v for v in VARIANTS])
    ax.set_ylabel("ms per step")
    ax.set_title(f"SPHERIC Test 2, {lead.n_particles} particles: probes sampled every step ({args.repeat} repeats)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
