"""Kernel profile on CUDA: where a step's GPU time goes, kernel by kernel, and a surface frame's.

The dam break of device_switch (a 0.96 m cube, IISPH eta 0.1 %, CFL 0.5, dt <= 5 ms) settles
for --settle simulated seconds with plain launches, then --steps steps are recorded with Warp's
CUDA activity timing (``wp.timing_begin``: kernels, copies and fills, each timed on the GPU by
CUDA events) and one surface reconstruction of the last state likewise. Per kernel: launches
per step, GPU ms per step and share; the sum of GPU time against the wall time of the same
steps says how much is launch overhead (what graph replay removes). Writes
benchmarks/results/kernel_profile.json and .png.

    python benchmarks/kernel_profile.py [--counts 1000000] [--steps 20] [--settle 0.1] [--quick]

Needs CUDA: on a machine without it, it says so and writes nothing.
"""

import argparse
import time

import numpy as np
import warp as wp
from common import RESULTS, header, pyplot, save, warm_up

from warp_iisph import Simulation, scenes
from warp_iisph.surface import SurfaceReconstructor

ACTIVITY = wp.TIMING_KERNEL | wp.TIMING_MEMCPY | wp.TIMING_MEMSET


def aggregate(results, per: int) -> list[dict]:
    """Activities summed by name, largest first: calls and GPU ms per step (``per`` steps)."""
    table = {}
    for r in results:
        row = table.setdefault(r.name, [0, 0.0])
        row[0] += 1
        row[1] += r.elapsed
    total = sum(ms for _, ms in table.values()) or 1.0
    rows = [
        {"name": name, "calls": calls / per, "ms": ms / per, "share": ms / total} for name, (calls, ms) in table.items()
    ]
    return sorted(rows, key=lambda r: -r["ms"])


def profile(device: str, count: int, settle: float, steps: int) -> dict:
    sim = Simulation(scenes.dam_break_cube(particles=count, eta=1e-3, cfl=0.5, dt_max=5e-3), device)
    sim.advance(settle)
    s0 = sim.step_count
    sim.step()  # untimed: anything that still loads
    wp.synchronize_device(device)
    wp.timing_begin(cuda_filter=ACTIVITY)
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step()
    wp.synchronize_device(device)
    wall = time.perf_counter() - t0
    step_results = wp.timing_end()
    st = sim.stats[s0 + 1 :]
    recon = SurfaceReconstructor(sim.model.spacing, sim.scene.surface, device)
    recon.reconstruct(sim.state.x)  # loads its kernels, sizes its workspace
    wp.synchronize_device(device)
    wp.timing_begin(cuda_filter=ACTIVITY)
    t0 = time.perf_counter()
    mesh = recon.reconstruct(sim.state.x)
    mesh_wall = time.perf_counter() - t0
    mesh_results = wp.timing_end()
    kernels = aggregate(step_results, steps)
    surface = aggregate(mesh_results, 1)
    return {
        "device": device,
        "particles": sim.n_particles,
        "steps": steps,
        "mean_iterations": float(np.mean([s["iterations"] for s in st])),
        "wall_ms_per_step": 1e3 * wall / steps,
        "gpu_ms_per_step": sum(k["ms"] for k in kernels),
        "launches_per_step": sum(k["calls"] for k in kernels),
        "kernels": kernels,
        "surface_wall_ms": 1e3 * mesh_wall,
        "surface_gpu_ms": sum(k["ms"] for k in surface),
        "surface_triangles": int(len(mesh.faces)),
        "surface_kernels": surface,
    }


def chart(rows, path):
    plt = pyplot()
    fig, axes = plt.subplots(1, len(rows), figsize=(6.5 * len(rows), 5), squeeze=False)
    for ax, r in zip(axes[0], rows):
        top = r["kernels"][:14]
        ax.barh([k["name"][:40] for k in top][::-1], [k["ms"] for k in top][::-1], color="tab:blue")
        ax.set_xlabel("GPU ms per step")
        ax.set_title(
            f"{r['particles']:,} particles: {r['gpu_ms_per_step']:.2f} GPU ms of "
            f"{r['wall_ms_per_step']:.2f} wall ms per step",
            fontsize=9,
        )
        ax.tick_params(axis="y", labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--counts", default="1000000")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--settle", type=float, default=0.1, help="simulated seconds before the recorded steps")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.counts, args.steps, args.settle = "8000", 3, 0.01
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    if not wp.is_cuda_available():
        print("kernel_profile needs a CUDA device; none is available here")
        return
    device = "cuda:0"
    warm_up(device)
    rows = [profile(device, int(c), args.settle, args.steps) for c in args.counts.split(",")]
    for r in rows:
        print(
            f"{r['particles']:,} particles, {r['mean_iterations']:.2f} iterations/step: "
            f"wall {r['wall_ms_per_step']:.2f} ms/step, "
            f"GPU {r['gpu_ms_per_step']:.2f} ms/step in {r['launches_per_step']:.0f} launches"
        )
        for k in r["kernels"][:20]:
            print(f"    {k['ms']:8.3f} ms {k['share']:6.1%} {k['calls']:6.1f}x  {k['name']}")
        print(
            f"  surface: wall {r['surface_wall_ms']:.1f} ms, GPU {r['surface_gpu_ms']:.2f} ms, "
            f"{r['surface_triangles']:,} triangles"
        )
        for k in r["surface_kernels"][:10]:
            print(f"    {k['ms']:8.3f} ms {k['share']:6.1%} {k['calls']:6.1f}x  {k['name']}")
    record = header(
        "kernel_profile",
        device,
        scene="dam_break_cube",
        settle=args.settle,
        activity="kernels, copies, fills",
        results=rows,
    )
    record["cuda_device_name"] = wp.get_device(device).name
    chart(rows, save(record, args.out, "kernel_profile", args.quick))


if __name__ == "__main__":
    main()
