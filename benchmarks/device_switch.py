"""Device switch: the same dam break (a 0.96 m cube of water in a 4 x 3 x 1.5 m tank, IISPH,
eta 0.1 %, CFL 0.5, dt <= 5 ms) at several particle counts on each device asked for: wall ms
per step, wall seconds per simulated second, particle-steps per second and the speed-up of
each device over the CPU. A device that is not present is reported and skipped.

Against the hardware's limit: each row gives the bytes a step must move at least (a model of
the solver's compulsory memory traffic, see ``bytes_per_step``), the device's copy bandwidth
measured here, and the ratio of that bound to the measured step. With --mesh the surface is
also rebuilt 30 times per simulated second (the product's target: 1 simulated second per wall
second for 1M particles with meshing on one H100), and ``realtime_ratio`` says how far a row
is from it. ``--method dfsph`` runs DFSPH instead (the bytes model stays IISPH's). Writes
benchmarks/results/device_switch[_dfsph][_graph][_mesh].json and .png.

    python benchmarks/device_switch.py [--devices cpu,cuda] [--counts 10000,30000,100000] [--duration 0.25]
                                       [--graph] [--mesh] [--method iisph|dfsph] [--quick]
    # on a GPU: --devices cuda --counts 100000,300000,1000000 --graph --mesh
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import warp as wp
from common import RESULTS, header, present_devices, pyplot, save, warm_up

from warp_iisph import Simulation, scenes
from warp_iisph.run.formats import write_mesh
from warp_iisph.surface import SurfaceReconstructor

FPS = 30.0
# fixed per-particle bytes of one step's passes (arrays read and written once each): neighbour
# count and fill 72, density 20, advection 96, integration and state check 80
PARTICLE_BYTES = 268
PARTICLE_BYTES_PER_ITERATION = (
    112  # sum_dij_pj 44 (with d_ii read, displacement written), jacobi 52, p copy 8, error sum 8
)
ENTRY_BYTES = 16  # one neighbour-list entry: index (4) and grad W (12)


def bytes_per_step(n: int, fluid_entries: int, boundary_entries: int, iterations: float) -> float:
    """The least DRAM traffic of one IISPH step: each neighbour-list entry written once and
    streamed by every pass that walks it (advection twice, integration, density's indices, and
    per Jacobi iteration the fluid lists twice and the boundary lists once), plus each particle's
    arrays once per pass. Neighbours' values gathered through the lists are counted as cache hits
    (particles are ordered by grid cell), so this is a lower bound."""
    e = fluid_entries + boundary_entries
    lists = ENTRY_BYTES * e * 4 + 4 * e + iterations * ENTRY_BYTES * (2 * fluid_entries + boundary_entries)
    return lists + n * (PARTICLE_BYTES + iterations * PARTICLE_BYTES_PER_ITERATION)


def copy_bandwidth(device: str, megabytes: int = 512, repeats: int = 5) -> float:
    """Bytes per second a device-to-device copy moves (read plus write): the practical peak."""
    a = wp.zeros(megabytes * 2**18, dtype=float, device=device)
    b = wp.empty_like(a)
    wp.copy(b, a)
    wp.synchronize_device(device)
    t = time.perf_counter()
    for _ in range(repeats):
        wp.copy(b, a)
    wp.synchronize_device(device)
    return 2.0 * a.capacity * repeats / (time.perf_counter() - t)


def run(
    device: str, count: int, duration: float, graph: bool = False, mesh: bool = False, method: str = "iisph"
) -> dict:
    scene = scenes.dam_break_cube(particles=count, method=method, eta=1e-3, cfl=0.5, dt_max=5e-3)
    sim = Simulation(scene, device, graph=graph)
    sim.step()  # a plain first step loads the kernels; the graph path records its graph on the second
    sim.step()
    recon = SurfaceReconstructor(sim.model.spacing, sim.scene.surface, sim.device) if mesh else None
    if recon is not None:
        recon.reconstruct(sim.state.x)  # loads its kernels
    frames = max(1, round(duration * FPS)) if mesh else 1
    steps0, t_sim0 = sim.step_count, sim.time
    wall = mesh_wall = 0.0
    triangles, export = [], {"ply": [], "obj": []}
    stage_ms = {}
    tmp = tempfile.TemporaryDirectory() if mesh else None
    for _ in range(frames):
        t0 = time.perf_counter()
        sim.advance(duration / frames)
        wp.synchronize_device(sim.device)
        wall += time.perf_counter() - t0
        if recon is not None:
            t0 = time.perf_counter()
            surface = recon.reconstruct(sim.state.x)
            mesh_wall += time.perf_counter() - t0
            triangles.append(len(surface.faces))
            for k, v in surface.seconds.items():
                stage_ms.setdefault(k, []).append(1e3 * v)
            for fmt in export:  # as the frame writer would, off the simulation's thread
                t0 = time.perf_counter()
                write_mesh(Path(tmp.name) / "frame", surface.vertices, surface.faces, surface.normals, fmt)
                export[fmt].append(1e3 * (time.perf_counter() - t0))
    if tmp is not None:
        tmp.cleanup()
    st = sim.stats[steps0:]
    search = sim.solver.search
    n = sim.n_particles  # entries the lists hold (the fluid lists' unused slots are not streamed)
    entries = (int(search.fluid.lists.count.numpy()[:n].sum()), int(search.boundary.lists.count.numpy()[:n].sum()))
    iterations = float(np.mean([s["iterations"] for s in st]))
    simulated = sim.time - t_sim0
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
        "mean_iterations": iterations,
        "mean_density_error": float(np.mean([s["compression"] for s in st])),
        "median_stage_ms": {k: float(np.median([s["ms"][k] for s in st])) for k in st[0]["ms"]},
        "neighbour_entries": {"fluid": entries[0], "boundary": entries[1]},
        "bytes_per_step": bytes_per_step(sim.n_particles, *entries, iterations),
        "mesh_frames": frames if mesh else 0,
        "mesh_ms_per_frame": 1e3 * mesh_wall / frames if mesh else None,
        "mesh_triangles": int(np.median(triangles)) if mesh else None,
        "mesh_stage_ms": {k: float(np.median(v)) for k, v in stage_ms.items()} if mesh else None,
        # writing a frame's mesh (binary PLY, OBJ text): the run's frame writer does this on its
        # own thread while the next frame simulates, so it adds to the wall time only where it
        # takes longer than simulating a frame
        "export_ms_per_frame": {k: float(np.median(v)) for k, v in export.items()} if mesh else None,
        "wall_seconds_with_mesh": wall + mesh_wall if mesh else None,
        "realtime_ratio": simulated / (wall + mesh_wall),  # simulated s per wall s, meshing included with --mesh
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
    ap.add_argument(
        "--graph",
        action="store_true",
        help="replay graph-captured steps (warp_iisph.stepping.graph) instead of plain launches",
    )
    ap.add_argument("--mesh", action="store_true", help=f"also rebuild the surface {FPS:g} times per simulated second")
    ap.add_argument(
        "--method",
        default="iisph",
        choices=("iisph", "dfsph"),
        help="the pressure solver (dfsph: its constant-density and divergence-free solves; the bytes model is IISPH's)",
    )
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.counts, args.duration = "2000,8000", 0.05
    wp.config.log_level = wp.LOG_WARNING
    wp.init()
    devices, missing = present_devices(args.devices)
    rows, bandwidth = [], {}
    for dev in devices:
        warm_up(dev, args.method)
        bandwidth[dev] = copy_bandwidth(dev, 64 if args.quick else 512)
        for count in (int(c) for c in args.counts.split(",")):
            r = run(dev, count, args.duration, args.graph, args.mesh, args.method)
            r["copy_bandwidth"] = bandwidth[dev]
            r["bandwidth_bound_ms"] = 1e3 * r["bytes_per_step"] / bandwidth[dev]
            r["fraction_of_bandwidth_bound"] = r["bandwidth_bound_ms"] / r["ms_per_step"]
            rows.append(r)
    cpu = {r["particles"]: r for r in rows if r["device"] == "cpu"}
    print(
        f"{'device':>6} {'particles':>9} {'steps':>5} {'ms/step':>8} {'s/sim s':>8} "
        f"{'Mpart-steps/s':>13} {'iters':>5} {'vs cpu':>6}"
        f" {'MB/step':>8} {'bound ms':>8} {'of bound':>8}" + (f" {'mesh ms':>8} {'sim s/s':>8}" if args.mesh else "")
    )
    for r in rows:
        r["speed_up_over_cpu"] = (
            cpu[r["particles"]]["wall_seconds"] / r["wall_seconds"]
            if r["device"] != "cpu" and r["particles"] in cpu
            else None
        )
        up = f"{r['speed_up_over_cpu']:.1f}x" if r["speed_up_over_cpu"] else "-"
        print(
            f"{r['device']:>6} {r['particles']:>9} {r['steps']:>5} {r['ms_per_step']:>8.1f} "
            f"{r['wall_seconds_per_simulated_second']:>8.1f} "
            f"{r['particle_steps_per_second'] / 1e6:>13.2f} {r['mean_iterations']:>5.2f} {up:>6} "
            f"{r['bytes_per_step'] / 1e6:>8.1f} "
            f"{r['bandwidth_bound_ms']:>8.2f} {r['fraction_of_bandwidth_bound']:>8.1%}"
            + (
                f" {r['mesh_ms_per_frame']:>8.1f} {r['realtime_ratio']:>8.3f} "
                f" PLY {r['export_ms_per_frame']['ply']:.0f} ms,"
                f" OBJ {r['export_ms_per_frame']['obj']:.0f} ms"
                if args.mesh
                else ""
            )
        )
    print("copy bandwidth: " + ", ".join(f"{d} {b / 1e9:.1f} GB/s" for d, b in bandwidth.items()))
    record = header(
        "device_switch",
        devices[0],
        scene="dam_break_cube",
        method=args.method,
        duration=args.duration,
        graph=args.graph,
        mesh=args.mesh,
        mesh_fps=FPS if args.mesh else None,
        devices_missing=missing,
        copy_bandwidth=bandwidth,
        target="1M particles, meshing at 30 fps included: realtime_ratio >= 1 on one H100",
        results=rows,
    )
    if "cuda" in devices:
        record["cuda_device_name"] = wp.get_device("cuda:0").name
    stem = "device_switch" + ("_dfsph" if args.method == "dfsph" else "") + ("_graph" if args.graph else "")
    stem += "_mesh" if args.mesh else ""
    chart(rows, save(record, args.out, stem, args.quick))


if __name__ == "__main__":
    main()
