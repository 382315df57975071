"""A run's checkpoint (``checkpoint.npz``): the state to resume from, whose it is, and whether it
makes sense, checked before a resume trusts it.

Besides the simulation's arrays (``Simulation.checkpoint``) and the frame it was taken at (and,
for a scene with probes, how many rows ``probes.csv`` held then), a checkpoint holds its run's
``run_id``, the fingerprint of the scene it was taken of (a hash of the geometry and of each mesh
file's contents, ``scene_fingerprint``), its format and the version of warp-iisph that wrote it.
A resume refuses, in one line naming the file, a checkpoint of another run, of a scene whose
geometry or meshes changed, of another format or version, one with keys missing or of the wrong
shape, and values that make no sense (a time that is not its frame's, more frames than the run was
asked for, fewer steps than frames, more probe samples than steps, non-finite particles, ids
repeated or beyond the next one, free bodies' state missing or not one finite row per body); what
the run folder must still hold besides is :mod:`.kept`'s.
"""

from __future__ import annotations

import json
import zipfile

import numpy as np

from .. import __version__
from ..scene import scene_fingerprint
from ..scene.settings import MIN_STEP
from ..setup.model import PARTICLE_FIELDS
from ..stepping.state_check import check_state, outside, scalar
from .atomic import staged_write
from .folder import RunError, RunFolder

FORMAT = 3  # what a checkpoint holds (1: before it said whose it is; 2: before obstacles were
# sampled in layers, whose boundary a resume would rebuild otherwise)
OWNER_KEYS = ("run_id", "fingerprint", "format", "warp_iisph")
STATE_KEYS = (*PARTICLE_FIELDS, "max_speed2", "sub_left", "sub_done", "time", "step_count", "method")
KEYS = (*STATE_KEYS, "next_id", "frame", *OWNER_KEYS)
# the rows probes.csv held when the checkpoint was taken (a scene with probes; older checkpoints: none)
PROBE_SAMPLES = "probe_samples"


def owner(run_id: str, scene) -> dict:
    """What a checkpoint of run ``run_id`` of ``scene`` records of itself."""
    return {
        "run_id": np.array(run_id),
        "fingerprint": np.array(json.dumps(scene_fingerprint(scene), sort_keys=True)),
        "format": np.int64(FORMAT),
        "warp_iisph": np.array(__version__),
    }


def stage_checkpoint(run: RunFolder, state: dict):
    """Write the checkpoint beside its place; the returned file's ``commit`` renames it in."""

    def write(tmp):
        with open(tmp, "wb") as f:
            np.savez(f, **state)

    return staged_write(run.checkpoint, write)


def load_checkpoint(run: RunFolder) -> dict:
    """The state ``run`` kept at its last checkpoint, with the frame it was taken at (read only:
    :func:`check_checkpoint` says whether it may be used)."""
    if not run.checkpoint.is_file():
        raise RunError(
            f"{run.checkpoint}: no checkpoint to resume from (output.checkpoint_every = 0, or no frame was written)"
        )
    try:
        with np.load(run.checkpoint, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise RunError(f"{run.checkpoint}: not a readable checkpoint ({' '.join(str(e).split())})") from None


def _check_values(state: dict, fps: float, duration: float, scene) -> None:
    """``ValueError`` saying what makes no sense (the caller names the file): the simulation's
    state (:func:`~warp_iisph.stepping.state_check.check_state`), and the run's own: the frame
    it was taken at, the steps and probe samples up to it."""
    for key in ("next_id", "frame"):
        if key not in state:
            raise ValueError(f"has no {key}")
    time, steps, _ = check_state(state, scene)
    frame = scalar(state, "frame", "int")
    if frame < 0 or abs(time - frame / fps) > 1e-6 * max(1.0, time):
        raise ValueError(f"frame = {frame} at time = {time:g} s: not that frame's time at {fps:g} frames/s")
    if time > duration * (1 + 1e-9) + 1e-9:
        raise ValueError(f"time = {time:g} s: beyond the {duration:g} s the run was asked for")
    if not frame <= steps <= 2.0 * time / MIN_STEP + 10 * (frame + 1):
        raise ValueError(f"step_count = {steps}: must be at least the frame ({frame}) and within the time")
    if PROBE_SAMPLES in state:  # the rows probes.csv held at the checkpoint: at most one per step
        samples = scalar(state, PROBE_SAMPLES, "int")
        if not 0 <= samples <= steps:
            raise ValueError(f"{PROBE_SAMPLES} = {samples}: must be in [0, step_count = {steps}]")


def check_checkpoint(state: dict, run: RunFolder, record: dict, scene, fps: float) -> None:
    """``RunError`` (one line naming the checkpoint) unless ``state`` is a checkpoint of this run
    (``record``, its run.json) taken of ``scene`` with this format and version, whose values make
    sense at ``fps``."""
    where = run.checkpoint
    missing = [k for k in KEYS if k not in state]
    if missing:
        older = " (written by an older warp-iisph)" if set(missing) & set(OWNER_KEYS) else ""
        raise RunError(f"{where}: has no {', '.join(missing)}{older}; this run cannot be resumed from it")
    try:
        fmt, version, run_id = scalar(state, "format", "int"), str(state["warp_iisph"]), str(state["run_id"])
    except ValueError as e:
        raise RunError(f"{where}: {e}") from None
    if fmt != FORMAT or version != __version__:
        raise RunError(
            f"{where}: written by warp-iisph {version} (checkpoint format {fmt}); this is {__version__} "
            f"(format {FORMAT}), which resumes only its own"
        )
    if run_id != record.get("run_id"):
        raise RunError(
            f"{where}: belongs to run {run_id}, not to this folder's run {record.get('run_id')} ({run.record_path}); "
            "a checkpoint resumes only its own run"
        )
    try:
        taken = json.loads(str(state["fingerprint"]))
        now = scene_fingerprint(scene)
    except ValueError as e:
        raise RunError(f"{where}: {e}") from None
    if not isinstance(taken, dict):
        raise RunError(f"{where}: its scene fingerprint is not readable")
    changed = [
        k
        for k in sorted(set(now["meshes"]) | set(taken.get("meshes") or {}))
        if now["meshes"].get(k) != (taken.get("meshes") or {}).get(k)
    ]
    if changed:
        raise RunError(
            f"{where}: the mesh file of {changed[0]} changed since the checkpoint was taken; "
            "resuming would mix two scenes"
        )
    if taken.get("geometry") != now["geometry"]:
        raise RunError(f"{where}: was taken of another scene geometry than {run.record_path} records")
    if "probes" in taken and taken["probes"] != now["probes"]:  # checkpoints before 2026-12-05 have none
        raise RunError(
            f"{where}: was taken with other probes than {run.record_path} records; "
            "probes.csv's columns would mix two sets of sensors"
        )
    if "probe_interval" in taken and taken["probe_interval"] != now["probe_interval"]:  # none before 2026-12-05
        raise RunError(
            f"{where}: its probes were read every {taken['probe_interval']:g} s (0: every step), this resume "
            f"would read them every {now['probe_interval']:g} s; probes.csv keeps one interval: resume without "
            "changing output.probe_interval"
        )
    try:
        _check_values(state, fps, float(record.get("duration") or 0.0), scene)
    except ValueError as e:
        raise RunError(f"{where}: {e}; not a checkpoint this run can resume from") from None


def check_positions(state: dict, run: RunFolder, domain) -> None:
    """``RunError`` when the checkpoint's particles lie outside the scene's domain (lower, upper)."""
    if outside(state["x"], domain):
        raise RunError(f"{run.checkpoint}: holds particles outside the tank; not a checkpoint of this scene")
