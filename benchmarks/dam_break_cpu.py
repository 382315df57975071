"""Dam break with 32,768 fluid particles (0.96 m cube at 3 cm spacing in a 4 x 3 x 1.5 m tank),
1 s simulated with IISPH (eta 0.1 %, CFL 0.5, dt <= 5 ms). Prints wall seconds per simulated
second, steps, mean iterations, mean density error and ms per stage; writes the numbers to
benchmarks/results/dam_break_<device>.json.

    python benchmarks/dam_break_cpu.py [--device cpu|cuda] [--duration 1.0] [--spacing 0.03]
"""

import argparse
import datetime
import json
import platform
import time
from pathlib import Path

import numpy as np
import warp as wp

from warp_iisph import Simulation, scenes
from warp_iisph.runner import versions


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--spacing", type=float, default=0.03)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results"))
    args = ap.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    device = "cuda:0" if args.device == "cuda" else args.device
    Simulation(scenes.hydrostatic_tank(spacing=0.05), device).step()  # compile kernels outside the timing
    sim = Simulation(scenes.dam_break_cube(spacing=args.spacing, eta=1e-3, cfl=0.5, dt_max=5e-3), device)
    t0 = time.perf_counter()
    sim.advance(args.duration)
    wall = time.perf_counter() - t0
    st = sim.stats
    stages = {k: float(np.mean([s["ms"][k] for s in st])) for k in st[0]["ms"]}
    result = {
        "scene": "dam_break_cube",
        "particles": sim.n_particles,
        "boundary_particles": sim.model.n_boundary,
        "device": str(sim.device),
        "machine": platform.processor() or platform.machine(),
        "cores": __import__("os").cpu_count(),
        "date": datetime.date.today().isoformat(),
        "versions": versions(),
        "simulated_seconds": sim.time,
        "wall_seconds": wall,
        "wall_seconds_per_simulated_second": wall / sim.time,
        "steps": len(st),
        "mean_dt": float(np.mean([s["dt"] for s in st])),
        "mean_iterations": float(np.mean([s["iterations"] for s in st])),
        "mean_solver_density_error": float(np.mean([s["density_error"] for s in st])),
        "mean_density_error": float(np.mean([s["compression"] for s in st])),
        "ms_per_step": {**stages, "total": float(sum(stages.values()))},
    }
    print(f"{result['particles']} particles on {result['device']}: {wall:.1f} s wall for {sim.time:.2f} s simulated "
          f"= {result['wall_seconds_per_simulated_second']:.1f} s per simulated second")
    print(f"steps {result['steps']}, mean dt {1e3 * result['mean_dt']:.2f} ms, mean iterations {result['mean_iterations']:.1f}, "
          f"mean density error {100 * result['mean_density_error']:.3f} % (solver's {100 * result['mean_solver_density_error']:.3f} %)")
    print("ms per step: " + ", ".join(f"{k} {v:.1f}" for k, v in result["ms_per_step"].items()))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"dam_break_{args.device}.json").write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
