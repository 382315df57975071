"""What probes cost: SPHERIC Test 2 (the bundled scene, 43k particles at 2.5 cm) stepped over the
same stretch of its flow (from a state taken at 0.3 s, as the water reaches the box) without
probes, with its eight pressure sensors and four level gauges sampled every step, and with its
force probe on the box as well. The particles are bitwise the same in the three (the probes only
read), so the steps are the same. The three run side by side in one process, in blocks of
--block steps taken in turn (the order rotating), so that the machine's drift (here up to 30 %
within minutes) falls on all three alike: the cost is the median over the blocks of each one's
time against the probe-less one's in the same block. The readings alone (one sample of every
probe, timed apart) are reported too. Target (issue 29): sensors and gauges every step at most 3 %.

Writes benchmarks/results/probes.json and probes.png.

    python benchmarks/probes.py [--spacing 0.025] [--steps 150] [--block 10] [--quick]
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


def simulations(spacing: float, state: dict, steps: int) -> dict:
    """The three variants, each restored to ``state`` and stepped once (its kernels loaded)."""
    sims = {}
    for variant in VARIANTS:
        sim = Simulation(scene_of(variant, spacing), "cpu", history=steps + 8)
        sim.restore(state)
        sim.step()
        sims[variant] = sim
    return sims


def reading_seconds(sim, repeat: int = 20) -> float:
    """One sample of every probe of ``sim`` (its state as it is), timed alone."""
    loop = sim.loop
    wp.synchronize()
    t0 = time.perf_counter()
    for _ in range(repeat):
        loop.probes.read(sim.state, sim.solver, loop.dt64, loop.max_speed2, loop.slot)
    wp.synchronize()
    return (time.perf_counter() - t0) / repeat


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacing", type=float, default=0.025)
    ap.add_argument("--start", type=float, default=0.3, help="simulated seconds before the timed stretch")
    ap.add_argument("--steps", type=int, default=150, help="steps each variant takes")
    ap.add_argument("--block", type=int, default=10, help="steps each variant takes in turn")
    ap.add_argument("--quick", action="store_true", help="5 cm, 12 steps in blocks of 2 (the test suite's)")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.spacing, args.start, args.steps, args.block = 0.05, 0.1, 12, 2
    wp.config.log_level = wp.LOG_WARNING
    lead = Simulation(scene_of("none", args.spacing), "cpu", history=1)
    lead.advance(args.start)
    state = lead.checkpoint()
    sims = simulations(args.spacing, state, args.steps)
    blocks = []
    for b in range(max(1, args.steps // args.block)):
        k = b % len(VARIANTS)
        seconds = {}
        for variant in VARIANTS[k:] + VARIANTS[:k]:  # the order rotates from block to block
            sim = sims[variant]
            t0 = time.perf_counter()
            for _ in range(args.block):
                sim.step()
            seconds[variant] = (time.perf_counter() - t0) / args.block
        blocks.append(seconds)
    digests = {float(np.sum(sim.positions, dtype=np.float64)) for sim in sims.values()}
    median = {v: float(np.median([b[v] for b in blocks])) for v in VARIANTS}
    cost = {v: float(np.median([b[v] / b["none"] for b in blocks])) - 1.0 for v in VARIANTS[1:]}
    reading = {v: reading_seconds(sims[v]) for v in VARIANTS[1:]}
    for v in VARIANTS:
        extra = f" ({100 * cost[v]:+.1f} %; a reading alone {1e3 * reading[v]:.2f} ms)" if v in cost else ""
        print(f"{v:14s} {1e3 * median[v]:8.1f} ms per step{extra}")
    print(f"the runs' particles agree to the bit: {len(digests) == 1}")
    record = header(
        "probes",
        spacing=args.spacing,
        particles=lead.n_particles,
        start=args.start,
        median_seconds_per_step=median,
        cost=cost,
        reading_seconds=reading,
        samples={v: len(sims[v].probes) for v in VARIANTS},
        same_particles=len(digests) == 1,
        block_steps=args.block,
        blocks=blocks,
    )
    path = save(record, args.out, "probes", args.quick)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for v in VARIANTS:
        label = f"{v} ({100 * cost[v]:+.1f} %)" if v in cost else v
        ax.plot([1e3 * b[v] for b in blocks], "o-", mfc="none", label=label)
    ax.set_xlabel(f"block of {args.block} steps (each variant in turn)")
    ax.set_ylabel("ms per step")
    ax.set_title(f"SPHERIC Test 2, {lead.n_particles} particles: probes sampled every step")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
