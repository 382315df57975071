"""Soak: 10,000 steps of a small scene with every output on (particle frames, meshes, statistics),
while a sampler thread reads the process's resident memory and open file descriptors. Both must
stay flat: a leak of a buffer per frame or a file handle per write shows as a slope. Writes
benchmarks/results/soak.json and .png.

    python benchmarks/soak.py [--steps 10000] [--quick]
"""

import argparse
import os
import tempfile
import threading
import time

import numpy as np
import warp as wp
from common import RESULTS, header, pyplot, save

from warp_iisph import scenes
from warp_iisph.run.runner import run_scene


def rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def open_files() -> int:
    return len(os.listdir("/proc/self/fd"))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--dt", type=float, default=1e-3, help="fixed step (s), so that the step count is exact")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.quick:
        args.steps = 600
    wp.config.log_level = wp.LOG_WARNING
    scene = scenes.martin_moyce(spacing=0.02, dt=args.dt)
    scene.output.mesh = True
    samples, stop = [], threading.Event()
    t0 = time.perf_counter()

    def sampler():
        while not stop.is_set():
            samples.append((time.perf_counter() - t0, rss_mib(), open_files()))
            stop.wait(0.25)

    thread = threading.Thread(target=sampler, daemon=True)
    with tempfile.TemporaryDirectory() as tmp:
        thread.start()
        record = run_scene(scene, os.path.join(tmp, "soak"), duration=args.steps * args.dt, fps=30, progress=False)
        stop.set()
        thread.join()
    t, rss, fds = (np.asarray(c) for c in zip(*samples))
    # after the first tenth (kernels compiled, buffers grown), memory and handles must not creep
    steady = t > 0.1 * t[-1]
    slope = float(np.polyfit(t[steady], rss[steady], 1)[0]) if steady.sum() > 2 else 0.0
    tenth = max(1, steady.sum() // 10)
    first, last = rss[steady][:tenth], rss[steady][-tenth:]
    result = {
        "scene": "martin_moyce, spacing 0.02 m",
        "particles": record["particles"]["fluid"],
        "steps": record["totals"]["steps"],
        "frames": record["totals"]["frames"],
        "ended": record["ended"],
        "wall_seconds": record["totals"]["wall_seconds"],
        "rss_mib_first_tenth": float(np.median(first)),
        "rss_mib_last_tenth": float(np.median(last)),
        "rss_slope_mib_per_minute": 60.0 * slope,
        "open_files_min": int(fds[steady].min()),
        "open_files_max": int(fds[steady].max()),
        "samples": {"t": t.tolist(), "rss_mib": rss.tolist(), "open_files": fds.tolist()},
    }
    print(
        f"{result['steps']} steps, {result['frames']} frames written ({result['ended']}) "
        f"in {result['wall_seconds']:.0f} s: "
        f"resident memory {result['rss_mib_first_tenth']:.0f} -> {result['rss_mib_last_tenth']:.0f} MiB "
        f"(slope {result['rss_slope_mib_per_minute']:+.2f} MiB/min), "
        f"open files {result['open_files_min']}-{result['open_files_max']}"
    )
    record = header("soak", **result)
    chart(result, save(record, args.out, "soak", args.quick))


def chart(r, path):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    s = r["samples"]
    ax.plot(s["t"], s["rss_mib"], label="resident memory (MiB)")
    ax.set_xlabel("wall seconds")
    ax.set_ylabel("MiB")
    ax2 = ax.twinx()
    ax2.plot(s["t"], s["open_files"], color="tab:orange", label="open files")
    ax2.set_ylabel("open file descriptors")
    ax2.set_ylim(0, max(s["open_files"]) * 1.5)
    ax.set_title(f"Soak: {r['steps']} steps, {r['frames']} frames of particles and meshes")
    fig.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
