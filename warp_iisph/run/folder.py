"""The run folder: the one place that knows its layout, names and run record.

```
RUN/particles/frame_00000.ply   particle frames (.vtu    RUN/stats.jsonl  one record per step
                                                         RUN/probes.csv   the probes' samples
                                with output.format vtu)  RUN/run.json     scene, device, totals, how it ended
RUN/mesh/frame_00000.obj        surface meshes (.ply     RUN/run.usdc     the whole run as one USD stage
                                with surface.format ply)
RUN/obstacles.obj               the obstacles and bodies (at t = 0; RUN/obstacles/frame_00000.obj ... when some move)
RUN/bodies.csv                  the free bodies' poses and motion, one row per frame
RUN/checkpoint.npz              the state at the last checkpoint
RUN/preview.mp4, frames/, video.mp4, blender_scene.py: views
```
"""

from __future__ import annotations

import json
import os
import re
import uuid
from pathlib import Path

import numpy as np

# the extensions of particle frames and meshes, as output.format and surface.format name them
from ..scene.checks import box_corners, positive
from ..scene.settings import MESH_FORMATS, PARTICLE_FORMATS
from .atomic import write_json

PARTICLES = "particles"
MESHES = "mesh"
FRAMES = "frames"  # rendered images (warp-iisph render)
STATS = "stats.jsonl"
PROBES = "probes.csv"  # the probes' samples (time, one column per probe)
PROBES_CHART = "probes.png"  # warp-iisph plot's default: every probe over time
RECORD = "run.json"
OBSTACLES = "obstacles.obj"
OBSTACLE_FRAMES = "obstacles"  # with moving obstacles or bodies: obstacles/frame_00000.obj, all of them at each frame
BODIES = "bodies.csv"  # with free bodies: their poses at each frame
CHECKPOINT = "checkpoint.npz"  # the full state at the last frame it was taken, to resume from
SOURCE = "source.json"  # in a folder of derived files (mesh/, frames/): what they were made from
USD = "run.usdc"  # warp-iisph usd's default; a run.usda or run.usd is found too
USD_NAMES = (USD, "run.usda", "run.usd")
# the views a run folder holds by default, each made of all its frames or samples (a resume that
# makes frames and samples again leaves them stale)
VIEW_FILES = ("video.mp4", "video.gif", "preview.mp4", "preview.gif", PROBES_CHART, *USD_NAMES)
DATA_FOLDERS = (PARTICLES, MESHES, FRAMES, OBSTACLE_FRAMES)
DEFAULT_FPS = 30.0
MAX_FPS = 10_000.0  # output.fps's limit, and a video's


# parts of a run record that the commands read, and their kinds
RECORD_TABLES = ("scene", "output", "totals", "particles", "versions")
RECORD_TEXTS = ("run_id", "device", "ended")
SCENE_TABLES = ("tank", "camera", "surface", "physics", "output")
SCENE_LISTS = ("fluids", "obstacles", "emitters", "sinks", "bodies")


class RunError(ValueError):
    """A run folder that cannot be used as asked (missing, no frames, bad selection, bad record)."""


def new_run_id() -> str:
    """A name for one run, which every file derived from it records."""
    return uuid.uuid4().hex


# a frame's file name: frame_ and its number, five digits or more (frame_00001.ply); other files
# beside them (frame_00001 copy.ply, frame_1.ply) are not frames
FRAME_NAME = re.compile(r"frame_(\d{5,})")


def frame_index(path: Path) -> int:
    return int(path.stem.split("_")[-1])


def is_frame(path: Path) -> bool:
    """Whether ``path`` is named as a frame: ``frame_NNNNN`` and its suffix, nothing else."""
    m = FRAME_NAME.fullmatch(Path(path).stem)
    return m is not None and m.group(1) == f"{int(m.group(1)):05d}"


def frame_files(folder: Path, ext: str) -> list[Path]:
    """The frames ``frame_NNNNN.ext`` in ``folder``, in frame order."""
    files = [p for p in Path(folder).glob(f"frame_*.{ext}") if is_frame(p) and p.suffix == f".{ext}" and p.is_file()]
    return sorted(files, key=frame_index)


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
        if run.path.exists() and not run.path.is_dir():
            raise RunError(f"{run.path}: a file, not a run folder (give the folder a run wrote)")
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
                on_disk = [e for e in PARTICLE_FORMATS if frame_files(self.path / PARTICLES, e)]
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
            on_disk = [e for e in MESH_FORMATS if frame_files(self.path / MESHES, e)]
            fmt = on_disk[0] if on_disk else MESH_FORMATS[0]
        return fmt

    def all_mesh_frames(self) -> list[Path]:
        """Every ``mesh/frame_*`` file of either mesh format (what an overwrite replaces)."""
        return [p for e in MESH_FORMATS for p in frame_files(self.path / MESHES, e)]

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
    def bodies(self) -> Path:
        return self.path / BODIES

    @property
    def checkpoint(self) -> Path:
        return self.path / CHECKPOINT

    def temporary_files(self) -> list[Path]:
        """Files a writer staged beside their place and never renamed in (a killed run's)."""
        folders = (self.path, self.path / PARTICLES, self.path / MESHES, self.path / OBSTACLE_FRAMES)
        return [p for d in folders for p in d.glob(".*.tmp*") if p.is_file()]

    def holds_as_its_own(self, path) -> bool:
        """Whether ``path`` is one of the run's own files (its record, step records, checkpoint,
        obstacles) or lies in a folder of its frames: what a view's --out must never replace."""
        root, target = Path(os.path.realpath(self.path)), Path(os.path.realpath(path))
        if target.parent == root and target.name in (RECORD, STATS, CHECKPOINT, OBSTACLES, BODIES):
            return True
        return any(root / d == target or root / d in target.parents for d in DATA_FOLDERS)

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
                files = frame_files(self.path / kind, ext)
                if files:
                    return files
            return []
        # the run's own format first; a folder of the other format (copied in, or an older run) is read too
        for ext in dict.fromkeys((self.particle_format, *PARTICLE_FORMATS)):
            files = frame_files(self.path / kind, ext)
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
            record = json.loads(self.record_path.read_text())
        except json.JSONDecodeError as e:
            raise RunError(f"{self.record_path}: not valid JSON ({e.msg}, line {e.lineno})") from None
        except (OSError, UnicodeDecodeError) as e:
            raise RunError(f"{self.record_path}: cannot be read ({e})") from None
        if not isinstance(record, dict):
            raise RunError(f"{self.record_path}: not a run record (a JSON object), but {type(record).__name__}")
        self._check_record(record)
        return record

    def _check_record(self, record: dict) -> None:
        """``RunError`` naming the key when a part of the record the commands read is of the
        wrong kind (a record edited by hand, or not written by warp-iisph)."""
        scene = record.get("scene", {})
        parts = [(k, record.get(k), dict) for k in RECORD_TABLES] + [(k, record.get(k), str) for k in RECORD_TEXTS]
        if isinstance(scene, dict):
            parts += [(f"scene.{k}", scene.get(k), dict) for k in SCENE_TABLES]
            parts += [(f"scene.{k}", scene.get(k), list) for k in SCENE_LISTS]
        for key, value, kind in parts:
            if value is not None and not isinstance(value, kind):
                what = {dict: "a table (a JSON object)", str: "a string", list: "a list"}[kind]
                raise RunError(f"{self.record_path}: {key} = {value!r:.80}: must be {what}")

    def spacing(self, record: dict | None = None) -> float | None:
        """The run's particle spacing (``None`` when the record has none)."""
        record = self.record() if record is None else record
        h = (record.get("scene") or {}).get("spacing")
        if h is None:
            return None
        try:
            return positive(h, "scene.spacing", "metres")
        except ValueError as e:
            raise RunError(f"{self.record_path}: {e}") from None

    def is_run(self) -> bool:
        """Whether the folder holds a run of warp-iisph: its ``run.json`` is one's record (a run id
        and the versions it was made with). Only such a folder may be replaced by another run."""
        try:
            record = self.record()
        except RunError:
            return False
        versions = record.get("versions")
        return isinstance(record.get("run_id"), str) and isinstance(versions, dict) and "warp_iisph" in versions

    def write_record(self, record: dict) -> None:
        """Replace ``run.json`` atomically."""
        write_json(self.record_path, record)

    def provenance(self, folder: str) -> dict | None:
        """What the files in ``folder`` (``mesh``, ``frames``) were made from, or ``None``."""
        path = self.path / folder / SOURCE
        try:
            made = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            return None
        return made if isinstance(made, dict) else None

    def write_provenance(self, folder: str, run_id: str | None, settings: dict) -> None:
        """Record that the files in ``folder`` come from run ``run_id`` made with ``settings``."""
        write_json(self.path / folder / SOURCE, {"run_id": run_id, "settings": settings})

    def fps(self, record: dict | None = None) -> float:
        """Frames per simulated second the run was written at (``RunError`` for a record whose
        ``fps`` is not a number in (0, 10000])."""
        record = self.record() if record is None else record
        fps = record.get("fps")
        fps = DEFAULT_FPS if fps is None else fps
        if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not 0.0 < fps <= MAX_FPS:
            raise RunError(f"{self.record_path}: fps = {fps!r}: must be a number in (0, {MAX_FPS:g}]")
        return float(fps)

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


def enclosing_run(path) -> Path | None:
    """The run folder that ``path`` lies in (or is), if any."""
    p = Path(os.path.realpath(path))
    for folder in (p, *p.parents):
        if (folder / RECORD).is_file() and RunFolder(folder).is_run():
            return folder
    return None


def run_around(path) -> Path | None:
    """The run folder that ``path`` lies inside, other than ``path`` itself (links resolved): where
    a new run or sweep must not go, as it would bar that run's ``--overwrite``."""
    return enclosing_run(Path(os.path.realpath(path)).parent)


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


def tank_bounds(record: dict, source=RECORD) -> tuple[np.ndarray, np.ndarray] | None:
    """The box tank's corners from a run record (``source``: its file, for messages); ``None``
    for a mesh tank or no record."""
    tank = (record.get("scene") or {}).get("tank") or {}
    if "lower" in tank and "upper" in tank:
        try:
            lo, hi = box_corners(tank["lower"], tank["upper"], "scene.tank")
        except ValueError as e:
            raise RunError(f"{source}: {e}") from None
        return np.asarray(lo, float), np.asarray(hi, float)
    return None
