"""What a resume keeps of its run folder: everything the run wrote up to its checkpoint, checked
before a resume trusts it (nothing written).

A resume keeps the frames up to the checkpoint's, the step records up to its step and the rows
of ``probes.csv`` and ``bodies.csv`` up to its time, and goes on after them. Files deleted since
(by hand, a crash, a sync tool) would leave holes in the run, or a time series out of step with
its frames, so a resume refuses, in one line naming the first such file, a folder where

- a frame file the run wrote up to the checkpoint is missing or empty: ``particles/`` and
  ``mesh/`` for the stretches of the run whose ``output`` wrote them (run.json's ``output`` and
  each resumption's ``output_before``), ``obstacles/`` when the solids move, and ``obstacles.obj``;
- a particle or mesh frame is cut short (:func:`.formats.cut_short`: a PLY's size is not what its
  header makes it, a VTU's XML is cut off, an OBJ's size is not what its counts make it);
- ``stats.jsonl`` does not hold the step records 1 .. the checkpoint's step, in order, the last at
  the checkpoint's time;
- ``probes.csv`` (a scene with probes) is missing, has other columns than the scene's probes (in
  their order), or holds another number of rows up to the checkpoint's time than the checkpoint
  counted;
- ``bodies.csv`` (a scene with free bodies) is missing, has other columns than the bodies', or does
  not hold one row per frame up to the checkpoint's.

The checks read a frame's header and last bytes only, and the step records and rows once; a time
series that the checkpoint says is empty and that is missing is made again by the resume (exactly).
"""

from __future__ import annotations

import math
from pathlib import Path

from ..scene.bodies import body_names
from ..scene.probes import probe_columns, sampled_order
from ..scene.settings import MESH_FORMATS
from .checkpoint import PROBE_SAMPLES
from .folder import MESHES, PARTICLES, RunError, RunFolder
from .formats import FileFormatError, cut_short, read_stats
from .probe_file import header as probes_header
from .run_record import FRAME_KINDS, STEP_SUMS
from .solids import header as bodies_header
from .solids import solids_move
from .time_series import rows_until

# the last kept step record's time may differ from the checkpoint's by this fraction (of 1 s at least)
TIME_SLACK = 1.0e-9

# what a user can do about a folder that lost some of its run
OVER = "put it back, or start the run over with --overwrite"


def check_kept(run: RunFolder, record: dict, state: dict, scene) -> list[dict]:
    """``RunError`` (one line naming the file and what to do) unless ``run`` holds what it wrote
    up to the checkpoint ``state`` (checked already: :func:`.checkpoint.check_checkpoint`), as its
    run.json ``record`` says (module docstring); the step records it keeps, when it does."""
    frame, steps, t = int(state["frame"]), int(state["step_count"]), float(state["time"])
    at = f"the checkpoint (frame {frame}, step {steps}, t = {t:g} s)"
    _check_frames(run, record, scene, frame, at)
    kept = _kept_steps(run, steps, t, at)
    if scene.probes:
        names, units = zip(*(c for p in sampled_order(scene.probes) for c in probe_columns(p)))
        cells = probes_header(names, units).split(",")
        counted = int(state[PROBE_SAMPLES]) if PROBE_SAMPLES in state else None
        _check_rows(run.probes, cells, counted, t, at, "probe samples", f"the checkpoint counted {counted}")
    if scene.bodies:
        cells = bodies_header(body_names(scene.bodies)).split(",")
        _check_rows(run.bodies, cells, frame + 1, t, at, "body rows", f"one per frame makes {frame + 1}")
    return kept


def _stretches(run: RunFolder, record: dict, frame: int) -> list[tuple[range, dict]]:
    """The frames 0 .. ``frame`` cut where the run was resumed, each with the ``output`` that wrote
    them (empty: not recorded)."""
    resumed = record.get("resumed", [])
    if not isinstance(resumed, list) or not all(
        isinstance(r, dict) and isinstance(r.get("frame"), int) and not isinstance(r.get("frame"), bool)
        for r in resumed
    ):
        raise RunError(f"{run.record_path}: resumed = {resumed!r:.80}: must be a list of the run's resumptions")
    out, start = [], 0
    for r in resumed:
        end = min(r["frame"], frame)
        wrote = r.get("output_before")
        out.append((range(start, end + 1), wrote if isinstance(wrote, dict) else {}))
        start = max(start, end + 1)
    out.append((range(start, frame + 1), record.get("output") or {}))
    return out


def _check_frames(run: RunFolder, record: dict, scene, frame: int, at: str) -> None:
    """Every frame file the run wrote up to ``frame`` is there, not empty and whole
    (:func:`.formats.cut_short`)."""
    remake = (  # what a user can do about a lost mesh whose particle frame is there
        f"put it back, make it again from its particle frame with `warp-iisph mesh {run.path}` "
        "(not bitwise the run's own), or start the run over with --overwrite"
    )
    for frames, wrote in _stretches(run, record, frame):
        for kind in FRAME_KINDS:
            if wrote.get(kind) is not True:
                continue
            for k in frames:
                if kind == PARTICLES:
                    _frame_there(run.particle_frame(k), at)
                    _whole(run.particle_frame(k), at)
                    continue
                remedy = remake if _size(run.particle_frame(k)) else OVER
                there = [p for p in (run.path / MESHES / f"frame_{k:05d}.{e}" for e in MESH_FORMATS) if _size(p)]
                if not there:
                    _frame_there(run.mesh_frame(k), at, remedy)
                for mesh in there:
                    _whole(mesh, at, remedy)
    if record.get("obstacles") and not _size(run.obstacles):
        raise RunError(
            f"{run.obstacles}: {_gone(run.obstacles)}; the run wrote it at its start and a resume keeps it: {OVER}"
        )
    if solids_move(scene):
        for k in range(frame + 1):
            _frame_there(run.obstacle_frame(k), at)


def _whole(path: Path, at: str, remedy: str = OVER) -> None:
    """``RunError`` saying ``remedy`` when the frame file ``path`` is cut short
    (:func:`.formats.cut_short`)."""
    why = cut_short(path)
    if why is not None:
        raise RunError(
            f"{path}: cut short ({why}), though the run had written it whole by {at}; "
            f"a resume would keep a broken frame: {remedy}"
        )


def _size(path: Path) -> int:
    """The file's size (0 when it is not a file)."""
    try:
        return path.stat().st_size if path.is_file() else 0
    except OSError:
        return 0


def _gone(path: Path) -> str:
    return "empty" if path.is_file() else "missing"


def _frame_there(path: Path, at: str, remedy: str = OVER) -> None:
    """``RunError`` saying ``remedy`` when the frame file ``path``, which the run had written by
    ``at``, is not there."""
    if not _size(path):
        raise RunError(
            f"{path}: {_gone(path)}, though the run had written it by {at}; "
            f"a resume would leave a hole in the run: {remedy}"
        )


def _kept_steps(run: RunFolder, steps: int, t: float, at: str) -> list[dict]:
    """The step records 1 .. ``steps`` of ``stats.jsonl``, the last at time ``t``."""
    path = run.stats
    if not path.is_file():
        if steps == 0:  # nothing to keep: the resume writes it anew
            return []
        raise RunError(f"{path}: missing, though the run had written {steps} step records by {at}: {OVER}")
    try:
        records = read_stats(path)
    except FileFormatError as e:
        raise RunError(f"{e}; the step records up to {at} are not all readable: {OVER}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RunError(f"{path}: cannot be read ({' '.join(str(e).split())})") from None
    kept = []
    for k, r in enumerate(records, 1):
        step = r.get("step") if isinstance(r, dict) else None
        if not _number(step, integer=True):
            raise RunError(f"{path}: record {k} is not a step record (it has no whole step number): {OVER}")
        if step > steps:  # after the checkpoint (a diverged step's may hold NaN): it goes
            continue
        if not _number(r.get("t")) or not all(_number(r.get(key), finite=False) for key in STEP_SUMS):
            raise RunError(f"{path}: record {k} is not a step record (t, {', '.join(STEP_SUMS)}): {OVER}")
        if step != len(kept) + 1:
            raise RunError(
                f"{path}: record {k} is of step {step}, where step {len(kept) + 1} belongs; "
                f"the step records up to {at} are not all there in order: {OVER}"
            )
        kept.append(r)
    if len(kept) < steps:
        raise RunError(
            f"{path}: holds the step records up to step {len(kept)}, the run had written {steps} by {at}; "
            f"a resume would leave it out of step with the frames: {OVER}"
        )
    if kept and abs(kept[-1]["t"] - t) > TIME_SLACK * max(1.0, t):
        raise RunError(
            f"{path}: step {steps} ends at t = {kept[-1]['t']:g} s, not at {at}; "
            f"not the step records of this run: {OVER}"
        )
    return kept


def _number(v, integer: bool = False, finite: bool = True) -> bool:
    """Whether ``v`` is a number of JSON (a whole one with ``integer``; finite with ``finite``)."""
    if isinstance(v, bool) or not isinstance(v, int if integer else (int, float)):
        return False
    return not finite or math.isfinite(v)


def _check_rows(path: Path, cells, expected: int | None, t: float, at: str, what: str, why: str):
    """A time series (``probes.csv``, ``bodies.csv``) headed ``cells``, in that order (the writer
    keeps rows only under its own header), that holds ``expected`` rows up to time ``t`` (``None``:
    not known, not counted; ``why`` says where the number comes from)."""
    if not path.is_file():
        if expected == 0:  # nothing to keep: the resume writes it anew
            return
        raise RunError(f"{path}: missing, though the run had written it by {at}: {OVER}")
    try:
        head, rows = rows_until(path, t)
    except (OSError, UnicodeDecodeError) as e:
        raise RunError(f"{path}: cannot be read ({' '.join(str(e).split())})") from None
    if head.split(",") != list(cells):
        raise RunError(
            f"{path}: its first line is not the header of this run's {what} ({len(cells) - 1} columns after t [s]); "
            f"a resume would drop its rows: {OVER}"
        )
    if expected is not None and len(rows) != expected:
        raise RunError(
            f"{path}: holds {len(rows)} {what} up to {at}, {why}; "
            f"a resume would leave it out of step with the frames: {OVER}"
        )
