"""What the benchmark scripts share: the run record's header (machine, device, versions, date),
writing JSON next to its chart, a headless matplotlib, compiling kernels outside the timing, and
running many measurements through the sweep machinery (in this process, or on a Dask cluster)."""

from __future__ import annotations

import datetime
import json
import os
import platform
import sys
from pathlib import Path

import warp as wp

from warp_iisph.engine.devices import device_name
from warp_iisph.run.run_record import versions

RESULTS = Path(__file__).resolve().parent / "results"


def header(name: str, device: str = "cpu", **extra) -> dict:
    """The fields every result file starts with."""
    wp.init()
    dev = wp.get_device(device_name(device))
    return {
        "benchmark": name,
        "device": str(dev),
        "device_name": dev.name,
        "machine": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "date": datetime.date.today().isoformat(),
        "versions": versions(),
        **extra,
    }


def save(record: dict, out, stem: str, quick: bool) -> Path:
    """Write ``<stem>.json`` (``<stem>_quick.json`` for --quick, git-ignored) and return the
    chart's path beside it."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stem = f"{stem}_quick" if quick else stem
    (out / f"{stem}.json").write_text(json.dumps(record, indent=2) + "\n")
    return out / f"{stem}.png"


def keep_parts(record: dict, out, stem: str, parts: dict, run: set, quick: bool) -> None:
    """Fill ``record`` (this run's header) with the parts of ``stem``'s saved file not run this time,
    and set ``part_dates``, the day each part was last measured (this run's date for those it
    measures). ``parts`` maps a part to the record's keys that hold it. Quick runs keep nothing."""
    path = Path(out) / f"{stem}.json"
    old = json.loads(path.read_text()) if path.is_file() and not quick else {}
    measured = old.get("part_dates", {})
    dates = {}
    for part, keys in parts.items():
        if part in run:
            dates[part] = record["date"]
        elif all(k in old for k in keys):
            record.update({k: old[k] for k in keys})
            # (older files: a key per part, or only the file's date)
            dates[part] = measured.get(part, old.get(f"{part}_date", old["date"]))
    record["part_dates"] = dates


def saved(out, stem: str, quick: bool = False) -> tuple[dict, Path]:
    """The record :func:`save` wrote for ``stem`` in ``out`` and its chart's path (for --replot)."""
    out = Path(out)
    stem = f"{stem}_quick" if quick else stem
    return json.loads((out / f"{stem}.json").read_text()), out / f"{stem}.png"


def present_devices(spec: str) -> tuple[list[str], list[str]]:
    """The devices of a comma-separated ``cpu,cuda`` list that this machine has, and those it
    lacks (each reported as skipped)."""
    wp.init()
    devices, missing = [], []
    for d in spec.split(","):
        (devices if d == "cpu" or (d == "cuda" and wp.is_cuda_available()) else missing).append(d)
    for d in missing:
        print(f"device {d}: not present on this machine, skipped")
    return devices, missing


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def warm_up(device: str = "cpu", method: str = "iisph") -> None:
    """Compile and load the solver's kernels so that the first timed run does not pay for it."""
    from warp_iisph import Simulation, scenes

    wp.config.log_level = wp.LOG_WARNING
    Simulation(scenes.hydrostatic_tank(spacing=0.05, method=method), device).step()


def martin_moyce_front(resolution: int, a: float = 0.1, t_end: float = 3.2, samples: int = 33, **physics):
    """The Martin & Moyce dam break (column a wide, 2a high, in a slab 4 particles deep) at
    ``a/h = resolution``: the front Z = x/a at ``samples`` evenly spaced T = t sqrt(2g/a) up to
    ``t_end``. Returns (T, Z, simulation, wall seconds spent stepping). Raises DivergenceError."""
    import time

    import numpy as np

    from warp_iisph import Simulation, scenes
    from warp_iisph.analysis.dam_break import surge_front

    h = a / resolution
    sim = Simulation(scenes.martin_moyce(spacing=h, a=a, depth=4 * h, length=5 * a, height=2.5 * a, **physics), "cpu")
    T = np.linspace(0.0, t_end, samples)
    Z, wall = [], 0.0
    for t in T:
        if t > 0:
            t0 = time.perf_counter()
            sim.advance(t / np.sqrt(2 * 9.81 / a) - sim.time)
            wall += time.perf_counter() - t0
        Z.append(surge_front(sim.positions, h) / a)
    return T, np.asarray(Z), sim, wall


TIMING_NOTE = (
    "timings are taken inside each measurement, and measurements running side by side share the cores, "
    "caches and memory bandwidth: parallel workers distort them (keep the default, one after another, for timings)"
)


def cluster_options(ap) -> None:
    """``--workers N | --scheduler ADDRESS``: where the measurements run (Dask, the cluster extra)."""
    where = ap.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="run the measurements on a Dask LocalCluster of N worker processes (cores/N CPU threads each); "
        f"default: one after another in this process; {TIMING_NOTE}",
    )
    where.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help=f"run the measurements on the Dask cluster whose scheduler is at ADDRESS; {TIMING_NOTE}",
    )


def check_cluster_options(ap, args) -> None:
    """``ap.error`` (one line, exit status 2) for a bad ``--workers``/``--scheduler``, or for
    either without Dask; call it right after parsing, before any measurement."""
    from warp_iisph.run.cluster import ClusterUnavailable, check_options

    try:
        check_options(args.scheduler, args.workers)
    except (ClusterUnavailable, ValueError) as e:
        ap.error(str(e))


def measure_all(args, calls: list, report) -> None:
    """Run ``calls`` (functions of no argument, e.g. ``functools.partial(measure, config)``) as
    one sweep's variants, where ``args.workers`` / ``args.scheduler`` say (by default one after
    another in this process), and ``report(result)`` each in the order given, as soon as it and
    those before it have ended. A measurement's error stops the benchmark."""
    from warp_iisph.run.cluster import open_workers

    if args.scheduler is not None:  # the workers of another machine need no copy of benchmarks/
        import cloudpickle

        here = Path(__file__).resolve().parent
        for module in list(sys.modules.values()):
            path = getattr(module, "__file__", None)
            if path and Path(path).resolve().parent == here and module.__name__ != "__main__":
                cloudpickle.register_pickle_by_value(module)
    done, reported = {}, [0]

    def on_done(i, result, error):
        if error is not None:
            raise error
        done[i] = result
        while reported[0] in done:
            report(done.pop(reported[0]))
            reported[0] += 1

    with open_workers(args.scheduler, args.workers) as workers:
        workers.run([(call, ()) for call in calls], on_done, name="measurement")


def warm_once(device: str = "cpu", method: str = "iisph") -> None:
    """:func:`warm_up`, once per process (each worker of a cluster compiles and loads for itself)."""
    from warp_iisph.run.cluster import warm

    warm(("warm_up", device, method), lambda: warm_up(device, method) or True)
