"""Where the time goes (the report's Figure 9): the share of wall time per stage of a dam-break
run that writes particles and a surface mesh every frame (30 frames per simulated second):
neighbour search, density, advection (non-pressure forces and IISPH's predictions), pressure
solve, integration, distance field, marching cubes, smoothing, export, and the rest (Python,
statistics, progress). Frame files are written on a background thread while the next frame
simulates; ``export`` is what that still costs the main thread (host copies and waits), and the
record also gives the writer thread's own seconds and, with --compare-inline, the wall time of
the same run writing inline. Writes benchmarks/results/breakdown.json and .png.

    python benchmarks/breakdown.py [--particles 32768] [--duration 1.0] [--device cpu] [--compare-inline] [--quick]
"""

import argparse
import tempfile

import warp as wp
from common import RESULTS, header, pyplot, save, warm_up

from warp_iisph import scenes
from warp_iisph.engine.devices import device_name
from warp_iisph.engine.launch import get_threads
from warp_iisph.run.runner import run_scene

SIMULATION = ("neighbours", "density", "advection", "pressure", "integration")
SURFACE = ("distance_field", "marching_cubes", "smoothing")


def chart(record, path):
    plt = pyplot()
    shares = record["share"]
    names = [k for k in (*SIMULATION, *SURFACE, "export", "other") if shares.get(k, 0) > 0]
    colors = {
        **{k: plt.cm.Blues(0.35 + 0.13 * i) for i, k in enumerate(SIMULATION)},
        **{k: plt.cm.Oranges(0.4 + 0.2 * i) for i, k in enumerate(SURFACE)},
        "export": "tab:green",
        "other": "lightgray",
    }
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.5), gridspec_kw={"width_ratios": [1, 1.3]})
    a.pie(
        [shares[k] for k in names],
        labels=[k.replace("_", " ") for k in names],
        colors=[colors[k] for k in names],
        autopct=lambda p: f"{p:.0f} %" if p >= 3 else "",
        startangle=90,
        counterclock=False,
        textprops={"fontsize": 8},
    )
    a.set_title(f"{record['particles']:,} particles, {record['frames']} frames, {record['device']}")
    secs = [record["stage_seconds"][k] for k in names]
    b.barh([k.replace("_", " ") for k in names][::-1], secs[::-1], color=[colors[k] for k in names][::-1])
    for y, s in enumerate(secs[::-1]):
        b.text(s, y, f" {s:.2f} s", va="center", fontsize=8)
    b.set_xlabel(
        f"wall seconds over {record['simulated_seconds']:g} simulated s (total {record['wall_seconds']:.1f} s)"
    )
    b.set_title("Time per stage")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--particles", type=int, default=32768)
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--compare-inline", action="store_true", help="also time the run with frames written inline")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.particles, args.duration = 4000, 0.1
    wp.config.log_level = wp.LOG_WARNING
    device = device_name(args.device)
    warm_up(device)
    scene = scenes.dam_break_cube(particles=args.particles, eta=1e-3, cfl=0.5, dt_max=5e-3)
    scene.output.mesh = True
    with tempfile.TemporaryDirectory() as tmp:
        run = run_scene(scene, tmp, duration=args.duration, fps=args.fps, device=device, progress=False)
    inline = None
    if args.compare_inline:
        with tempfile.TemporaryDirectory() as tmp:
            inline = run_scene(
                scene, tmp, duration=args.duration, fps=args.fps, device=device, progress=False, background_output=False
            )["totals"]["wall_seconds"]
    if run["ended"] != "completed":
        raise SystemExit(f"breakdown: the run {run['ended']}: {run['message']}")
    stages = dict(run["stage_seconds"])
    wall = run["totals"]["wall_seconds"]
    stages["other"] = max(wall - sum(stages.values()), 0.0)
    share = {k: v / wall for k, v in stages.items()}
    record = header(
        "breakdown",
        device,
        scene="dam_break_cube with meshing",
        particles=run["particles"]["fluid"],
        threads=get_threads() if device == "cpu" else None,
        frames=run["totals"]["frames"],
        simulated_seconds=run["totals"]["simulated_time"],
        steps=run["totals"]["steps"],
        wall_seconds=wall,
        stage_seconds=stages,
        share=share,
        surface=run["scene"]["surface"],
        writer_thread_seconds=run["output"]["writer_seconds"],
        inline_output_wall_seconds=inline,
    )
    print(
        f"{record['particles']} particles, {record['steps']} steps, {record['frames']} frames, "
        f"{wall:.1f} s wall on {device}"
        + (f" ({inline:.1f} s writing frames inline)" if inline else "")
        + f"; the writer thread worked {run['output']['writer_seconds']:.1f} s alongside"
    )
    for k, v in sorted(stages.items(), key=lambda kv: -kv[1]):
        print(f"{k:>15} {v:8.2f} s {100 * share[k]:5.1f} %")
    chart(record, save(record, args.out, "breakdown", args.quick))


if __name__ == "__main__":
    main()
