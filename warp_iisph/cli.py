"""Command line: ``warp-iisph run | sweep | scenes | mesh | preview | plot | render | usd | blender-script``.

Every error is one line on stderr: exit status 2 for bad input (a file, key or argument and its
allowed range), 1 for a failure at run time, 130 for Ctrl-C and 143 for SIGTERM; ``--debug``
shows the traceback instead.
"""

from __future__ import annotations

import argparse
import signal
import sys

from .scene.settings import METHODS

EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_TERMINATED = 2, 1, 130, 143


class OneLineParser(argparse.ArgumentParser):
    """argparse, with its usage errors in one line."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, f"warp-iisph: error: {message} (see {self.prog} --help)\n")


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="warp-iisph", description="IISPH liquids on NVIDIA Warp")
    p.add_argument("--debug", action="store_true", help="show the Python traceback of an error instead of one line")
    sub = p.add_subparsers(dest="command", required=True, parser_class=OneLineParser)
    run = sub.add_parser("run", help="simulate a scene file (or a bundled scene) into an output folder")
    run.add_argument(
        "scene", nargs="?", help="a scene file (.toml) or the name of a bundled scene (see `warp-iisph scenes`)"
    )
    run.add_argument(
        "--resume",
        metavar="RUN_DIR",
        default=None,
        help="continue a stopped, interrupted or diverged (then --set fixed) run from its last checkpoint, "
        "bitwise as it would have run; --duration may extend it",
    )
    run.add_argument(
        "--duration", type=float, default=None, help="simulated seconds (default: the scene's output.duration)"
    )
    run.add_argument(
        "--fps", type=float, default=None, help="frames per simulated second (default: the scene's output.fps)"
    )
    run.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    run.add_argument("--out", default=None, help="output folder (default runs/SCENE_NAME)")
    run.add_argument(
        "--spacing", type=float, default=None, help="particle spacing h in metres (same as --set spacing=H)"
    )
    run.add_argument("--method", choices=METHODS, default=None, help="pressure solver (same as --set physics.method=M)")
    run.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scene-file key, e.g. --set spacing=0.01 --set physics.eta=0.0005 --set fluids.0.radius=0.1",
    )
    run.add_argument(
        "--mesh",
        action="store_true",
        help="also write the surface mesh/frame_NNNNN.obj (same as --set output.mesh=true)",
    )
    run.add_argument(
        "--format",
        choices=("ply", "vtu"),
        default=None,
        help="particle files: binary PLY (default; splashsurf reads it) "
        "or VTU for ParaView (same as --set output.format=F)",
    )
    run.add_argument(
        "--threads", default=None, help="CPU threads for per-particle kernels (default: all available cores)"
    )
    run.add_argument(
        "--graph",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="record the loop over steps as a graph and replay it (no per-step Python launches); "
        "default: on with a CUDA device, off on the CPU (a replay there runs on one thread)",
    )
    run.add_argument("--overwrite", action="store_true", help="replace the contents of an existing output folder")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    sweep = sub.add_parser(
        "sweep",
        help="run a scene at every combination of --vary values (each a run folder) into sweep.json and a chart",
    )
    sweep.add_argument("scene", nargs="?", help="a scene file (.toml) or the name of a bundled scene")
    sweep.add_argument(
        "--vary",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help="a scene key and its values (as --set takes them; commas inside [] or quotes are kept), "
        "e.g. --vary spacing=0.02,0.01 --vary physics.eta=0.01,0.001: every combination is a variant",
    )
    sweep.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a scene-file key for every variant (as in `warp-iisph run`)",
    )
    sweep.add_argument("--repeat", type=int, default=1, help="run each variant N times (to time them; default 1)")
    sweep.add_argument(
        "--duration", type=float, default=None, help="simulated seconds (default: the scene's output.duration)"
    )
    sweep.add_argument(
        "--fps", type=float, default=None, help="frames per simulated second (default: the scene's output.fps)"
    )
    sweep.add_argument(
        "--device",
        choices=("cpu", "cuda"),
        default="cpu",
        help="cpu (default) or cuda: each variant on a GPU, one at a time per GPU (Dask resource GPU)",
    )
    sweep.add_argument(
        "--graph",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="as in `warp-iisph run` (default: on with cuda, off on the CPU)",
    )
    sweep.add_argument("--out", default=None, help="the sweep's folder (default sweeps/SCENE_NAME)")
    sweep.add_argument(
        "--resume",
        metavar="SWEEP_DIR",
        default=None,
        help="run the variants of that sweep not yet complete (with its own settings)",
    )
    sweep.add_argument(
        "--measure",
        default=None,
        help="what the chart shows: a value of the variants' run.json, e.g. mean_compression or "
        "totals.mean_iterations (default totals.wall_seconds_per_simulated_second)",
    )
    _cluster_options(sweep, "variants", "one after another in this process")
    sweep.add_argument(
        "--threads",
        type=int,
        default=None,
        help="CPU threads per variant (default: all cores in this process, the cores over the workers of "
        "--workers, each worker's Dask threads with --scheduler)",
    )
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar")
    sub.add_parser("scenes", help="list bundled scenes")
    mesh = sub.add_parser("mesh", help="mesh a run's particle frames (or any particle files) into OBJ surfaces")
    mesh.add_argument(
        "run_dir",
        metavar="PATH",
        help="an output folder of `warp-iisph run` (meshes go to PATH/mesh/), or a particle file or a folder of "
        "them in any format meshio reads (PLY, VTK, VTU; needs --spacing)",
    )
    mesh.add_argument("--spacing", type=float, default=None, help="particle spacing h in metres (default: the run's)")
    mesh.add_argument(
        "--out",
        default=None,
        help="output folder for particle files that are not a run (default: beside them, in mesh/ for a folder)",
    )
    mesh.add_argument("--cell", type=float, default=None, help="grid cell, in particle spacings (default 0.5)")
    mesh.add_argument(
        "--r0", type=float, default=None, help="particle radius of the distance field, in spacings (default 0.5)"
    )
    mesh.add_argument("--radius", type=float, default=None, help="kernel radius R, in spacings (default 2)")
    mesh.add_argument("--smoothing", choices=("laplacian", "taubin", "none"), default=None, help="default laplacian")
    mesh.add_argument("--passes", type=int, default=None, help="smoothing passes (default 3)")
    mesh.add_argument("--format", choices=("obj", "ply"), default=None, help="mesh files: obj (default) or binary ply")
    mesh.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    mesh.add_argument("--threads", default=None, help="CPU threads (default: all available cores)")
    mesh.add_argument(
        "--overwrite", action="store_true", help="re-mesh frames that already have a mesh, also with other settings"
    )
    mesh.add_argument("--no-progress", action="store_true", help="no progress bar")
    render = sub.add_parser(
        "render", help="path-trace a run's meshes into frames/ and video.mp4 (needs the render extra)"
    )
    render.add_argument("run_dir", help="an output folder of `warp-iisph run --mesh` (or of `warp-iisph mesh`)")
    render.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16; denoised)")
    render.add_argument("--resolution", default="640x360", help="WIDTHxHEIGHT (default 640x360)")
    render.add_argument(
        "--material", default="water", help="water, wine, whisky, or r,g,b: the colour of 5 cm of the liquid"
    )
    render.add_argument(
        "--frames", default=None, metavar="A:B", help="frame numbers a (included) to b (excluded), e.g. 0:30"
    )
    render.add_argument("--walls", action="store_true", help="show the box tank's far walls")
    render.add_argument("--no-denoise", action="store_true", help="skip OpenImageDenoise")
    render.add_argument(
        "--variant",
        default=None,
        help="force a Mitsuba variant (default: cuda_ad_rgb, llvm_ad_rgb or scalar_rgb, the fastest that works)",
    )
    render.add_argument("--gif", action="store_true", help="write video.gif instead of video.mp4")
    render.add_argument("--overwrite", action="store_true", help="re-render frames already rendered")
    _cluster_options(render, "frames", "one after another")
    render.add_argument("--no-progress", action="store_true", help="no progress bar")
    preview = sub.add_parser(
        "preview", help="a fast look at a run (particles coloured by speed, or the mesh) in preview.mp4"
    )
    preview.add_argument("run_dir", help="an output folder of `warp-iisph run`")
    preview.add_argument(
        "--source", choices=("particles", "mesh"), default=None, help="default: particles when the run has them"
    )
    preview.add_argument("--resolution", default="640x360", help="WIDTHxHEIGHT (default 640x360)")
    preview.add_argument("--frames", default=None, metavar="A:B", help="frame numbers a (included) to b (excluded)")
    preview.add_argument("--fps", type=float, default=None, help="video frame rate (default: the run's fps)")
    preview.add_argument("--yaw", type=float, default=30.0, help="camera turn about the vertical, degrees (default 30)")
    preview.add_argument("--pitch", type=float, default=25.0, help="camera elevation, degrees (default 25)")
    preview.add_argument("--gif", action="store_true", help="write preview.gif instead of preview.mp4")
    preview.add_argument(
        "--out", default=None, help="video path (default RUN_DIR/preview.mp4), or a .png for one frame's still"
    )
    preview.add_argument("--no-progress", action="store_true", help="no progress bar")
    plot = sub.add_parser("plot", help="chart every probe of a run over time (probes.csv) in a PNG")
    plot.add_argument("run_dir", help="an output folder of `warp-iisph run` of a scene with [[probes]]")
    plot.add_argument("--out", default=None, help="the PNG's path (default RUN_DIR/probes.png)")
    usd = sub.add_parser(
        "usd", help="write the run as one USD stage for Blender, Houdini, Omniverse (needs the usd extra)"
    )
    usd.add_argument("run_dir", help="an output folder with mesh/frame_NNNNN.obj (or .ply)")
    usd.add_argument(
        "--out", default=None, help="the stage's file: .usdc (binary), .usda (text) or .usd (default RUN_DIR/run.usdc)"
    )
    usd.add_argument("--frames", default=None, metavar="A:B", help="frame numbers a (included) to b (excluded)")
    usd.add_argument(
        "--particles", action="store_true", help="also the particles, as points with velocities, ids, density, pressure"
    )
    usd.add_argument("--material", default="water", help="the liquid's preview colour: water, wine, whisky, or r,g,b")
    usd.add_argument("--no-progress", action="store_true", help="no progress bar")
    blend = sub.add_parser("blender-script", help="write a script that loads a run into Blender as one liquid object")
    blend.add_argument("run_dir", help="an output folder with mesh/frame_NNNNN.obj (or .ply)")
    blend.add_argument("--material", default="water", help="water, wine, whisky, or r,g,b")
    blend.add_argument("--frames", default=None, metavar="A:B", help="frame numbers a (included) to b (excluded)")
    blend.add_argument(
        "--usd",
        action="store_true",
        help="import the run's USD stage (`warp-iisph usd RUN_DIR`) instead of its OBJ files",
    )
    blend.add_argument("--out", default=None, help="script path (default RUN_DIR/blender_scene.py)")
    return p


def _cluster_options(parser, what: str, default: str) -> None:
    """``--scheduler ADDRESS | --workers N``: where the tasks run (Dask, the cluster extra)."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help=f"run the {what} on the Dask cluster whose scheduler is at ADDRESS (e.g. tcp://10.0.0.5:8786; "
        "its workers must see this folder) (needs the cluster extra)",
    )
    where.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help=f"run the {what} on N local worker processes (a Dask LocalCluster; needs the cluster extra); "
        f"default: {default}",
    )


def _preview(args) -> int:
    from .view.preview import preview_run

    r = preview_run(
        args.run_dir,
        args.out,
        args.source,
        args.resolution,
        args.frames,
        args.fps,
        args.gif,
        args.yaw,
        args.pitch,
        progress=not args.no_progress,
    )
    print(
        f"preview of {r['frames']} frames ({r['source']}, "
        f"{1e3 * r['seconds_per_frame']:.0f} ms per frame) -> {r['path']}"
    )
    return 0


def _plot(args) -> int:
    from .view.plots import plot_probes

    print(f"probes of {args.run_dir} -> {plot_probes(args.run_dir, args.out)}")
    return 0


def _render(args) -> int:
    from .run.cluster import ClusterUnavailable
    from .view.render import RenderUnavailable, render_run

    try:
        r = render_run(
            args.run_dir,
            args.spp,
            args.resolution,
            args.material,
            args.frames,
            args.walls,
            not args.no_denoise,
            args.gif,
            args.overwrite,
            args.variant,
            progress=not args.no_progress,
            scheduler=args.scheduler,
            workers=args.workers,
        )
    except (RenderUnavailable, ClusterUnavailable) as e:
        raise ValueError(f"render: {e}") from None
    print(
        f"rendered {r['rendered']} frames ({r['skipped']} already there) with Mitsuba {r['why']}, "
        f"{r['seconds_per_frame']:.1f} s per frame -> {r['video']}"
    )
    return 0


def _usd(args) -> int:
    from .view.usd import UsdUnavailable, export_usd

    try:
        r = export_usd(
            args.run_dir, args.out, args.frames, args.particles, args.material, progress=not args.no_progress
        )
    except UsdUnavailable as e:
        raise ValueError(f"usd: {e}") from None
    print(f"wrote frames {r['first']}..{r['last']} at {r['fps']:g} frames/s ({', '.join(r['prims'])}) -> {r['path']}")
    return 0


def _blender_script(args) -> int:
    from .view.blender import blender_script

    path = blender_script(args.run_dir, args.out, args.material, args.frames, usd=args.usd)
    print(f"wrote {path}; run: blender -b -P {path} -- --render")
    return 0


def _scenes(args) -> int:
    from .scene import bundled_scenes
    from .scene.library import describe

    for name, path in bundled_scenes().items():
        print(f"{name:16s} {describe(path)}")
    return 0


def _start_warp(threads) -> None:
    """Warp, started quietly; ``--threads`` applied."""
    import warp as wp

    from .engine.devices import init_warp

    wp.config.log_level = wp.LOG_WARNING
    init_warp()
    if threads is not None:
        from .engine.launch import set_threads

        set_threads(threads, "--threads")


def _mesh(args) -> int:
    from .engine.devices import checked_device
    from .run.meshing import mesh_path

    _start_warp(args.threads)
    overrides = {
        k: getattr(args, k)
        for k in ("cell", "r0", "radius", "smoothing", "passes", "format")
        if getattr(args, k) is not None
    }
    result = mesh_path(
        args.run_dir,
        overrides,
        checked_device(args.device),
        overwrite=args.overwrite,
        progress=not args.no_progress,
        spacing=args.spacing,
        out=args.out,
    )
    secs = ", ".join(f"{k} {v:.2f} s" for k, v in result["stage_seconds"].items())
    print(f"meshed {result['written']} frames ({result['skipped']} already there) -> {result['out']}; {secs}")
    return 0


def _run(args) -> int:
    from .engine.devices import checked_device
    from .scene import load_scene, resolve_scene

    overrides = list(args.overrides)
    if args.spacing is not None:
        overrides.append(f"spacing={args.spacing!r}")
    if args.method:
        overrides.append(f'physics.method="{args.method}"')
    if args.mesh:
        overrides.append("output.mesh=true")
    if args.format:
        overrides.append(f'output.format="{args.format}"')
    if args.resume:
        if args.scene or args.out or args.overwrite:
            raise ValueError(
                "--resume RUN_DIR: continues that run with its own scene and folder; "
                "give no SCENE, --out or --overwrite"
            )
        from .run.runner import resumed_scene

        scene, out, source = resumed_scene(args.resume, overrides), args.resume, f"{args.resume}/run.json"
    elif not args.scene:
        raise ValueError("SCENE: required (a scene file or a bundled scene's name), or --resume RUN_DIR")
    else:
        scene = load_scene(args.scene, overrides)
        out, source = args.out or f"runs/{scene.name}", resolve_scene(args.scene)
    _start_warp(args.threads)
    device = checked_device(args.device)
    from .run.folder import RunError
    from .run.runner import run_scene

    try:
        record = run_scene(
            scene,
            out,
            args.duration,
            args.fps,
            device,
            overwrite=args.overwrite,
            progress=not args.no_progress,
            graph=use_graph(args.graph, device),
            resume=bool(args.resume),
        )
    except ValueError as e:
        if str(e).startswith("--") or isinstance(e, RunError):  # an argument, or a run folder's file: named already
            raise
        raise ValueError(f"{source}: {e}") from None  # found while building the scene's particles
    t = record["totals"]
    o = record["output"]
    wrote = (
        " and ".join(k for k in ("particles", "mesh") if o[k])
        or "no frame files (output.particles and output.mesh are false)"
    )
    cut = ""
    if record["requested_duration"] != record["duration"]:
        cut = f" (the {record['requested_duration']:g} s asked for, cut to whole frames)"
    summary = (
        f"{record['ended']}: {t['steps']} steps, {t['simulated_time']:.3f} s simulated{cut} "
        f"in {t['wall_seconds']:.1f} s wall, "
        f"{t['frames']} frames of {wrote}, {t.get('particles', record['particles']['fluid'])} particles"
        + (
            f" ({t['emitted']} emitted, {t['removed']} removed by sinks"
            + (f", {t['blocked']} not emitted: liquid at the nozzle" if t.get("blocked") else "")
            + ")"
            if "emitted" in t
            else ""
        )
        + f", mean {t['mean_iterations']:.1f} iterations, "
        f"mean compression {100 * t['mean_compression']:.3f} %"
        + (
            f", {t['wall_corrections'] + t['obstacle_corrections']} particles put back "
            f"within the walls in {t['corrected_steps']} steps"
            if t.get("corrected_steps")
            else ""
        )
        + (
            f", the fixed dt cut into up to {t['most_substeps']} substeps in {t['substeps']} steps"
            if t.get("substeps")
            else ""
        )
        + f" -> {out}"
    )
    if t.get("not_emitted"):
        print(
            f"warp-iisph: warning: the emitters could not add {t['not_emitted']} particles: "
            f"the liquid reached its capacity of "
            f"{record['particles']['capacity']} (raise max_particles)",
            file=sys.stderr,
        )
    if t["unconverged_steps"]:
        ph = scene.physics
        print(
            f"warp-iisph: warning: {t['unconverged_steps']} of {t['steps']} steps stopped at "
            f"max_iterations = {ph.max_iterations} "
            f"above eta = {100 * ph.eta:g} % (worst {100 * t['worst_unconverged_error']:.3f} %)",
            file=sys.stderr,
        )
    if record["ended"] == "completed":
        print(summary)
        return 0
    print(f"warp-iisph: {record['message']}; {summary}", file=sys.stderr)
    return {"interrupted": EXIT_INTERRUPTED, "terminated": EXIT_TERMINATED}.get(record["ended"], EXIT_FAILED)


def _sweep(args) -> int:
    from .run import sweep as sw
    from .run.cluster import ClusterUnavailable, check_options, open_workers

    try:
        check_options(args.scheduler, args.workers)
        sw.require_chart()
    except (ClusterUnavailable, RuntimeError) as e:
        raise ValueError(f"sweep: {e}") from None
    if args.threads is not None and not 1 <= args.threads <= 1024:
        raise ValueError(f"--threads {args.threads}: must be in [1, 1024]")
    if args.resume:
        given = [
            name
            for name, value in (
                ("SCENE", args.scene),
                ("--vary", args.vary),
                ("--set", args.overrides),
                ("--repeat", args.repeat != 1),
                ("--duration", args.duration is not None),
                ("--fps", args.fps is not None),
                ("--device", args.device != "cpu"),
                ("--graph", args.graph is not None),
                ("--out", args.out),
            )
            if value
        ]
        if given:
            raise ValueError(f"--resume SWEEP_DIR: runs that sweep with its own settings; give no {', '.join(given)}")
        record, out = sw.load_sweep(args.resume), args.resume
        if args.measure:
            record["measure"] = sw.check_measure(args.measure)
    elif not args.scene:
        raise ValueError("SCENE: required (a scene file or a bundled scene's name), or --resume SWEEP_DIR")
    else:
        record, out = sw.plan_sweep(
            args.scene,
            args.vary,
            args.overrides,
            args.repeat,
            args.duration,
            args.fps,
            args.device,
            use_graph(args.graph, args.device),
            args.out,
            args.measure or sw.DEFAULT_MEASURE,
        )
    if args.scheduler is None and args.workers is None:
        _start_warp(args.threads)  # the variants run in this process
        if record["device"] == "cuda":
            from .engine.devices import checked_device

            checked_device("cuda")
    with open_workers(args.scheduler, args.workers, args.threads, gpu=record["device"] == "cuda") as workers:
        record = sw.run_sweep(record, out, workers, progress=not args.no_progress)
    variants = record["variants"]
    ran = record["sessions"][-1]["variants_run"]
    counts = ", ".join(f"{n} {state}" for state, n in record["counts"].items())
    for e in variants:
        if e["ended"] not in sw.DONE:
            print(f"warp-iisph: warning: variant {e['name']} {e['ended']}: {e['message']}", file=sys.stderr)
    if record["chart"] is None:
        names = next((sw.numbers_in(e["summary"]) for e in variants if e["summary"]), [])
        names.sort(key=lambda n: not n.startswith("totals."))  # the totals first: what a study measures
        print(
            f"warp-iisph: warning: --measure {record['measure']}: no variant has it, no chart"
            + (f" (the variants have {', '.join(names)})" if names else ""),
            file=sys.stderr,
        )
    n = len(variants)
    print(
        f"swept {n} variant{'s' if n != 1 else ''} ({ran} run now, {n - ran} complete before): {counts} "
        f"in {record['sessions'][-1]['wall_seconds']:.1f} s wall -> {out}"
        + (f" (chart {record['chart']}: {record['measure']})" if record["chart"] else "")
    )
    return 0 if all(e["ended"] in sw.DONE for e in variants) else EXIT_FAILED


COMMANDS = {
    "run": _run,
    "sweep": _sweep,
    "scenes": _scenes,
    "mesh": _mesh,
    "preview": _preview,
    "plot": _plot,
    "render": _render,
    "usd": _usd,
    "blender-script": _blender_script,
}


def _on_sigterm(signum, frame):
    from .run.runner import Terminated

    raise Terminated()


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]  # anywhere on the line, before or after the command
    try:
        if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
            signal.signal(signal.SIGTERM, _on_sigterm)
        args = _parser().parse_args(argv)
        return COMMANDS[args.command](args)
    except KeyboardInterrupt as e:
        terminated = type(e).__name__ == "Terminated"
        print(f"warp-iisph: {'terminated' if terminated else 'interrupted'}", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    except Exception as e:
        if debug:
            raise
        code, text = _one_line(e)
        print(f"warp-iisph: error: {text}", file=sys.stderr)
        return code


def use_graph(asked: bool | None, device: str) -> bool:
    """``--graph`` / ``--no-graph`` as given, else graphs on CUDA (they remove the per-step launch
    cost: 1.75 against 3.8 ms per step at 97k particles on an H200) and not on the CPU (where
    a replay runs on one thread and split launches are faster)."""
    return bool(asked) if asked is not None else device.startswith("cuda")


def _one_line(e: Exception) -> tuple[int, str]:
    """Exit status and message of an error: bad input (ValueError: a file, key or argument out of
    range) is 2, anything else 1."""
    text = " ".join(str(e).split()) or type(e).__name__
    if isinstance(e, ValueError):
        return EXIT_BAD_INPUT, text
    if isinstance(e, MemoryError):
        return EXIT_FAILED, text if str(e) else "out of memory"
    if isinstance(e, OSError):
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        return EXIT_FAILED, f"{where}{e.strerror or text}"
    return EXIT_FAILED, f"{type(e).__name__}: {text} (an internal error: run with --debug for the traceback)"


if __name__ == "__main__":
    sys.exit(main())
