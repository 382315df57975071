"""What each command does: its arguments turned into a call of the package, and its one line of
report."""

from __future__ import annotations

import sys

from . import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_TERMINATED, use_graph


def _frames(n: int) -> str:
    """``n`` frames, in words ("1 frame", "4 frames")."""
    return f"{n} frame{'' if n == 1 else 's'}"


def _preview(args) -> int:
    from ..view.preview import preview_run

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
        f"preview of {_frames(r['frames'])} ({r['source']}, "
        f"{1e3 * r['seconds_per_frame']:.0f} ms per frame) -> {r['path']}"
    )
    return 0


def _plot(args) -> int:
    from ..view.plots import plot_probes

    print(f"probes of {args.run_dir} -> {plot_probes(args.run_dir, args.out)}")
    return 0


def _render(args) -> int:
    from ..run.cluster import ClusterUnavailable
    from ..view.render import RenderUnavailable, render_run

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
        f"rendered {_frames(r['rendered'])} ({r['skipped']} already there) with Mitsuba {r['why']}, "
        f"{r['seconds_per_frame']:.1f} s per frame -> {r['video']} ({_frames(r['video_frames'])})"
    )
    return 0


def _usd(args) -> int:
    from ..view.usd import UsdUnavailable, export_usd

    try:
        r = export_usd(
            args.run_dir, args.out, args.frames, args.particles, args.material, progress=not args.no_progress
        )
    except UsdUnavailable as e:
        raise ValueError(f"usd: {e}") from None
    print(f"wrote frames {r['first']}..{r['last']} at {r['fps']:g} frames/s ({', '.join(r['prims'])}) -> {r['path']}")
    return 0


def _blender_script(args) -> int:
    from ..view.blender import blender_script

    path = blender_script(args.run_dir, args.out, args.material, args.frames, usd=args.usd)
    print(f"wrote {path}; run: blender -b -P {path} -- --render")
    return 0


def _scenes(args) -> int:
    from ..scene import bundled_scenes
    from ..scene.library import describe

    for name, path in bundled_scenes().items():
        print(f"{name:16s} {describe(path)}")
    return 0


def _start_warp(threads) -> None:
    """Warp, started quietly; ``--threads`` applied."""
    import warp as wp

    from ..engine.devices import init_warp

    wp.config.log_level = wp.LOG_WARNING
    init_warp()
    if threads is not None:
        from ..engine.launch import set_threads

        set_threads(threads, "--threads")


def _mesh(args) -> int:
    from ..engine.devices import checked_device
    from ..run.meshing import mesh_path

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
    kept = result["skipped"]
    # a run's meshes record their settings (refused when other); another tool's files' meshes do not
    unknown = ", kept as they are: --overwrite remakes them with these settings" if kept and not result["run"] else ""
    print(f"meshed {_frames(result['written'])} ({kept} already there{unknown}) -> {result['out']}; {secs}")
    return 0


def _run(args) -> int:
    from ..engine.devices import checked_device
    from ..scene import load_scene, resolve_scene

    overrides = list(args.overrides)
    if args.spacing is not None:
        overrides.append(f"spacing={args.spacing!r}")
    if args.method:
        overrides.append(f'physics.method="{args.method}"')
    if args.mesh:
        overrides.append("output.mesh=true")
    if args.format:
        overrides.append(f'output.format="{args.format}"')
    if args.out is not None and not args.out:
        raise ValueError("--out '': empty; give the run folder's path (default: runs/NAME)")
    if args.resume:
        if args.scene or args.out is not None or args.overwrite:
            raise ValueError(
                "--resume RUN_DIR: continues that run with its own scene and folder; "
                "give no SCENE, --out or --overwrite"
            )
        from ..run.runner import resumed_scene

        scene, out, source = resumed_scene(args.resume, overrides), args.resume, f"{args.resume}/run.json"
    elif not args.scene:
        raise ValueError("SCENE: required (a scene file or a bundled scene's name), or --resume RUN_DIR")
    else:
        scene = load_scene(args.scene, overrides)
        out, source = args.out or f"runs/{scene.name}", resolve_scene(args.scene)
    from ..scene import scene_to_dict
    from ..scene.bodies import bodies_at_walls, bodies_in_liquid, thin_bodies
    from ..setup.fill import lattice_shortfalls, nozzle_flows

    # said before a long run starts (once its scene is built: a refusal stays one line), not only
    # in the warnings it ends with
    table = scene_to_dict(scene)
    early = lattice_shortfalls(table) + nozzle_flows(table) + thin_bodies(scene.bodies, scene.spacing)
    if not args.resume:  # where the bodies start: said at the start only
        early += bodies_in_liquid(scene.bodies, scene.fluids)
        ph = scene.physics
        early += bodies_at_walls(scene.bodies, scene.fluids, scene.tank, scene.spacing, ph.rho0, ph.gravity)

    def say_early(sim) -> None:
        early.extend(sim.model.setup_warnings)
        for warning in early:
            print(f"warp-iisph: warning: {warning}", file=sys.stderr)

    _start_warp(args.threads)
    device = checked_device(args.device)
    from ..run.folder import RunError
    from ..run.runner import run_scene

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
            inputs=[] if args.resume else [source],
            on_built=say_early,
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
        f"{_frames(t['frames'])} of {wrote}, {t.get('particles', record['particles']['fluid'])} particles"
        + (
            f" ({t['emitted']} emitted, {t['removed']} removed by sinks"
            + (f", {t['blocked']} blocked: liquid at the nozzle" if t.get("blocked") else "")
            + ")"
            if "emitted" in t
            else ""
        )
        + f", mean {t['mean_iterations']:.1f} iterations, "
        f"mean compression {100 * t['mean_compression']:.3f} %"
        + (
            f", {t['wall_corrections'] + t['obstacle_corrections']} particles put back by the last line "
            f"({t['wall_corrections']} at the tank's walls, {t['obstacle_corrections']} at obstacles and bodies) "
            f"in {t['corrected_steps']} steps"
            if t.get("corrected_steps")
            else ""
        )
        + (
            f", the fixed dt cut into up to {t['most_substeps']} substeps in {t['substeps']} steps"
            if t.get("substeps")
            else ""
        )
        + (f" -> {out}" if t["frames"] else f"; nothing written ({out} as it was)")
    )
    from ..run.run_record import run_warnings

    for warning in run_warnings(record):
        if warning not in early:
            print(f"warp-iisph: warning: {warning}", file=sys.stderr)
    if record["ended"] == "completed":
        print(summary)
        return 0
    print(f"warp-iisph: {record['message']}; {summary}", file=sys.stderr)
    return {"interrupted": EXIT_INTERRUPTED, "terminated": EXIT_TERMINATED}.get(record["ended"], EXIT_FAILED)


def _sweep(args) -> int:
    from ..run import sweep as sw
    from ..run import sweep_chart as charts
    from ..run.cluster import ClusterUnavailable, check_options, open_workers

    try:
        check_options(args.scheduler, args.workers)
        charts.require_chart()
    except (ClusterUnavailable, RuntimeError) as e:
        raise ValueError(f"sweep: {e}") from None
    if args.threads is not None and not 1 <= args.threads <= 1024:
        raise ValueError(f"--threads {args.threads}: must be in [1, 1024]")
    if args.out is not None and not args.out:
        raise ValueError("--out '': empty; give the sweep folder's path (default: sweeps/NAME)")
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
                ("--out", args.out is not None),
            )
            if value
        ]
        if given:
            raise ValueError(f"--resume SWEEP_DIR: runs that sweep with its own settings; give no {', '.join(given)}")
        record, out = sw.load_sweep(args.resume), args.resume
        if args.measure:
            record["measure"] = sw.resumed_measure(record, args.measure)
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
            args.measure or charts.DEFAULT_MEASURE,
        )
    if args.scheduler is None and args.workers is None:
        _start_warp(args.threads)  # the variants run in this process
        if record["device"] == "cuda":
            from ..engine.devices import checked_device

            checked_device("cuda")
    with sw.claim(out, resume=bool(args.resume)) as record_now:  # one sweep writes a sweep folder at a time
        if record_now is not None:  # read again under the lock, with the measure checked above
            record = {**record_now, "measure": record["measure"]}
        with open_workers(args.scheduler, args.workers, args.threads, gpu=record["device"] == "cuda") as workers:
            record = sw.run_sweep(record, out, workers, progress=not args.no_progress)
    variants = record["variants"]
    ran = record["sessions"][-1]["variants_run"]
    counts = ", ".join(f"{n} {state}" for state, n in record["counts"].items())
    for e in variants:
        if e["ended"] not in sw.DONE:
            print(f"warp-iisph: warning: variant {e['name']} {e['ended']}: {e['message']}", file=sys.stderr)
        for warning in (e.get("summary") or {}).get("warnings", ()):
            print(f"warp-iisph: warning: variant {e['name']}: {warning}", file=sys.stderr)
    if record["chart"] is None:
        names = charts.measure_names(e["summary"] for e in variants if e["summary"])
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
