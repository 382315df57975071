"""The run folder: the one place that knows its layout, names and run record.

```
RUN/particles/frame_00000.ply   particle frames          RUN/stats.jsonl  one record per step
RUN/mesh/frame_00000.obj        surface meshes           RUN/run.json     scene, device, totals, how it ended
RUN/obstacles.obj               static obstacles         RUN/checkpoint.npz  the state at the last checkpoint
RUN/preview.mp4, frames/, video.mp4, blender_scene.py: views
```
"""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import numpy as np

from .atomic import write_json

PARTICLES = "particles"
MESHES = "mesh"
FRAMES = "frames"  # rendered images (warp-iisph render)
STATS = "stats.jsonl"
RECORD = "run.json"
OBSTACLES = "obstacles.obj"
CHECKPOINT = "checkpoint.npz"  # the full state at the last frame it was taken, to resume from
SOURCE = "source.json"  # in a folder of derived files (mesh/, frames/): what they were made from
DEFAULT_FPS = 30.0
_FRAME_EXT = {PARTICLES: "ply", MESHES: "obj"}


class RunError(ValueError):
    """A run folder that cannot be used as asked (missing, no frames, bad selection, bad record)."""


def new_run_id() -> str:
    """A name for one run, which every file derived from it records."""
    return uuid.uuid4().hex


def frame_index(path: Path) -> int:
    return int(path.stem.split("_")[-1])


class RunFolder:
    """Paths of a run's files, its record, and its frames in order."""

    def __init__(self, path):
        self.path = Path(path)

    def __str__(self) -> str:
        return str(self.path)

    @classmethod
    def existing(cls, path) -> "RunFolder":
        """A run folder that must exist already (``RunError`` otherwise)."""
        run = cls(path)
        if not run.path.is_dir():
            raise RunError(f"{run.path}: no such run folder")
        return run

    # --- names -----------------------------------------------------------------------------

    def frame_path(self, kind: str, k: int) -> Path:
        """Frame ``k`` of ``kind`` (``particles`` or ``mesh``)."""
        return self.path / kind / f"frame_{k:05d}.{_FRAME_EXT[kind]}"

    def particle_frame(self, k: int) -> Path:
        return self.frame_path(PARTICLES, k)

    def mesh_frame(self, k: int) -> Path:
        return self.frame_path(MESHES, k)

    @property
    def stats(self) -> Path:
        return self.path / STATS

    @property
    def record_path(self) -> Path:
        return self.path / RECORD

    @property
    def obstacles(self) -> Path:
        return self.path / OBSTACLES

    @property
    def checkpoint(self) -> Path:
        return self.path / CHECKPOINT

    # --- contents --------------------------------------------------------------------------

    def frames(self, kind: str) -> list[Path]:
        """``particles/frame_*.ply`` or ``mesh/frame_*.obj``, in frame order (``RunError`` for none)."""
        ext = _FRAME_EXT[kind]
        files = sorted((self.path / kind).glob(f"frame_*.{ext}"))
        if not files:
            hint = "run with --mesh, or `warp-iisph mesh RUN_DIR`" if kind == MESHES else "was the run written with output.particles = false?"
            raise RunError(f"{self.path / kind}: no frame_*.{ext} files ({hint})")
        return files

    def record(self) -> dict:
        """``run.json`` (empty when the run wrote none)."""
        if not self.record_path.is_file():
            return {}
        try:
            return json.loads(self.record_path.read_text())
        except json.JSONDecodeError as e:
            raise RunError(f"{self.record_path}: not valid JSON ({e.msg}, line {e.lineno})") from None

    def write_record(self, record: dict) -> None:
        """Replace ``run.json`` atomically."""
        write_json(self.record_path, record)

    def provenance(self, folder: str) -> dict | None:
        """What the files in ``folder`` (``mesh``, ``frames``) were made from, or ``None``."""
        path = self.path / folder / SOURCE
        try:
            return json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            return None

    def write_provenance(self, folder: str, run_id: str | None, settings: dict) -> None:
        """Record that the files in ``folder`` come from run ``run_id`` made with ``settings``."""
        write_json(self.path / folder / SOURCE, {"run_id": run_id, "settings": settings})

    def fps(self, record: dict | None = None) -> float:
        """Frames per simulated second the run was written at."""
        record = self.record() if record is None else record
        return float(record.get("fps") or DEFAULT_FPS)

    def obstacle_mesh(self):
        """The run's obstacles as one ``trimesh.Trimesh``, or ``None`` when it has none."""
        if not self.obstacles.is_file():
            return None
        from .formats import read_mesh

        mesh = read_mesh(self.obstacles)
        return mesh if len(getattr(mesh, "faces", ())) else None


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
