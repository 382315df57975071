"""Command line: ``warp-iisph run SCENE``, ``warp-iisph scenes``."""

from __future__ import annotations

import argparse
import sys

from . import scenes


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="warp-iisph", description="IISPH liquids on NVIDIA Warp")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="simulate a bundled scene into an output folder")
    run.add_argument("scene", help="bundled scene name (see `warp-iisph scenes`)")
    run.add_argument("--duration", type=float, default=2.0, help="simulated seconds (default 2)")
    run.add_argument("--fps", type=float, default=30.0, help="particle frames per simulated second (default 30)")
    run.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    run.add_argument("--out", default=None, help="output folder (default runs/SCENE)")
    run.add_argument("--spacing", type=float, default=None, help="particle spacing h in metres (scene default if omitted)")
    run.add_argument("--method", choices=("iisph", "wcsph"), default=None, help="pressure solver (default iisph)")
    run.add_argument("--overwrite", action="store_true", help="replace the contents of an existing output folder")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    sub.add_parser("scenes", help="list bundled scenes")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    if args.command == "scenes":
        for name, factory in scenes.BUNDLED.items():
            print(f"{name:18s} {(factory.__doc__ or '').strip().splitlines()[0]}")
        return 0
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    from .runner import run_scene

    try:
        if args.scene not in scenes.BUNDLED:
            raise ValueError(f"scene {args.scene!r}: unknown; bundled scenes are {', '.join(scenes.BUNDLED)}")
        kwargs = {} if args.spacing is None else {"spacing": args.spacing}
        if args.method:
            kwargs["method"] = args.method
        scene = scenes.BUNDLED[args.scene](**kwargs)
        device = "cuda:0" if args.device == "cuda" else args.device
        if device.startswith("cuda") and not wp.is_cuda_available():
            raise ValueError(f"--device {args.device}: no CUDA device is available on this machine; use --device cpu")
        out = args.out or f"runs/{args.scene}"
        record = run_scene(scene, out, args.duration, args.fps, device, overwrite=args.overwrite, progress=not args.no_progress)
    except ValueError as e:
        print(f"warp-iisph: error: {e}", file=sys.stderr)
        return 2
    t = record["totals"]
    summary = (
        f"{record['ended']}: {t['steps']} steps, {t['simulated_time']:.3f} s simulated in {t['wall_seconds']:.1f} s wall, "
        f"{t['frames']} frames, {record['particles']['fluid']} particles, mean {t['mean_iterations']:.1f} iterations -> {out}"
    )
    if record["ended"] == "completed":
        print(summary)
        return 0
    print(f"warp-iisph: {record['message']}; {summary}", file=sys.stderr)
    return 130 if record["ended"] == "interrupted" else 1


if __name__ == "__main__":
    sys.exit(main())
