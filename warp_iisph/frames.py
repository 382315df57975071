"""A run's frame files as seen by the viewers (preview, render, Blender script): which frames
exist, the run's record, a ``a:b`` frame selection, and image sequences written as video."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


class RunError(ValueError):
    """A run folder that cannot be viewed as asked (missing, no frames, bad selection)."""


def load_run(run_dir) -> tuple[Path, dict]:
    """The run folder and its ``run.json`` record (empty when the run wrote none)."""
    run = Path(run_dir)
    if not run.is_dir():
        raise RunError(f"{run}: no such run folder")
    record = {}
    if (run / "run.json").is_file():
        try:
            record = json.loads((run / "run.json").read_text())
        except json.JSONDecodeError as e:
            raise RunError(f"{run / 'run.json'}: not valid JSON ({e.msg}, line {e.lineno})") from None
    return run, record


def frame_files(run: Path, kind: str) -> list[Path]:
    """``particles/frame_*.ply`` or ``mesh/frame_*.obj`` of a run, in frame order."""
    sub, ext = {"particles": ("particles", "ply"), "mesh": ("mesh", "obj")}[kind]
    files = sorted((run / sub).glob(f"frame_*.{ext}"))
    if not files:
        hint = "run with --mesh, or `warp-iisph mesh RUN_DIR`" if kind == "mesh" else "was the run written with output.particles = false?"
        raise RunError(f"{run / sub}: no frame_*.{ext} files ({hint})")
    return files


def frame_index(path: Path) -> int:
    return int(path.stem.split("_")[-1])


def select_frames(files: list[Path], spec: str | None) -> list[Path]:
    """Frames whose number is in ``a:b`` (b excluded; either end may be left out, like a Python
    slice of frame numbers); all of them for ``None``."""
    if not spec:
        return files
    parts = spec.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        lo = int(parts[0]) if parts[0] else 0
        hi = int(parts[1]) if parts[1] else None
    except ValueError:
        raise RunError(f"--frames {spec!r}: must be a:b with whole frame numbers, e.g. 0:30, 10:, :60") from None
    chosen = [f for f in files if frame_index(f) >= lo and (hi is None or frame_index(f) < hi)]
    if not chosen:
        raise RunError(f"--frames {spec}: no frame in that range (the run has frames {frame_index(files[0])}..{frame_index(files[-1])})")
    return chosen


def tank_bounds(record: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The box tank's corners from a run record; ``None`` for a mesh tank or no record."""
    tank = record.get("scene", {}).get("tank", {})
    if "lower" in tank and "upper" in tank:
        return np.asarray(tank["lower"], float), np.asarray(tank["upper"], float)
    return None


OBSTACLES = "obstacles.obj"  # a run's obstacles, written once: they do not move


def obstacle_mesh(run: Path):
    """The run's obstacles as one ``trimesh.Trimesh``, or ``None`` when it has none."""
    path = run / OBSTACLES
    if not path.is_file():
        return None
    import trimesh

    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except Exception as e:  # trimesh raises many kinds for a bad file
        raise RunError(f"{path}: cannot read the obstacles ({type(e).__name__}: {e})") from None
    return mesh if len(getattr(mesh, "faces", ())) else None


def write_video(images, path, fps: float, gif: bool = False) -> None:
    """Write RGB uint8 frames (an iterable of (H, W, 3) arrays) as an MP4 (H.264) or a GIF."""
    import imageio.v2 as imageio

    path = Path(path)
    tmp = path.with_name(path.stem + ".part" + path.suffix)
    if gif:
        writer = imageio.get_writer(tmp, mode="I", duration=1000.0 / fps, loop=0)
    else:
        writer = imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, macro_block_size=2, pixelformat="yuv420p")
    try:
        for im in images:
            writer.append_data(np.asarray(im))
    finally:
        writer.close()
    tmp.replace(path)  # a video that is there is complete
