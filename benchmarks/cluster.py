"""Sweeps and render farms on Dask against the same work done one piece after another, in one run
on the same cores: the wall time of the whole command, as a user types it.

1. ``warp-iisph sweep`` of the Martin & Moyce dam break at 2 cm (2,000 particles: one CPU thread
   per run either way) over 4 s, 4 variants (physics.viscosity 0.02, 0.05 x
   physics.boundary_viscosity 0, 0.1): in this process one after another, then with
   ``--workers N`` (a LocalCluster; its start and shut-down counted, some 4 s here). Target: at
   most 0.6 x.
   Beside it: the CPU an idle LocalCluster takes (its scheduler's, nannies' and workers'
   housekeeping), with the package's intervals and with Dask's own.
2. ``warp-iisph render`` of 8 mesh frames of that dam break (640x360, 16 samples, as the
   command's defaults) one after another, then with ``--workers N``. Target: at most 0.6 x.

Each is timed ``--repeats`` times (default 3), serial and parallel alternated, and the medians
compared. Beside each, in the same run, the best any engine could do on these cores: for the sweep,
its variants split into N plain ``warp-iisph sweep`` processes started together, no scheduler at
all, against the whole sweep in one (alternated, medians); for the render, the CPU seconds the
serial command used over its wall time (how many cores it already keeps busy: a farm on the same
C cores, doing at least that work, cannot beat that share of C). Both check that the parallel
command wrote what the serial one did (the variants' particle frames and step records but their
timings; the rendered PNGs, byte for byte). Writes
benchmarks/results/cluster.json and cluster.png.

    python benchmarks/cluster.py [--workers 2] [--quick] [--replot]

--quick (proves it works; its times say little): 0.2 s of simulation per variant, 160x90 frames
at 4 samples, 1 s of idle housekeeping. Needs the cluster extra (Dask) and, for the render, the render extra (Mitsuba).
"""

import argparse
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import warp as wp
from common import RESULTS, header, pyplot, save, saved

from warp_iisph.engine.devices import init_warp

TARGET = 0.6
SCENE = ["martin_moyce", "--set", "spacing=0.02"]
VARY = ["--vary", "physics.viscosity=0.02,0.05", "--vary", "physics.boundary_viscosity=0,0.1"]


def children_cpu() -> float:
    """CPU seconds (user and system) used so far by this process's waited-for children."""
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def command(*args, cpu: list | None = None) -> float:
    """Run ``warp-iisph ARGS``; its wall seconds (a failure stops the benchmark with its stderr).
    The CPU seconds it used (its children's included) are appended to ``cpu`` where given."""
    cpu0, t0 = children_cpu(), time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "warp_iisph.cli", *args], capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if cpu is not None:
        cpu.append(children_cpu() - cpu0)
    if proc.returncode != 0:
        sys.exit(f"warp-iisph {' '.join(args)}: exit status {proc.returncode}\n{proc.stderr}")
    return seconds


def together(*commands) -> float:
    """Wall seconds of ``warp-iisph`` commands started at once as plain processes, until the last
    ends (their stderr in files, so that none waits on a full pipe); a failure stops the benchmark."""
    with tempfile.TemporaryDirectory(prefix="together_") as tmp:
        errs = [open(Path(tmp) / f"{k}.err", "w+") for k in range(len(commands))]
        t0 = time.perf_counter()
        procs = [
            subprocess.Popen([sys.executable, "-m", "warp_iisph.cli", *a], stdout=subprocess.DEVNULL, stderr=err)
            for a, err in zip(commands, errs)
        ]
        codes = [proc.wait() for proc in procs]
        seconds = time.perf_counter() - t0
        for code, a, err in zip(codes, commands, errs):
            err.seek(0)
            if code != 0:
                sys.exit(f"warp-iisph {' '.join(a)}: exit status {code}\n{err.read()}")
            err.close()
    return seconds


def split_sweep(work: Path, workers: int, duration: float, k: int) -> float:
    """The sweep with no engine at all: its variants split by the first varied key's values into
    ``workers`` plain ``warp-iisph sweep`` processes started together (each with the threads a
    worker's task has, the cores over the workers); wall seconds until the last ends."""
    key, values = VARY[1].split("=")
    shares = [values.split(",")[w::workers] for w in range(workers)]
    threads = max(1, len(os.sched_getaffinity(0)) // workers)
    rest = [*SCENE, *VARY[2:], "--duration", str(duration), "--no-progress", "--threads", str(threads)]
    return together(
        *[
            ["sweep", "--vary", f"{key}={','.join(v)}", *rest, "--out", str(work / f"split{k}_{w}")]
            for w, v in enumerate(shares)
            if v
        ]
    )


def same_runs(a: Path, b: Path) -> bool:
    """Whether two sweep folders hold the same variants: particle frames (but meshio's time stamp)
    and step records (but their timings)."""

    def content(sweep: Path) -> dict:
        out = {}
        for f in sorted(sweep.glob("*/particles/*.ply")):
            out[str(f.relative_to(sweep))] = re.sub(rb"comment Created by meshio[^\n]*\n", b"", f.read_bytes())
        for f in sorted(sweep.glob("*/stats.jsonl")):
            out[str(f.relative_to(sweep))] = [
                {k: v for k, v in json.loads(line).items() if k != "ms"} for line in f.read_text().splitlines()
            ]
        return out

    ca = content(a)
    return bool(ca) and ca == content(b)


def alternated(repeats: int, *runs) -> list[list]:
    """``repeats`` timings of each of ``runs`` (functions of the repeat's number), the order
    rotated each repeat so that none always goes first; one list of timings per run."""
    times = [[] for _ in runs]
    for k in range(repeats):
        for j in range(len(runs)):
            i = (j + k) % len(runs)
            times[i].append(runs[i](k))
    return times


def sweep_timing(work: Path, workers: int, duration: float, repeats: int) -> dict:
    args = [*SCENE, *VARY, "--duration", str(duration), "--no-progress"]
    serials, parallels, splits = alternated(
        repeats,
        lambda k: command("sweep", *args, "--out", str(work / f"serial{k}")),
        lambda k: command("sweep", *args, "--workers", str(workers), "--out", str(work / f"parallel{k}")),
        lambda k: split_sweep(work, workers, duration, k),
    )
    serial, parallel, split = (statistics.median(t) for t in (serials, parallels, splits))
    record = json.loads((work / "parallel0" / "sweep.json").read_text())
    return {
        "scene": " ".join(SCENE),
        "vary": VARY[1::2],
        "duration": duration,
        "variants": len(record["variants"]),
        "particles": record["variants"][0]["summary"]["particles"]["fluid"],
        "repeats": repeats,
        "serial_seconds": serial,  # medians of the repeats
        "workers_seconds": parallel,
        "serial_runs": serials,
        "workers_runs": parallels,
        "ratio": parallel / serial,
        "variant_seconds": [e["wall_seconds"] for e in record["variants"]],
        "same_results": all(same_runs(work / "serial0", work / f"parallel{k}") for k in range(repeats)),
        # the best on these cores with no engine: the variants split over `workers` plain
        # processes started together (split_sweep), against the serial sweep
        "split_seconds": split,
        "split_runs": splits,
        "floor": split / serial,
    }


def housekeeping(workers: int, seconds: float = 10.0) -> dict:
    """CPU seconds a LocalCluster of ``workers`` (this process, which holds its scheduler and
    nannies, and its worker processes) uses in ``seconds`` with no task to run: with the package's
    slowed housekeeping (run/cluster.py's LOCAL_CLUSTER_CONFIG) and with Dask's own intervals.
    On cores kept busy by the tasks, that is CPU taken from them."""
    import psutil

    from warp_iisph.run import cluster

    def idle(config: dict) -> float:
        kept, cluster.LOCAL_CLUSTER_CONFIG = cluster.LOCAL_CLUSTER_CONFIG, config
        try:
            with cluster.open_workers(workers=workers):
                time.sleep(2.0)  # the workers' start-up done
                procs = [psutil.Process(), *psutil.Process().children(recursive=True)]
                before = [sum(p.cpu_times()[:2]) for p in procs]
                time.sleep(seconds)
                return sum(sum(p.cpu_times()[:2]) - b for p, b in zip(procs, before))
        finally:
            cluster.LOCAL_CLUSTER_CONFIG = kept

    slowed, default = idle(cluster.LOCAL_CLUSTER_CONFIG), idle({})
    return {
        "seconds": seconds,
        "config": cluster.LOCAL_CLUSTER_CONFIG,
        "cpu_seconds": slowed,
        "cpu_seconds_dask_defaults": default,
        "cores_taken": slowed / seconds,
        "cores_taken_dask_defaults": default / seconds,
    }


def render_timing(work: Path, workers: int, resolution: str, spp: int, repeats: int) -> dict:
    run = work / "meshed"
    command("run", *SCENE, "--duration", str(7 / 30), "--fps", "30", "--mesh", "--out", str(run), "--no-progress")
    args = ["--resolution", resolution, "--spp", str(spp), "--no-progress"]

    def copy(name: str, k: int) -> Path:
        twin = work / f"{name}{k}"
        shutil.copytree(run, twin)
        return twin

    serial_cpu = []
    serials, parallels = alternated(
        repeats,
        lambda k: command("render", str(copy("meshed_serial", k)), *args, cpu=serial_cpu),
        lambda k: command("render", str(copy("meshed_farm", k)), *args, "--workers", str(workers)),
    )
    serial, parallel = statistics.median(serials), statistics.median(parallels)
    busy = statistics.median(c / s for c, s in zip(serial_cpu, serials))
    run, twins = work / "meshed_serial0", [work / f"meshed_farm{k}" for k in range(repeats)]
    pngs = sorted((run / "frames").glob("frame_*.png"))
    return {
        "frames": len(pngs),
        "resolution": resolution,
        "spp": spp,
        "variant": json.loads((run / "frames" / "source.json").read_text())["settings"]["variant"],
        "repeats": repeats,
        "serial_seconds": serial,  # medians of the repeats
        "workers_seconds": parallel,
        "serial_runs": serials,
        "workers_runs": parallels,
        "ratio": parallel / serial,
        # cores the serial render keeps busy (its CPU seconds over its wall time), and so the best
        # ratio any farm on these same cores could reach (doing at least the serial CPU work)
        "serial_cores_busy": busy,
        "floor": busy / len(os.sched_getaffinity(0)),
        "same_results": bool(pngs)
        and all(
            all(p.read_bytes() == (twin / "frames" / p.name).read_bytes() for p in pngs)
            and len(pngs) == len(list((twin / "frames").glob("frame_*.png")))
            for twin in twins
        ),
    }


def chart(record: dict, path: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    rows = [(name, record[key]) for name, key in (("sweep, 4 variants", "sweep"), ("render, 8 frames", "render"))]
    rows = [(name, r) for name, r in rows if r]
    for k, (_, r) in enumerate(rows):
        serial, farm = ("one after another", f"{record['workers']} workers") if k == 0 else (None, None)
        ax.bar(k - 0.2, r["serial_seconds"], 0.4, color="tab:gray", label=serial)
        ax.bar(k + 0.2, r["workers_seconds"], 0.4, color="tab:blue", label=farm)
        best = r["floor"] * r["serial_seconds"]
        best_label = "best on these cores" if k == 0 else None
        ax.hlines(best, k - 0.42, k + 0.42, colors="k", linestyles="--", label=best_label)
        ax.annotate(
            f"{r['ratio']:.2f} x" + ("" if r["same_results"] else " (results differ!)"),
            (k + 0.2, r["workers_seconds"]),
            textcoords="offset points",
            xytext=(0, 4),
            ha="center",
        )
    ax.set_xticks(range(len(rows)), [name for name, _ in rows])
    ax.set_ylabel("wall seconds of the command")
    ax.set_ylim(0, 1.4 * max(max(r["serial_seconds"], r["workers_seconds"]) for _, r in rows))
    ax.set_title(f"Dask LocalCluster of {record['workers']} against one process (target <= {TARGET} x)")
    ax.legend(loc="upper center", ncol=3, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=2, help="local worker processes (default 2)")
    ap.add_argument("--repeats", type=int, default=3, help="timings of each, alternated; medians reported")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--replot", action="store_true", help="redraw the chart from the saved JSON; run nothing")
    args = ap.parse_args()
    if args.replot:
        record, png = saved(args.out, "cluster", args.quick)
        chart(record, png)
        return
    wp.config.log_level = wp.LOG_WARNING
    try:
        import distributed  # noqa: F401
    except ImportError:
        ap.error("Dask is not installed: pip install 'warp_iisph[cluster]'")
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        mitsuba = None
    duration, resolution, spp = (0.2, "160x90", 4) if args.quick else (4.0, "640x360", 16)
    repeats = 1 if args.quick else max(1, args.repeats)
    with tempfile.TemporaryDirectory(prefix="cluster_bench_") as tmp:
        work = Path(tmp)
        # kernels compiled (and cached) before anything is timed
        command("run", *SCENE, "--duration", "0.1", "--mesh", "--out", str(work / "warm"), "--no-progress")
        idle = housekeeping(args.workers, 1.0 if args.quick else 10.0)
        print(
            f"an idle LocalCluster of {args.workers} takes {idle['cores_taken']:.3f} cores "
            f"({idle['cores_taken_dask_defaults']:.3f} at Dask's own intervals)"
        )
        sweep = sweep_timing(work, args.workers, duration, repeats)
        print(
            f"sweep of {sweep['variants']} variants ({sweep['particles']} particles, {duration:g} s each): "
            f"{sweep['serial_seconds']:.1f} s one after another, {sweep['workers_seconds']:.1f} s on "
            f"{args.workers} workers: {sweep['ratio']:.2f} x (target <= {TARGET}); "
            f"same results: {sweep['same_results']}; split over {args.workers} plain processes at once "
            f"(no engine): {sweep['floor']:.2f} x"
        )
        render = None
        if mitsuba is None:
            print("render: Mitsuba (the render extra) is not installed, skipped")
        else:
            render = render_timing(work, args.workers, resolution, spp, repeats)
            print(
                f"render of {render['frames']} frames ({resolution}, {spp} spp, {render['variant']}): "
                f"{render['serial_seconds']:.1f} s one after another, {render['workers_seconds']:.1f} s on "
                f"{args.workers} workers: {render['ratio']:.2f} x (target <= {TARGET}); "
                f"same frames: {render['same_results']}; the serial render keeps "
                f"{render['serial_cores_busy']:.2f} cores busy: best on these cores {render['floor']:.2f} x"
            )
    init_warp()  # without the no-driver warning of a machine with no GPU
    record = header("cluster", workers=args.workers, cores_available=len(os.sched_getaffinity(0)), target=TARGET)
    record.update(housekeeping=idle, sweep=sweep, render=render)
    chart(record, save(record, args.out, "cluster", args.quick))


if __name__ == "__main__":
    main()
