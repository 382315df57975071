"""Surface reconstruction beside splashsurf, in one process, on the same particle frames (CPU).

Frames, simulated once with one thread and cached as ``<name>.npz`` in --frames-dir (default
``.frames/`` at the repository root, git-ignored; a missing frame takes minutes to simulate):

    dam_break_32k      scenes.dam_break_cube() after 0.5 s (32,768 particles, h = 0.03)
    martin_moyce_nx30  scenes.martin_moyce(spacing=a/30, a=0.3, depth=0.15, length=1.8, height=0.9) after 0.45 s
    martin_moyce_nx40  the same with spacing a/40
    dam_break_200k     scenes.dam_break_cube(particles=200000) after 0.3 s

For each frame and thread count, the median of --reps alternating runs after a warm-up of

    ours          SurfaceReconstructor(h).reconstruct with the defaults: cell h/2, field, marching
                  cubes, 3 Laplacian passes, vertex normals (per stage)
    splashsurf    pysplashsurf.reconstruction_pipeline with particle radius h/2, smoothing length 2
                  (support 2h), cube size 1 (h/2), iso 0.6: its field and marching cubes only
    splashsurf+   the same plus its post-processing as its README shows it: 25 weighted smoothing
                  passes, normals smoothed 10 times

(pysplashsurf runs multi-threaded on all cores when threads > 1, single-threaded for 1), and
the export of our mesh as OBJ and as binary PLY. Quality, once per frame: watertight, winding,
volume / (N h^3), area, and the normal spread (mean angle between the vertex normals at the
ends of each edge; lower is smoother), for ours (Laplacian, Taubin, none) and splashsurf (raw,
smoothed). splashsurf is optional (``pip install .[bench]``): without it those columns are
skipped. Writes benchmarks/results/surface_cpu.json and .png.

    python benchmarks/surface.py [--frames dam_break_32k,...] [--threads 1,2] [--reps 3] [--quick]

--quick: one synthetic 20k-particle frame (a slab and a ball, no simulation), one run.
"""

import argparse
import tempfile
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
import warp as wp
from common import RESULTS, header, pyplot, save

from warp_iisph.engine.launch import available_cores, get_threads, set_threads
from warp_iisph.run.formats import write_mesh
from warp_iisph.scene import Box, Sphere, SurfaceSettings
from warp_iisph.setup.sampling import sample_box, sample_sphere
from warp_iisph.surface import SurfaceReconstructor

try:
    import pysplashsurf
except ImportError:  # optional: the `bench` extra
    pysplashsurf = None

ROOT = Path(__file__).resolve().parent.parent
A = 0.3  # the Martin & Moyce column's width
FRAMES = {
    "dam_break_32k": ("scenes.dam_break_cube() after 0.5 s", 0.5),
    "martin_moyce_nx30": (
        "scenes.martin_moyce(spacing=0.3/30, a=0.3, depth=0.15, length=1.8, height=0.9) after 0.45 s",
        0.45,
    ),
    "martin_moyce_nx40": (
        "scenes.martin_moyce(spacing=0.3/40, a=0.3, depth=0.15, length=1.8, height=0.9) after 0.45 s",
        0.45,
    ),
    "dam_break_200k": ("scenes.dam_break_cube(particles=200000) after 0.3 s", 0.3),
}
# stages of SurfaceMesh.detail, grouped for the chart
GROUPS = {
    "field": ("upload", "bounds", "sort", "classify", "splat"),
    "marching cubes": ("mc_cases", "mc_emit"),
    "smoothing, normals": ("adjacency", "smooth", "normals"),
}


def _scene(name: str):
    from warp_iisph import scenes

    if name == "dam_break_32k":
        return scenes.dam_break_cube()
    if name == "dam_break_200k":
        return scenes.dam_break_cube(particles=200000)
    nx = {"martin_moyce_nx30": 30, "martin_moyce_nx40": 40}[name]
    return scenes.martin_moyce(spacing=A / nx, a=A, depth=0.15, length=1.8, height=0.9)


def load_frame(name: str, frames_dir: Path) -> tuple[np.ndarray, float]:
    """Positions and spacing of a benchmark frame, simulated (one thread) the first time."""
    path = frames_dir / f"{name}.npz"
    if not path.is_file():
        from warp_iisph import Simulation

        recipe, t_end = FRAMES[name]
        print(f"simulating {name} ({recipe}), once ...", flush=True)
        threads = get_threads()
        set_threads(1)
        try:
            scene = _scene(name)
            sim = Simulation(scene, "cpu")
            sim.advance(t_end)
        finally:
            set_threads(threads)
        frames_dir.mkdir(parents=True, exist_ok=True)
        np.savez(path, x=np.asarray(sim.positions, dtype=np.float32), h=scene.spacing, t=sim.time, recipe=recipe)
    data = np.load(path)
    return data["x"], float(data["h"])


def synthetic_frame(n: int = 20000, h: float = 0.01) -> np.ndarray:
    """About ``n`` particles: a 4:1:2 slab of 85 % of them and a ball of the rest, jittered."""
    a = (0.85 * n * h**3 / 8.0) ** (1.0 / 3.0)
    x = sample_box(Box((0, 0, 0), (4 * a, a, 2 * a)), h)
    r = (0.15 * n * h**3 * 3.0 / (4.0 * np.pi)) ** (1.0 / 3.0)
    x = np.concatenate([x, sample_sphere(Sphere((2 * a, a + 2 * r, a), r), h)])
    return (x + np.random.default_rng(0).normal(0.0, 0.05 * h, x.shape)).astype(np.float32)


def splashsurf(x: np.ndarray, h: float, threads: int, post: bool = False):
    """pysplashsurf's mesh (vertices, triangles) with the settings of the module's docstring."""
    extra = (
        {
            "mesh_smoothing_iters": 25,
            "mesh_smoothing_weights": True,
            "compute_normals": True,
            "normals_smoothing_iters": 10,
        }
        if post
        else {}
    )
    mesh, _ = pysplashsurf.reconstruction_pipeline(
        x,
        particle_radius=0.5 * h,
        smoothing_length=2.0,
        cube_size=1.0,
        iso_surface_threshold=0.6,
        multi_threading=threads > 1,
        **extra,
    )
    return np.asarray(mesh.mesh.vertices, dtype=np.float32), np.asarray(mesh.mesh.triangles, dtype=np.int64)


def vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (the same rule for every mesh compared)."""
    v = v.astype(np.float64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        for c in range(3):
            n[:, c] += np.bincount(f[:, k], weights=fn[:, c], minlength=len(v))
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def normal_spread(v: np.ndarray, f: np.ndarray) -> float:
    """Mean angle in degrees between the vertex normals at the two ends of each edge."""
    n = vertex_normals(v, f)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    e = np.unique(e[:, 0].astype(np.int64) * len(v) + e[:, 1])
    a, b = e // len(v), e % len(v)
    return float(np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n[a], n[b]), -1.0, 1.0))).mean())


def quality(v: np.ndarray, f: np.ndarray, n_particles: int, h: float) -> dict:
    import trimesh

    t = trimesh.Trimesh(v.astype(np.float64), f.astype(np.int64), process=False)
    return {
        "vertices": int(len(v)),
        "triangles": int(len(f)),
        "watertight": bool(t.is_watertight),
        "winding_consistent": bool(t.is_winding_consistent),
        "outward": bool(t.volume > 0),
        "volume_per_Nh3": float(abs(t.volume) / (n_particles * h**3)),
        "area": float(t.area),
        "normal_spread_deg": normal_spread(v, f),
    }


def median_ms(samples: list) -> float:
    return float(1e3 * np.median(samples))


def measure(name: str, x: np.ndarray, h: float, threads: int, reps: int, tmp: Path) -> dict:
    """Alternating timed runs of ours, splashsurf and splashsurf+ after one warm-up of each."""
    set_threads(threads)
    rec = SurfaceReconstructor(h, SurfaceSettings(), "cpu", profile=True)
    runs = {"ours": lambda: rec.reconstruct(x)}
    if pysplashsurf is not None:
        runs["splashsurf"] = lambda: splashsurf(x, h, threads)
        runs["splashsurf+"] = lambda: splashsurf(x, h, threads, post=True)
    wall = {k: [] for k in runs}
    details = []
    for k in range(reps + 1):
        for key, run in runs.items():
            t0 = time.perf_counter()
            out = run()
            if k:
                wall[key].append(time.perf_counter() - t0)
                if key == "ours":
                    details.append(out.detail)
            if key == "ours":
                mesh = out
    export = {"obj": [], "ply": []}
    for _ in range(reps):
        for fmt in export:
            t0 = time.perf_counter()
            write_mesh(tmp / name, mesh.vertices, mesh.faces, mesh.normals, fmt)
            export[fmt].append(time.perf_counter() - t0)
    ours = {"total": median_ms(wall["ours"]), **{s: median_ms([d[s] for d in details]) for s in details[0]}}
    row = {
        "frame": name,
        "particles": int(len(x)),
        "h": h,
        "threads": threads,
        "ours_ms": ours,
        "triangles": int(len(mesh.faces)),
        "vertices": int(len(mesh.vertices)),
        "stored_nodes": mesh.stored_nodes,
        "lattice_nodes": mesh.lattice_nodes,
        "export_ms": {fmt: median_ms(v) for fmt, v in export.items()},
        "export_mb": {fmt: (tmp / f"{name}.{fmt}").stat().st_size / 1e6 for fmt in export},
    }
    if pysplashsurf is not None:
        row["splashsurf_ms"] = median_ms(wall["splashsurf"])
        row["splashsurf_post_ms"] = median_ms(wall["splashsurf+"])
        row["ratio"] = ours["total"] / row["splashsurf_ms"]
        row["ratio_post"] = ours["total"] / row["splashsurf_post_ms"]
    return row


def frame_quality(x: np.ndarray, h: float) -> dict:
    out = {}
    for smoothing in ("laplacian", "taubin", "none"):
        m = SurfaceReconstructor(h, SurfaceSettings(smoothing=smoothing)).reconstruct(x)
        out["ours" if smoothing == "laplacian" else f"ours_{smoothing}"] = quality(m.vertices, m.faces, len(x), h)
    if pysplashsurf is not None:
        out["splashsurf"] = quality(*splashsurf(x, h, get_threads()), len(x), h)
        out["splashsurf+"] = quality(*splashsurf(x, h, get_threads(), post=True), len(x), h)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", default=",".join(FRAMES))
    ap.add_argument("--frames-dir", default=str(ROOT / ".frames"))
    ap.add_argument("--threads", default=",".join(str(t) for t in sorted({1, available_cores()})))
    ap.add_argument("--reps", type=int, default=3, help="timed runs per measurement (median), after one warm-up")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    if pysplashsurf is None:
        print("pysplashsurf is not installed (pip install .[bench]): measuring ours only")
    thread_counts = [int(t) for t in args.threads.split(",")]
    if args.quick:
        frames = {"synthetic_20k": (synthetic_frame(), 0.01)}
        args.reps = 1
    else:
        frames = {name: load_frame(name, Path(args.frames_dir)) for name in args.frames.split(",")}
    results, qualities = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name, (x, h) in frames.items():
            for threads in thread_counts:
                r = measure(name, x, h, threads, args.reps, tmp)
                results.append(r)
                side = (
                    f"; splashsurf {r['splashsurf_ms']:.0f} ms, ours/splashsurf {r['ratio']:.2f}; splashsurf+ "
                    f"{r['splashsurf_post_ms']:.0f} ms"
                    if "ratio" in r
                    else ""
                )
                print(
                    f"{name} ({len(x):,} particles), {threads} threads: ours {r['ours_ms']['total']:.0f} ms{side}; "
                    f"export OBJ {r['export_ms']['obj']:.0f} ms, PLY {r['export_ms']['ply']:.0f} ms",
                    flush=True,
                )
                print("    " + ", ".join(f"{s} {v:.1f}" for s, v in r["ours_ms"].items() if s != "total"), flush=True)
            qualities[name] = frame_quality(x, h)
            for k, q in qualities[name].items():
                print(
                    f"    {k:>16}: watertight {q['watertight']}, winding {q['winding_consistent']}, volume/Nh^3 "
                    f"{q['volume_per_Nh3']:.4f}, area {q['area']:.4f}, normal spread {q['normal_spread_deg']:.2f} deg, "
                    f"{q['vertices']:,} vertices",
                    flush=True,
                )
    record = header(
        "surface",
        "cpu",
        cell="h/2",
        smoothing="laplacian x3",
        splashsurf=version("pysplashsurf") if pysplashsurf else None,
        splashsurf_settings="reconstruction_pipeline(particle_radius=h/2, smoothing_length=2.0, cube_size=1.0, "
        "iso_surface_threshold=0.6); splashsurf+: mesh_smoothing_iters=25, "
        "mesh_smoothing_weights=True, compute_normals=True, normals_smoothing_iters=10",
        frames={k: FRAMES.get(k, ("synthetic slab and ball", 0))[0] for k in frames},
        reps=args.reps,
        results=results,
        quality=qualities,
    )
    chart(results, save(record, args.out, "surface" if args.quick else "surface_cpu", args.quick))


def chart(results, path):
    plt = pyplot()
    names = list(dict.fromkeys(r["frame"] for r in results))
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 4.2), squeeze=False)
    colours = {"field": "#4c72b0", "marching cubes": "#dd8452", "smoothing, normals": "#55a868"}
    for ax, name in zip(axes[0], names):
        rows = [r for r in results if r["frame"] == name]
        x = np.arange(len(rows))
        bottom = np.zeros(len(rows))
        for group, stages in GROUPS.items():
            v = np.array([sum(r["ours_ms"].get(s, 0.0) for s in stages) for r in rows])
            ax.bar(x - 0.2, v, 0.36, bottom=bottom, color=colours[group], label=f"ours: {group}")
            bottom += v
        if "splashsurf_ms" in rows[0]:
            ax.bar(x + 0.2, [r["splashsurf_ms"] for r in rows], 0.36, color="#8172b3", label="splashsurf")
            for xi, r in zip(x, rows):
                ax.text(
                    xi,
                    max(r["splashsurf_ms"], r["ours_ms"]["total"]) * 1.02,
                    f"ours / splashsurf {r['ratio']:.2f}",
                    ha="center",
                    fontsize=8,
                )
        ax.set_xticks(x, [f"{r['threads']} thr" for r in rows])
        ax.set_title(f"{name}\n{rows[0]['particles']:,} particles", fontsize=9)
        ax.set_ylabel("ms per frame")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(
        "Surface per frame on the CPU, both in one process (cell h/2; ours with 3 Laplacian passes and\n"
        "normals, splashsurf field and marching cubes only)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
