"""The command line's grammar: every command, its arguments and options, and their help."""

from __future__ import annotations

from . import EXIT_BAD_INPUT


def _parser():
    import argparse

    from ..scene.settings import METHODS

    class OneLineParser(argparse.ArgumentParser):
        """argparse, with its usage errors in one line."""

        def error(self, message: str):
            self.exit(EXIT_BAD_INPUT, f"warp-iisph: error: {message} (see {self.prog} --help)\n")

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
        help="continue a stopped, interrupted, terminated or diverged (then --set fixed) run from its last checkpoint, "
        "bitwise as it would have run; --duration may extend it; refused while a file the run wrote up to "
        "the checkpoint is missing or cut",
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
    run.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing run in the output folder (only a run of warp-iisph holding none of the run's inputs)",
    )
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
    mesh = sub.add_parser("mesh", help="mesh a run's particle frames (or any particle files) into OBJ or PLY surfaces")
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
