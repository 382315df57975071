"""Command line: ``warp-iisph run | scenes | mesh | preview | render | blender-script``."""

from __future__ import annotations

import argparse
import sys


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="warp-iisph", description="IISPH liquids on NVIDIA Warp")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="simulate a scene file (or a bundled scene) into an output folder")
    run.add_argument("scene", help="a scene file (.toml) or the name of a bundled scene (see `warp-iisph scenes`)")
    run.add_argument("--duration", type=float, default=None, help="simulated seconds (default: the scene's output.duration)")
    run.add_argument("--fps", type=float, default=None, help="frames per simulated second (default: the scene's output.fps)")
    run.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    run.add_argument("--out", default=None, help="output folder (default runs/SCENE_NAME)")
    run.add_argument("--spacing", type=float, default=None, help="particle spacing h in metres (same as --set spacing=H)")
    run.add_argument("--method", choices=("iisph", "wcsph"), default=None, help="pressure solver (same as --set physics.method=M)")
    run.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
        help="override a scene-file key, e.g. --set spacing=0.01 --set physics.eta=0.0005 --set fluids.0.radius=0.1",
    )
    run.add_argument("--mesh", action="store_true", help="also write the surface mesh/frame_NNNNN.obj (same as --set output.mesh=true)")
    run.add_argument("--threads", default=None, help="CPU threads for per-particle kernels (default: all available cores)")
    run.add_argument("--graph", action="store_true", help="record one time step as a graph and replay it (no per-step Python launches)")
    run.add_argument("--overwrite", action="store_true", help="replace the contents of an existing output folder")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    sub.add_parser("scenes", help="list bundled scenes")
    mesh = sub.add_parser("mesh", help="mesh the particle frames of a run into mesh/frame_NNNNN.obj")
    mesh.add_argument("run_dir", help="an output folder of `warp-iisph run`")
    mesh.add_argument("--cell", type=float, default=None, help="grid cell, in particle spacings (default 0.5)")
    mesh.add_argument("--r0", type=float, default=None, help="particle radius of the distance field, in spacings (default 0.5)")
    mesh.add_argument("--radius", type=float, default=None, help="kernel radius R, in spacings (default 2)")
    mesh.add_argument("--smoothing", choices=("laplacian", "taubin", "none"), default=None, help="default laplacian")
    mesh.add_argument("--passes", type=int, default=None, help="smoothing passes (default 3)")
    mesh.add_argument("--format", choices=("obj", "ply"), default=None, help="mesh files: obj (default) or binary ply")
    mesh.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    mesh.add_argument("--threads", default=None, help="CPU threads (default: all available cores)")
    mesh.add_argument("--overwrite", action="store_true", help="re-mesh frames that already have a mesh")
    mesh.add_argument("--no-progress", action="store_true", help="no progress bar")
    render = sub.add_parser("render", help="path-trace a run's meshes into frames/ and video.mp4 (needs the render extra)")
    render.add_argument("run_dir", help="an output folder of `warp-iisph run --mesh` (or of `warp-iisph mesh`)")
    render.add_argument("--spp", type=int, default=16, help="samples per pixel (default 16; denoised)")
    render.add_argument("--resolution", default="640x360", help="WIDTHxHEIGHT (default 640x360)")
    render.add_argument("--material", default="water", help="water, wine, whisky, or r,g,b: the colour of 5 cm of the liquid")
    render.add_argument("--frames", default=None, metavar="A:B", help="frame numbers a (included) to b (excluded), e.g. 0:30")
    render.add_argument("--walls", action="store_true", help="show the box tank's far walls")
    render.add_argument("--no-denoise", action="store_true", help="skip OpenImageDenoise")
    render.add_argument("--variant", default=None, help="force a Mitsuba variant (default: cuda_ad_rgb, llvm_ad_rgb or scalar_rgb, the fastest that works)")
    render.add_argument("--gif", action="store_true", help="write video.gif instead of video.mp4")
    render.add_argument("--overwrite", action="store_true", help="re-render frames already rendered")
    render.add_argument("--no-progress", action="store_true", help="no progress bar")
    preview = sub.add_parser("preview", help="a fast look at a run (particles coloured by speed, or the mesh) in preview.mp4")
    preview.add_argument("run_dir", help="an output folder of `warp-iisph run`")
    preview.add_argument("--source", choices=("particles", "mesh"), default=None, help="default: particles when the run has them")
    preview.add_argument("--resolution", default="640x360", help="WIDTHxHEIGHT (default 640x360)")
    preview.add_argument("--frames", default=None, metavar="A:B", help="frame numbers a (included) to b (excluded)")
    preview.add_argument("--fps", type=float, default=None, help="video frame rate (default: the run's fps)")
    preview.add_argument("--yaw", type=float, default=30.0, help="camera turn about the vertical, degrees (default 30)")
    preview.add_argument("--pitch", type=float, default=25.0, help="camera elevation, degrees (default 25)")
    preview.add_argument("--gif", action="store_true", help="write preview.gif instead of preview.mp4")
    preview.add_argument("--out", default=None, help="video path (default RUN_DIR/preview.mp4)")
    preview.add_argument("--no-progress", action="store_true", help="no progress bar")
    blend = sub.add_parser("blender-script", help="write a script that loads a run's OBJ sequence into Blender")
    blend.add_argument("run_dir", help="an output folder with mesh/frame_NNNNN.obj")
    blend.add_argument("--material", default="water", help="water, wine, whisky, or r,g,b")
    blend.add_argument("--frames", default=None, metavar="A:B", help="frame numbers a (included) to b (excluded)")
    blend.add_argument("--out", default=None, help="script path (default RUN_DIR/blender_scene.py)")
    return p


def _view_command(args) -> int:
    """preview, render and blender-script: they read a run folder and write images or a script."""
    from .run.folder import RunError

    try:
        if args.command == "preview":
            from .view.preview import preview_run

            r = preview_run(args.run_dir, args.out, args.source, args.resolution, args.frames, args.fps, args.gif, args.yaw,
                            args.pitch, progress=not args.no_progress)
            print(f"preview of {r['frames']} frames ({r['source']}, {1e3 * r['seconds_per_frame']:.0f} ms per frame) -> {r['path']}")
        elif args.command == "render":
            from .view.render import RenderUnavailable, render_run

            try:
                r = render_run(args.run_dir, args.spp, args.resolution, args.material, args.frames, args.walls, not args.no_denoise,
                               args.gif, args.overwrite, args.variant, progress=not args.no_progress)
            except RenderUnavailable as e:
                print(f"warp-iisph: error: render: {e}", file=sys.stderr)
                return 2
            print(f"rendered {r['rendered']} frames ({r['skipped']} already there) with Mitsuba {r['why']}, "
                  f"{r['seconds_per_frame']:.1f} s per frame -> {r['video']}")
        else:
            from .view.blender import blender_script

            path = blender_script(args.run_dir, args.out, args.material, args.frames)
            print(f"wrote {path}; run: blender -b -P {path} -- --render")
    except RunError as e:
        print(f"warp-iisph: error: {e}", file=sys.stderr)
        return 2
    return 0


def _mesh_command(args) -> int:
    from pathlib import Path

    from .engine.devices import checked_device
    from .run.meshing import mesh_run

    try:
        overrides = {k: getattr(args, k) for k in ("cell", "r0", "radius", "smoothing", "passes", "format") if getattr(args, k) is not None}
        device = checked_device(args.device)
        result = mesh_run(args.run_dir, overrides, device, overwrite=args.overwrite, progress=not args.no_progress)
    except ValueError as e:
        print(f"warp-iisph: error: {e}", file=sys.stderr)
        return 2
    secs = ", ".join(f"{k} {v:.2f} s" for k, v in result["stage_seconds"].items())
    print(f"meshed {result['written']} frames ({result['skipped']} already there) -> {Path(args.run_dir) / 'mesh'}; {secs}")
    return 0


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from .scene import SceneFileError, bundled_scenes, load_scene, resolve_scene
    from .scene.library import describe

    if args.command in ("preview", "render", "blender-script"):
        return _view_command(args)
    if args.command == "scenes":
        for name, path in bundled_scenes().items():
            print(f"{name:16s} {describe(path)}")
        return 0
    import warp as wp

    wp.config.log_level = wp.LOG_WARNING
    from .engine.devices import checked_device
    from .run.runner import OutputExistsError, run_scene

    if args.threads is not None:
        from .engine.launch import set_threads

        try:
            set_threads(args.threads)
        except ValueError as e:
            print(f"warp-iisph: error: --{e}", file=sys.stderr)
            return 2
    if args.command == "mesh":
        return _mesh_command(args)
    source, out = args.scene, args.out
    try:
        overrides = list(args.overrides)
        if args.spacing is not None:
            overrides.append(f"spacing={args.spacing!r}")
        if args.method:
            overrides.append(f'physics.method="{args.method}"')
        if args.mesh:
            overrides.append("output.mesh=true")
        scene = load_scene(args.scene, overrides)
        source = str(resolve_scene(args.scene))
        duration = scene.output.duration if args.duration is None else args.duration
        fps = scene.output.fps if args.fps is None else args.fps
        try:
            device = checked_device(args.device)
        except ValueError as e:
            raise SceneFileError(str(e)) from None
        out = args.out or f"runs/{scene.name}"
        record = run_scene(scene, out, duration, fps, device, overwrite=args.overwrite, progress=not args.no_progress, graph=args.graph)
    except (SceneFileError, OutputExistsError) as e:
        print(f"warp-iisph: error: {e}", file=sys.stderr)
        return 2
    except ValueError as e:  # found while building the particles (memory, nothing fits)
        print(f"warp-iisph: error: {source}: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a frame could not be written (disk full, permissions); earlier frames are kept
        print(f"warp-iisph: error: writing the run to {out}: {e}", file=sys.stderr)
        return 1
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
