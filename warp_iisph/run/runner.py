"""Run a scene to an output folder: particle frames, per-step statistics and a run record."""

from __future__ import annotations

import dataclasses
import platform
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from .. import __version__
from ..engine.timing import StageTimes
from ..scene import Scene, obstacles_mesh
from ..stepping import DivergenceError, Simulation
from .folder import OBSTACLES, RunFolder
from .formats import StatsWriter, write_json, write_obj, write_particles
from .frame_queue import FrameQueue
from .meshing import FrameMesher
from .progress import frame_bar


class OutputExistsError(ValueError):
    pass


def prepare_output(out: Path, overwrite: bool) -> None:
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise OutputExistsError(f"--out {out}: folder exists and is not empty; pass --overwrite to replace it")
        RunFolder(out).clear()
    out.mkdir(parents=True, exist_ok=True)


def versions() -> dict:
    return {"warp_iisph": __version__, "warp": wp.__version__, "numpy": np.__version__, "python": platform.python_version()}


def run_scene(scene: Scene, out, duration=None, fps=None, device: str = "cpu", overwrite: bool = False, progress: bool = True,
              graph: bool = False, background_output: bool = True) -> dict:
    """Simulate ``duration`` seconds, writing ``particles/frame_%05d.ply`` every ``1/fps`` s,
    ``stats.jsonl`` (one record per step), ``run.json`` and, for a scene with obstacles,
    ``obstacles.obj``. Returns the run record; its
    ``ended`` is ``completed``, ``diverged`` or ``interrupted``. Frame files are written on a
    background thread while the next frame simulates (``background_output=False``: inline)."""
    duration = scene.output.duration if duration is None else duration
    fps = scene.output.fps if fps is None else fps
    if not duration > 0:
        raise ValueError(f"duration = {duration}: must be > 0 seconds")
    if not fps > 0:
        raise ValueError(f"fps = {fps}: must be > 0 frames per second")
    out = Path(out)
    prepare_output(out, overwrite)
    run = RunFolder(out)
    t_start = time.perf_counter()
    sim = Simulation(scene, device=device, graph=graph)
    stats = StatsWriter(run.stats)
    n_frames = int(np.floor(duration * fps + 1e-9)) + 1
    record = {
        "scene": dataclasses.asdict(scene),
        "device": str(sim.device),
        "graph": graph,
        "versions": versions(),
        "command": " ".join(sys.argv),
        "particles": {"fluid": sim.n_particles, "boundary": sim.model.n_boundary},
        "duration": duration,
        "fps": fps,
    }
    if scene.obstacles:  # static: one file for the viewers and Blender, not one per frame
        mesh = obstacles_mesh(scene.obstacles)
        write_obj(run.obstacles, np.asarray(mesh.vertices), np.asarray(mesh.faces))
        record["obstacles"] = OBSTACLES
    # seconds per stage on the main thread; ``export`` is what output cost it: the host copies
    # plus the waits for the writer thread (whose own work overlaps the simulation)
    times = StageTimes()
    frames_written = 0
    ended, message = "completed", ""

    mesher = FrameMesher(scene.spacing, scene.surface, sim.device) if scene.output.mesh else None
    queue = FrameQueue(background=background_output)

    def write_frame(k: int) -> None:
        jobs = []
        if scene.output.particles:
            with times("export"):
                ply = run.particle_frame(k)
                snapshot = (sim.positions, sim.velocities, sim.densities, sim.pressures)
            jobs.append(lambda: write_particles(ply, *snapshot))
        if mesher is not None:
            mesh, obj = mesher.mesh(sim.state.x), run.mesh_frame(k)
            jobs.append(lambda: mesher.export(mesh, obj))
        queue.submit(lambda: [job() for job in jobs])

    def on_step(rec: dict) -> None:
        stats.write(rec)
        times.merge({k: v / 1e3 for k, v in rec["ms"].items()})

    bar = frame_bar(n_frames, progress)
    try:
        write_frame(0)
        frames_written = 1
        bar.update(1)
        for k in range(1, n_frames):
            steps_before, wall_before = sim.step_count, time.perf_counter()
            sim.advance(k / fps - sim.time, callback=on_step)
            write_frame(k)
            stats.flush()
            frames_written = k + 1
            rate = (sim.step_count - steps_before) / max(time.perf_counter() - wall_before, 1e-9)
            last = sim.stats[-1] if sim.stats else {}
            bar.set_postfix_str(f"t={sim.time:.3f}s {rate:.1f} steps/s err={100 * last.get('density_error', 0):.3f}%")
            bar.update(1)
    except DivergenceError as e:
        ended, message = "diverged", str(e)
    except KeyboardInterrupt:
        ended, message = "interrupted", f"interrupted at step {sim.step_count}, t = {sim.time:.5f} s"
    finally:
        try:
            queue.close()  # every frame handed over is on disk before the record says so
        finally:
            bar.close()
            stats.close()
    wall = time.perf_counter() - t_start
    its = [s["iterations"] for s in sim.stats]
    errs = [s["density_error"] for s in sim.stats]
    record.update(
        {
            "ended": ended,
            "message": message,
            "totals": {
                "steps": sim.step_count,
                "simulated_time": sim.time,
                "frames": frames_written,
                "wall_seconds": wall,
                "wall_seconds_per_simulated_second": wall / sim.time if sim.time > 0 else None,
                "mean_iterations": float(np.mean(its)) if its else 0.0,
                "mean_density_error": float(np.mean(errs)) if errs else 0.0,
                "mean_compression": float(np.mean([s["compression"] for s in sim.stats])) if sim.stats else 0.0,
            },
            "stage_seconds": _stage_seconds(times, mesher, queue),
            "output": {"background": background_output, "writer_seconds": queue.busy, "waited_seconds": queue.blocked},
        }
    )
    write_json(run.record_path, record)
    return record


def _stage_seconds(times: StageTimes, mesher, queue: FrameQueue) -> dict:
    """The main thread's seconds per stage: the steps', the meshing's and the waits for output."""
    total = StageTimes()
    total.merge(times.seconds)
    if mesher is not None:
        total.merge({k: v for k, v in mesher.times.seconds.items() if k != "export"})
    total.add("export", queue.blocked)
    return total.seconds
