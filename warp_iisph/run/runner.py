"""Run a scene to an output folder: particle frames, per-step statistics and a run record.

Nothing on disk changes until the run is built (scene validated, particles sampled, memory
checked, the output folder checked and locked: :mod:`.replace`, :mod:`.lock`). A new run is
written into a folder beside its place, which it takes (with the old run's place, when it
replaces one) once its first frame is on disk; so a refused or failed start leaves the old run
as it was, and nothing of the old run (frames, videos, scripts) outlives the replacement.
``run.json`` exists from the first frame on, says ``running`` while the run goes on (with totals
updated every frame) and is rewritten atomically however the run ends: ``completed``,
``diverged``, ``interrupted``, ``terminated`` or ``failed`` (a file could not be written, or
anything else went wrong at run time, which the message names). A resume continues from the
run's own checkpoint only (:mod:`.checkpoint`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from pathlib import Path

from ..engine import signals
from ..engine.signals import Terminated
from ..scene import MeshShape, Scene
from ..scene.checks import in_range
from ..scene.settings import MESH_FORMATS, PARTICLE_FORMATS
from .checkpoint import check_checkpoint, check_positions, load_checkpoint, owner
from .folder import (
    FRAMES,
    MESHES,
    OBSTACLE_FRAMES,
    PARTICLES,
    VIEW_FILES,
    RunError,
    RunFolder,
    frame_files,
    frame_index,
)
from .formats import StatsWriter
from .frame_queue import FrameQueue
from .frame_writer import FrameWriter
from .kept import check_kept
from .lock import FolderLock
from .meshing import FrameMesher, mesh_settings, recorded_mesh_settings
from .probe_file import open_probe_file
from .progress import frame_bar
from .replace import OutputExistsError, commit, discard, prepare, recover, resolved, stage
from .run_record import RunRecord
from .solids import SolidFiles

__all__ = ["OutputExistsError", "Terminated", "load_checkpoint", "resumed_scene", "run_scene"]


@dataclasses.dataclass
class FramePlan:
    """Frames at ``k / fps`` for ``k = 0 .. frames - 1``: ``duration`` is the last frame's time (the
    asked duration cut to whole frames, which ``requested`` keeps)."""

    fps: float
    frames: int
    duration: float
    requested: float


def plan_frames(scene: Scene, duration=None, fps=None) -> FramePlan:
    """The frames a run writes; ``ValueError`` naming ``--duration``/``--fps`` (or the scene's
    ``output`` keys) when they are out of range or give less than one frame interval."""
    d_name, f_name = (
        ("output.duration" if duration is None else "--duration"),
        ("output.fps" if fps is None else "--fps"),
    )
    duration = in_range(
        scene.output.duration if duration is None else duration, d_name, 0.0, 1.0e6, "simulated seconds", lo_open=True
    )
    fps = in_range(
        scene.output.fps if fps is None else fps, f_name, 0.0, 10_000.0, "frames per simulated second", lo_open=True
    )
    intervals = int(math.floor(duration * fps + 1e-9))
    if intervals < 1:
        raise ValueError(
            f"{d_name} = {duration:g}: shorter than one frame interval at {fps:g} frames/s ({1 / fps:.4g} s)"
        )
    return FramePlan(fps, intervals + 1, intervals / fps, duration)


def scene_inputs(scene: Scene) -> list[Path]:
    """The files a run of ``scene`` reads besides its scene file: its meshes."""
    shapes = [scene.tank, *scene.obstacles, *(b.shape for b in scene.bodies)]
    return [Path(s.base_dir) / s.path for s in shapes if isinstance(s, MeshShape)]


def _open_to_resume(out, scene: Scene, plan: FramePlan) -> tuple[RunFolder, dict, dict, list[dict], FolderLock]:
    """The run folder to resume, locked, with its record, its checkpoint and the step records it
    keeps, checked: the checkpoint, and that the folder holds what the run wrote up to it
    (:mod:`.kept`); nothing written."""
    path = resolved(out, "--resume")
    recover(path)
    run = RunFolder.existing(path)
    lock = FolderLock(path).acquire()
    try:
        before = run.record()
        if not run.is_run():
            raise RunError(f"{run.record_path}: not the record of a warp-iisph run; there is nothing to resume")
        checkpoint = load_checkpoint(run)
        if abs(run.fps(before) - plan.fps) > 1e-9 * plan.fps:
            raise ValueError(
                f"--fps (or --set output.fps) = {plan.fps:g}: a resumed run keeps its {run.fps(before):g} frames/s"
            )
        if run.particle_format != scene.output.format:
            raise ValueError(f"--set output.format: a resumed run keeps its {run.particle_format} frames")
        _check_mesh_settings(run, before, scene)
        check_checkpoint(checkpoint, run, before, scene, plan.fps)
        kept_steps = check_kept(run, before, checkpoint, scene)
        frame = int(checkpoint["frame"])
        if plan.frames - 1 < frame:
            raise ValueError(
                f"--duration = {plan.requested:g}: the run has already reached frame {frame} "
                f"(t = {frame / plan.fps:g} s) and a resumed run goes on from there; give a longer one"
            )
        if plan.frames - 1 == frame and before.get("ended") == "completed":  # nothing to run, nothing to change
            raise ValueError(
                f"--resume {out}: the run is complete at frame {frame} (t = {frame / plan.fps:g} s); "
                "give a longer --duration to extend it"
            )
        inputs = {Path(os.path.realpath(p)) for p in scene_inputs(scene)}
        doomed = [f for f in _frames_after(run, frame) if Path(os.path.realpath(f)) in inputs]
        if doomed:
            raise RunError(
                f"{doomed[0]}: a mesh of this run's scene, which resuming would delete (frames after the checkpoint go)"
            )
    except BaseException:
        lock.release()
        raise
    return run, before, checkpoint, kept_steps, lock


def _check_mesh_settings(run: RunFolder, before: dict, scene: Scene) -> None:
    """``RunError`` when a resume that writes meshes would put them beside meshes of other settings
    (remade by ``warp-iisph mesh``, or a ``--set surface.KEY`` on this resume): mesh/source.json
    names one set of settings for the folder. A key a run of an older version did not record has
    its default."""
    made = run.provenance(MESHES)
    if not scene.output.mesh or made is None or not run.has_frames(MESHES):
        return
    mine = mesh_settings(scene.surface, scene.spacing)
    theirs = recorded_mesh_settings(made, scene.spacing)
    changed = sorted(k for k in mine if theirs.get(k) != mine[k])
    if made.get("run_id") == before.get("run_id") and not changed:
        return
    raise RunError(
        f"{run.path / MESHES}: holds meshes made with other settings ({', '.join(changed) or 'another run'}) "
        "than this resume writes; it would mix the two: resume with theirs (--set surface.KEY=VALUE), or "
        "first remake them with this resume's (warp-iisph mesh RUN_DIR --overwrite --KEY VALUE)"
    )


def _failure(e: BaseException) -> str:
    """A run-time error in one line: our own messages as they are, anything else with its kind."""
    text = " ".join(str(e).split())
    if isinstance(e, ValueError):
        return text or type(e).__name__
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def run_scene(
    scene: Scene,
    out,
    duration=None,
    fps=None,
    device: str = "cpu",
    overwrite: bool = False,
    progress: bool = True,
    graph: bool = False,
    background_output: bool = True,
    resume: bool = False,
    inputs=(),
    on_built=None,
) -> dict:
    """Simulate the scene, writing ``particles/frame_%05d.ply`` (or ``.vtu``, as ``output.format``
    says) every ``1/fps`` s, ``stats.jsonl`` (one record per step), ``run.json``, for a scene
    with obstacles or bodies the files of :mod:`.solids` and for one with probes ``probes.csv``.
    Returns the run record (``ended`` says how it ended). Frame files are written on a background
    thread while the next frame simulates (``background_output=False``: inline). With ``resume``,
    ``out`` is a run stopped (or diverged, then fixed) after a checkpoint: it continues from there,
    bitwise as it would have, to the frames ``duration`` asks for (``scene``: the run's own, see
    :func:`resumed_scene`). ``inputs``: files the run is made from besides the scene's meshes (its
    scene file), which ``overwrite`` never deletes. The run folder is locked while the run goes on
    (:mod:`.lock`); a new run is written beside its place and moved there with its first frame
    (:mod:`.replace`). ``on_built`` is called with the simulation once everything is built and
    checked, before the first step: a refusal never follows what it says."""
    from ..stepping import Simulation

    flags = {
        "overwrite": overwrite,
        "progress": progress,
        "graph": graph,
        "background_output": background_output,
        "resume": resume,
    }
    for name, value in flags.items():
        if not isinstance(value, bool):
            raise TypeError(f"{name} = {value!r}: must be True or False")
    plan = plan_frames(scene, duration, fps)
    held = []  # the locks (and the target) released when the run ends, however it ends
    staging = None  # a new run's folder and lock, until it takes its place
    before = None  # a resumed run's record
    kept_steps = None  # and the step records it keeps
    try:
        if resume:
            run, before, checkpoint, kept_steps, lock = _open_to_resume(out, scene, plan)
            held.append(lock)
            out = run.path
        else:
            target = prepare(out, overwrite, [*inputs, *scene_inputs(scene)])
            held.append(target)
            out = target.path
        t_start = time.perf_counter()
        # everything is built before the disk changes; step records go to stats.jsonl, not memory
        sim = Simulation(scene, device=device, graph=graph, history=1, until=plan.duration, probe_history=1)
        scene = sim.scene  # its own validated copy, which the caller cannot change while it runs
        sim.flows.warn_full = False  # run.json counts what was not emitted, and the run warns of it
        first = 0
        if resume:
            check_positions(checkpoint, run, (sim.model.domain_lower, sim.model.domain_upper))
            sim.restore(checkpoint)
            first = int(checkpoint["frame"]) + 1
            run = RunFolder(out, scene.output.format)
        else:
            staging = stage(target)
            run = RunFolder(staging[0], scene.output.format)
        if on_built is not None:
            on_built(sim)
        place = None if resume else (lambda: commit(target, *staging))
        record = _simulate(
            scene, sim, run, plan, first, t_start, background_output, progress, graph, (before, kept_steps), place
        )
        if staging is not None and run.path == staging[0]:  # the new run never got its first frame in place
            discard(*staging, target)
        return record
    except BaseException:
        if staging is not None and staging[0].exists():
            discard(*staging, target)
        raise
    finally:
        for h in held:
            h.release()


def _simulate(scene, sim, run, plan, first, t_start, background_output, progress, graph, resumed, place) -> dict:
    """The run itself, from frame ``first`` (0, or the one after a resumed run's checkpoint:
    ``resumed`` is its record and the step records it keeps, else ``(None, None)``); ``place``
    moves a new run's folder into its place once its first frame is on disk. Returns the run
    record, whose ``ended`` says how it ended; every ending is written to ``run.json`` (except
    where the run never got in place, and the old folder stays as it was)."""
    from ..stepping import DivergenceError

    before, kept_steps = resumed
    resume = before is not None
    record = RunRecord(scene, sim, run, plan, graph, background_output, before, first)
    record.started = t_start
    mesher = queue = frames = None
    logs = []  # the files that grow step by step or frame by frame: stats.jsonl, the solids', probes.csv
    placed = resume  # whether the run folder is in its place (a new one moves there with frame 0)
    bar = frame_bar(plan.frames, progress)
    ended, message = "completed", ""
    try:
        mesher = FrameMesher(scene.spacing, scene.surface, sim.device) if scene.output.mesh else None
        queue = FrameQueue(background=background_output)
        if resume:
            steps, solids, probes = _continue_logs(run, sim, scene, plan, first, record, kept_steps)
        else:
            steps, solids = StatsWriter(run.stats), SolidFiles(run, scene, plan.fps)
            probes = open_probe_file(run.probes, sim)
        logs += [steps, solids, probes]
        owner_keys = owner(record.run_id, scene)
        frames = FrameWriter(sim, run, scene, plan.frames, queue, mesher, solids, owner_keys, record.times, probes)

        def on_step(step: dict) -> None:
            steps.write(step)
            record.add_step(step)

        if resume:
            frames.written = first
            record.write(frames.written, mesher, queue)
        else:
            record.data.update(solids.start())  # one file for the viewers and Blender (at t = 0)
            if mesher is not None:
                run.write_provenance(MESHES, record.run_id, mesh_settings(scene.surface, scene.spacing))
            frames.write(0)
            queue.wait()
            record.write(frames.written, mesher, queue)
            with signals.held():  # a Ctrl-C now is raised once the run is in place and knows it
                run.path = place()  # the new run is on disk: it takes its place (and the old one's)
                placed = True
            first = 1
        bar.update(first)
        for k in range(first, plan.frames):
            steps_before, wall_before = sim.step_count, time.perf_counter()
            sim.advance(k / plan.fps - sim.time, callback=on_step)
            for log in (steps, probes):  # in the file before the frame's checkpoint says they are
                if log is not None:
                    log.flush()
            frames.write(k)
            record.write(frames.written, mesher, queue)
            rate = (sim.step_count - steps_before) / max(time.perf_counter() - wall_before, 1e-9)
            last = sim.stats[-1] if sim.stats else {}
            bar.set_postfix_str(f"t={sim.time:.3f}s {rate:.1f} steps/s err={100 * last.get('density_error', 0):.3f}%")
            bar.update(1)
        queue.wait()
    except DivergenceError as e:
        ended, message = "diverged", str(e)
    except Terminated:
        ended, message = "terminated", f"terminated at step {sim.step_count}, t = {sim.time:.5f} s"
    except KeyboardInterrupt:
        ended, message = "interrupted", f"interrupted at step {sim.step_count}, t = {sim.time:.5f} s"
    except Exception as e:  # an error met while a Ctrl-C or SIGTERM unwound is how that signal ended it
        stop = _signal_behind(e)
        if stop is not None:
            ended = "terminated" if isinstance(stop, Terminated) else "interrupted"
            message = f"{ended} at step {sim.step_count}, t = {sim.time:.5f} s"
        elif isinstance(e, OSError):
            ended, message = "failed", f"writing the run to {run.path}: {e}"
        elif isinstance(e, MemoryError):  # storage that would outgrow the device or its indices: frames so far stay
            ended, message = "failed", str(e) or "out of memory"
        else:  # anything else at run time (a surface grid outgrowing its limit, a thread that cannot
            # start): the run stops, and its record says why
            ended, message = "failed", f"at step {sim.step_count}, t = {sim.time:.5f} s: {_failure(e)}"
    finally:
        _close_quietly(bar.close)
        if queue is not None:
            try:
                queue.close()  # every frame handed over is on disk (or failed) before the record says so
            except Exception as e:
                if ended == "completed":
                    ended, message = "failed", f"writing the run to {run.path}: {_failure(e)}"
        for log in logs:
            if log is not None:
                _close_quietly(log.close)
    written = frames.written if frames is not None else 0
    if not placed:  # the new run never got its first frame in place: the old folder stays as it was
        record.end(ended if ended != "completed" else "failed", message or "no frame was written")
        return record.refresh(0)
    record.end(ended, message)
    try:
        record.write(written, mesher, queue)
    except OSError as e:  # the disk is full: the record written at the last frame stays
        note = f"run.json could not be updated ({e})"
        record.end(ended if ended != "completed" else "failed", f"{message}; {note}" if message else note)
    return record.data


def _signal_behind(e: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C or SIGTERM an exception was raised while handling, if any: that is how the run
    ended, not the error its cleanup met."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, KeyboardInterrupt):
            return e
        e = e.__context__
    return None


def _continue_logs(run: RunFolder, sim, scene, plan, first: int, record: RunRecord, kept: list[dict]) -> tuple:
    """A resumed run's growing files, cut back to its checkpoint (frame ``first - 1``): what the
    stopped run wrote after it goes (and the rendered images of those frames), and what a killed
    run staged; the views made of all frames or samples (:data:`.folder.VIEW_FILES`: videos, the
    USD stage, the probes' chart) go too, as the resume makes frames again or adds frames after
    the last;
    the step records up to its step (``kept``, checked by :func:`.kept.check_kept`) stay and go
    into the totals, the solids' and the probes' rows up to its time."""
    again = _frames_after(run, first - 1)
    again += [f for f in frame_files(run.path / FRAMES, "png") if frame_index(f) > first - 1]  # their images
    again += [run.path / v for v in VIEW_FILES if (run.path / v).is_file()]  # they would miss or mix frames
    for old in again + run.temporary_files():
        old.unlink()
    for r in kept:
        record.totals.add(r)
    steps = StatsWriter(run.stats, keep=kept)
    solids = SolidFiles(run, scene, plan.fps, keep_until=sim.time)
    return steps, solids, open_probe_file(run.probes, sim, keep_until=sim.time)


def _close_quietly(close) -> None:
    try:
        close()
    except Exception:  # a progress bar on a closed terminal, a stats file on a full disk: the record says the rest
        pass


def resumed_scene(run_dir, overrides=()) -> Scene:
    """The scene of the run in ``run_dir`` (as its ``run.json`` records it), changed by ``--set``
    overrides of its physics, output, surface or camera: a resumed run keeps its particles, so its
    spacing, tank, fluids and obstacles stay as they were."""
    from ..scene import scene_from_dict
    from ..scene.file import apply_override

    path = resolved(run_dir, "--resume")
    recover(path)
    run = RunFolder.existing(path)
    record = run.record()
    data = record.get("scene")
    if not data or "tank" not in data:  # the record's parts are of their kinds (RunFolder.record)
        raise RunError(f"{run.record_path}: records no scene to resume")
    # the run's own length and frame rate (asked on its command line, not in its scene file)
    data.setdefault("output", {}).update(
        duration=record.get("requested_duration", record.get("duration")), fps=run.fps(record)
    )
    if isinstance(overrides, str):  # one string is one override, as load_scene takes it
        overrides = [overrides]
    for assignment in overrides:
        key = assignment.partition("=")[0].strip()
        if key.split(".")[0] not in ("physics", "output", "surface", "camera"):
            raise ValueError(
                f"--set {key}: a resumed run keeps its particles, bodies and probes (probes.csv goes on as "
                f"it was written); only physics, output, surface and camera keys may change"
            )
        try:
            apply_override(data, assignment)
        except ValueError as e:  # the override's own fault, said with the record it changes
            raise type(e)(f"{run.record_path}, {e}") from None
    try:
        return scene_from_dict(data, default_name=run.path.name)
    except ValueError as e:
        raise ValueError(f"{run.record_path}: {e}") from None


def _frames_after(run: RunFolder, k: int) -> list[Path]:
    """The particle, mesh and obstacle frames after frame ``k``."""
    exts = {PARTICLES: PARTICLE_FORMATS, MESHES: MESH_FORMATS, OBSTACLE_FRAMES: ("obj",)}
    return [
        f for kind, kinds in exts.items() for e in kinds for f in frame_files(run.path / kind, e) if frame_index(f) > k
    ]
