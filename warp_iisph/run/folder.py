"""The run folder: the one place that knows its layout, names and run record.

```
RUN/particles/frame_00000.ply   particle frames (.vtu    RUN/stats.jsonl  one record per step
                                                         RUN/probes.csv   the probes' samples
                                with output.format vtu)  RUN/run.json     scene, device, totals, how it ended
RUN/mesh/frame_00000.obj        surface meshes (.ply     RUN/run.usdc     the whole run as one USD stage
                                with surface.format ply)
RUN/obstacles.obj               the obstacles (at t = 0; RUN/obstacles/frame_00000.obj ... when some move)
RUN/checkpoint.npz              the state at the last checkpoint
RUN/preview.mp4, frames/, video.mp4, blender_scene.py: views
```
"""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import numpy as np

# the extensions of particle frames and meshes, as output.format and surface.format name them
from ..scene.settings import MESH_FORMATS, PARTICLE_FORMATS
from .atomic import write_json

PARTICLES = "particles"
MESHES = "mesh"
FRAMES = "frames"  # rendered images (warp-iisph render)
STATS = "stats.jsonl"
PROBES = "probes.csv"  # the probes' samples (time, one column per probe)
RECORD = "run.json"
OBSTACLES = "obstacles.obj"
OBSTACLE_FRAMES = "obstacles"  # with moving obstacles: obstacles/frame_00000.obj, all of them at each frame
CHECKPOINT = "checkpoint.npz"  # the full state at the last frame it was taken, to resume from
SOURCE = "source.json"  # in a folder of derived files (mesh/, frames/): what they were made from
USD = "run.usdc"  # warp-iisph usd's default; a run.usda or run.usd is found too
USD_NAMES = (USD, "run.usda", "run.usd")
DEFAULT_FPS = 30.0


class RunError(ValueError):
    """A run folder that cannot be used as asked (missing, no frames, bad selection, bad record)."""


def new_run_id() -> str:
    """A name for one run, which every file derived from it records."""
    return uuid.uuid4().hex


def frame_index(path: Path) -> int:
    return int(path.stem.split("_")[-1])


class RunFolder:
    """Paths of a run's files, its record, and its frames in order."""

    def __init__(self, path, particle_format: str | None = None):
        """``particle_format`` (``ply``, ``vtu``) names the particle frames a run writes; left out,
        it is the run record's ``output.format``, else the format of the frames on disk, else PLY."""
        self.path = Path(path)
        if particle_format is not None and particle_format not in PARTICLE_FORMATS:
            raise RunError(f"particle format {particle_format!r}: must be one of {', '.join(PARTICLE_FORMATS)}")
        self._particle_format = particle_format

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

    @property
    def particle_format(self) -> str:
        """The extension of this run's particle frames (see the constructor)."""
        if self._particle_format is None:
            try:
                fmt = (self.record().get("output") or {}).get("format")
            except RunError:  # an unreadable run.json: the files on disk say
                fmt = None
            if fmt not in PARTICLE_FORMATS:
                on_disk = [e for e in PARTICLE_FORMATS if any((self.path / PARTICLES).glob(f"frame_*.{e}"))]
                fmt = on_disk[0] if on_disk else PARTICLE_FORMATS[0]
            self._particle_format = fmt
        return self._particle_format

    def frame_path(self, kind: str, k: int) -> Path:
        """Frame ``k`` of ``kind`` (``particles``, in the run's particle format, or ``mesh``, in
        the format of the meshes there)."""
        return self.path / kind / f"frame_{k:05d}.{self.particle_format if kind == PARTICLES else self.mesh_format}"

    def particle_frame(self, k: int) -> Path:
        return self.frame_path(PARTICLES, k)

    def mesh_frame(self, k: int) -> Path:
        return self.frame_path(MESHES, k)

    @property
    def mesh_format(self) -> str:
        """The extension of this run's meshes: what ``mesh/source.json`` records, else the
        run's ``surface.format``, else that of the meshes on disk, else OBJ."""
        made = (self.provenance(MESHES) or {}).get("settings") or {}
        fmt = made.get("format")
        if fmt not in MESH_FORMATS:
            try:
                fmt = ((self.record().get("scene") or {}).get("surface") or {}).get("format")
            except RunError:
                fmt = None
        if fmt not in MESH_FORMATS:
            on_disk = [e for e in MESH_FORMATS if any((self.path / MESHES).glob(f"frame_*.{e}"))]
            fmt = on_disk[0] if on_disk else MESH_FORMATS[0]
        return fmt

    def all_mesh_frames(self) -> list[Path]:
        """Every ``mesh/frame_*`` file of either mesh format (what an overwrite replaces)."""
        return sorted(p for e in MESH_FORMATS for p in (self.path / MESHES).glob(f"frame_*.{e}"))

    @property
    def stats(self) -> Path:
        return self.path / STATS

    @property
    def probes(self) -> Path:
        return self.path / PROBES

    @property
    def record_path(self) -> Path:
        return self.path / RECORD

    @property
    def obstacles(self) -> Path:
        return self.path / OBSTACLES

    @property
    def checkpoint(self) -> Path:
        return self.path / CHECKPOINT

    def usd_files(self) -> list[Path]:
        """The run's USD stages: ``run.usdc``, ``run.usda``, ``run.usd``, those that exist."""
        return [self.path / name for name in USD_NAMES if (self.path / name).is_file()]

    def usd_file(self) -> Path | None:
        """The run's USD stage (the first of :meth:`usd_files`), ``None`` when it has none."""
        return next(iter(self.usd_files()), None)

    # --- contents --------------------------------------------------------------------------

    def _frame_files(self, kind: str) -> list[Path]:
        if kind == MESHES:
            for ext in dict.fromkeys((self.mesh_format, *MESH_FORMATS)):
                files = sorted((self.path / kind).glob(f"frame_*.{ext}"))
                if files:
                    return files
            return []
        # the run's own format first; a folder of the other format (copied in, or an older run) is read too
        for ext in dict.fromkeys((self.particle_format, *PARTICLE_FORMATS)):
            files = sorted((self.path / kind).glob(f"frame_*.{ext}"))
            if files:
                return files
        return []

    def has_frames(self, kind: str) -> bool:
        """Whether the run holds any frame of ``kind``."""
        return bool(self._frame_files(kind))

    def frames(self, kind: str) -> list[Path]:
        """``particles/frame_*.ply`` (or ``.vtu``) or ``mesh/frame_*.obj`` (or ``.ply``), in frame order
        (``RunError`` for none)."""
        files = self._frame_files(kind)
        if not files:
            if kind == MESHES:
                raise RunError(
                    f"{self.path / kind}: no frame_*.{' or frame_*.'.join(MESH_FORMATS)} files "
                    f"(run with --mesh, or `warp-iisph mesh RUN_DIR`)"
                )
            raise RunError(
                f"{self.path / kind}: no frame_*.{' or frame_*.'.join(PARTICLE_FORMATS)} files "
                "(was the run written with output.particles = false?)"
            )
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

    def obstacle_frame(self, k: int) -> Path:
        """The obstacles at frame ``k`` (written when some of them move)."""
        return self.path / OBSTACLE_FRAMES / f"frame_{k:05d}.obj"

    @property
    def obstacles_move(self) -> bool:
        return (self.path / OBSTACLE_FRAMES).is_dir()

    def obstacle_mesh(self, frame: int | None = None):
        """The run's obstacles as one ``trimesh.Trimesh`` (at ``frame`` when they move), or
        ``None`` when it has none."""
        if frame is not None and self.obstacle_frame(frame).is_file():
            from .formats import read_mesh

            return read_mesh(self.obstacle_frame(frame))
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
        raise RunError(
            f"--frames {spec}: no frame in that range "
            f"(the run has frames {frame_index(files[0])}..{frame_index(files[-1])})"
        )
    return chosen


def tank_bounds(record: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The box tank's corners from a run record; ``None`` for a mesh tank or no record."""
    tank = record.get("scene", {}).get("tank", {})
    if "lower" in tank and "upper" in tank:
        return np.asarray(tank["lower"], float), np.asarray(tank["upper"], float)
    return None
