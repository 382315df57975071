"""Surface reconstruction speed: per-stage ms per frame for 50k and 200k particles, with 1, 2,
... CPU threads (the report's Figure 8), cell h/2, 3 Laplacian passes, OBJ export included.
The particles are a collapsed-dam shape: a slab of water with a ball above it. Also records the
distance-field nodes stored (blocks near the surface) against those of a dense lattice over the
bounding box. Writes benchmarks/results/surface.json and surface.png.

    python benchmarks/surface.py [--counts 50000,200000] [--threads 1,2] [--device cpu] [--quick]
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp

from common import RESULTS, header, pyplot, save
from warp_iisph.engine.devices import device_name
from warp_iisph.engine.launch import available_cores, set_threads
from warp_iisph.run.meshing import FrameMesher
from warp_iisph.setup.sampling import sample_box, sample_sphere
from warp_iisph.scene import Box, Sphere, SurfaceSettings

H = 0.01


def particles(n: int) -> np.ndarray:
    """About ``n`` particles: a 4:1:2 slab of 85 % of them and a ball of the rest, jittered."""
    slab = 0.85 * n * H**3
    a = (slab / 8.0) ** (1.0 / 3.0)
    x = sample_box(Box((0, 0, 0), (4 * a, a, 2 * a)), H)
    r = (0.15 * n * H**3 * 3.0 / (4.0 * np.pi)) ** (1.0 / 3.0)
    x = np.concatenate([x, sample_sphere(Sphere((2 * a, a + 2 * r, a), r), H)])
    return x + np.random.default_rng(0).normal(0.0, 0.05 * H, x.shape)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--counts", default="50000,200000")
    ap.add_argument("--threads", default=",".join(str(t) for t in sorted({1, 2, available_cores()})))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=3, help="frames per measurement (median)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.counts, args.frames = "20000", 1
    wp.config.log_level = wp.LOG_WARNING
    device = device_name(args.device)
    thread_counts = [int(t) for t in args.threads.split(",")] if device == "cpu" else [1]
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        FrameMesher(H, SurfaceSettings(), device).write(particles(1000), Path(tmp) / "warm.obj")  # compile
        for n in (int(c) for c in args.counts.split(",")):
            x = particles(n)
            for threads in thread_counts:
                set_threads(threads)
                runs = []
                for k in range(args.frames):
                    mesher = FrameMesher(H, SurfaceSettings(), device)
                    t = time.perf_counter()
                    mesh = mesher.write(x, Path(tmp) / f"f{k}.obj")
                    total = time.perf_counter() - t
                    runs.append({**{s: 1e3 * v for s, v in mesher.times.seconds.items()}, "total": 1e3 * total})
                med = {s: float(np.median([r[s] for r in runs])) for s in runs[0]}
                results.append({"particles": len(x), "threads": threads, "triangles": int(len(mesh.faces)),
                                "stored_nodes": mesh.stored_nodes, "lattice_nodes": mesh.lattice_nodes, "median_ms": med})
                print(f"{len(x):>8} particles, {threads} threads: " + ", ".join(f"{s} {v:.0f}" for s, v in med.items())
                      + f" ms ({len(mesh.faces)} triangles, {mesh.stored_nodes:,} of {mesh.lattice_nodes:,} nodes stored)")
    record = header("surface", args.device, cell="h/2", smoothing="laplacian x3", results=results,
                    reference="splashsurf 0.14 on this 2-core machine: 50k particles 0.25-0.37 s, 160k 0.5-0.9 s",
                    dense_lattice="before the block-sparse field (commit 577ce19, 2 threads): 47k particles distance "
                                  "field 283 ms, marching cubes 249 ms; 193k: 783 and 904 ms")
    chart(results, save(record, args.out, "surface" if args.quick else f"surface_{args.device}", args.quick))


def chart(results, path):
    plt = pyplot()

    counts = sorted({r["particles"] for r in results})
    fig, axes = plt.subplots(1, len(counts), figsize=(5 * len(counts), 4), squeeze=False)
    for ax, n in zip(axes[0], counts):
        rows = [r for r in results if r["particles"] == n]
        bottom = np.zeros(len(rows))
        for s in ("distance_field", "marching_cubes", "smoothing", "export"):
            v = np.array([r["median_ms"][s] for r in rows])
            ax.bar([str(r["threads"]) for r in rows], v, bottom=bottom, label=s)
            bottom += v
        ax.set_title(f"{n:,} particles, {rows[0]['stored_nodes'] / rows[0]['lattice_nodes']:.0%} of the lattice stored")
        ax.set_xlabel("threads")
        ax.set_ylabel("ms per frame")
        ax.legend(fontsize=8)
    fig.suptitle("Surface reconstruction per frame (cell h/2, 3 Laplacian passes, OBJ export)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
