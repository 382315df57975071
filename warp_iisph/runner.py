"""Run a scene to an output folder: particle frames, per-step statistics and a run record."""

from __future__ import annotations

import dataclasses
import platform
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

from . import __version__
from .frames import OBSTACLES
from .io import StatsWriter, write_json, write_obj, write_particles
from .meshing import FrameMesher
from .scene import Scene, obstacles_mesh
from .simulation import DivergenceError, Simulation
from .writer import FrameWriter


class OutputExistsError(ValueError):
    pass


def prepare_output(out: Path, overwrite: bool) -> None:
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise OutputExistsError(f"--out {out}: folder exists and is not empty; pass --overwrite to replace it")
        for name in ("particles", "mesh", "stats.jsonl", "run.json", OBSTACLES):
            p = out / name
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
    out.mkdir(parents=True, exist_ok=True)


def _stage_seconds(stage_ms: dict, mesher, writer: FrameWriter) -> dict:
    """Wall seconds per stage on the main thread. ``export`` is what output cost it: the host
    copies plus the waits for the writer thread (whose own work overlaps the simulation)."""
    out = {k: v / 1e3 for k, v in stage_ms.items()}
    if mesher is not None:
        for k, v in mesher.seconds.items():
            if k != "export":
                out[k] = out.get(k, 0.0) + v
    out["export"] = out.get("export", 0.0) + writer.blocked
    return out


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
    t_start = time.perf_counter()
    sim = Simulation(scene, device=device, graph=graph)
    stats = StatsWriter(out / "stats.jsonl")
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
        write_obj(out / OBSTACLES, np.asarray(mesh.vertices), np.asarray(mesh.faces))
        record["obstacles"] = OBSTACLES
    stage_ms: dict[str, float] = {}
    frames_written = 0
    ended, message = "completed", ""

    mesher = FrameMesher(scene.spacing, scene.surface, sim.device) if scene.output.mesh else None
    writer = FrameWriter(background=background_output)

    def write_frame(k: int) -> None:
        jobs = []
        t = time.perf_counter()
        if scene.output.particles:
            ply = out / "particles" / f"frame_{k:05d}.ply"
            snapshot = (sim.positions, sim.velocities, sim.densities, sim.pressures)
            jobs.append(lambda: write_particles(ply, *snapshot))
        stage_ms["export"] = stage_ms.get("export", 0.0) + 1e3 * (time.perf_counter() - t)
        if mesher is not None:
            mesh, obj = mesher.mesh(sim.state.x), out / "mesh" / f"frame_{k:05d}.obj"
            jobs.append(lambda: mesher.export(mesh, obj))
        writer.submit(lambda: [job() for job in jobs])

    def on_step(rec: dict) -> None:
        stats.write(rec)
        for k, v in rec["ms"].items():
            stage_ms[k] = stage_ms.get(k, 0.0) + v

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_frames, unit="frame", dynamic_ncols=True, file=sys.stderr)
    try:
        write_frame(0)
        frames_written = 1
        if bar:
            bar.update(1)
        for k in range(1, n_frames):
            steps_before, wall_before = sim.step_count, time.perf_counter()
            sim.advance(k / fps - sim.time, callback=on_step)
            write_frame(k)
            stats.flush()
            frames_written = k + 1
            if bar:
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
            writer.close()  # every frame handed over is on disk before the record says so
        finally:
            if bar:
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
            "stage_seconds": _stage_seconds(stage_ms, mesher, writer),
            "output": {"background": background_output, "writer_seconds": writer.busy, "waited_seconds": writer.blocked},
        }
    )
    write_json(out / "run.json", record)
    return record
