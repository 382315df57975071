"""Surface meshes of particle frames, one OBJ (or binary PLY, ``surface.format``) per frame: a
run's (``mesh/frame_00000.obj`` ...), or any particle files."""

from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path

from ..engine import signals
from ..engine.timing import StageTimes
from ..scene import SurfaceSettings
from ..scene.checks import positive
from ..scene.settings import MESH_FORMATS
from ..surface import SurfaceMesh, SurfaceReconstructor
from .atomic import write_json
from .folder import MESHES, PARTICLES, RECORD, SOURCE, RunError, RunFolder, enclosing_run, frame_files, frame_index
from .formats import read_particles, write_mesh
from .lock import LOCK_NAME, FolderLock
from .progress import frame_bar
from .replace import Target, commit, discard, recover, stage

MESH_STAGES = ("distance_field", "marching_cubes", "smoothing", "export")
# what meshio reads as points, for a folder of another tool's particle files
POINT_SUFFIXES = (".ply", ".vtk", ".vtu", ".vtp")


class FrameMesher:
    """Meshes frames of particles of spacing ``h`` and writes them; keeps seconds per stage."""

    def __init__(self, h: float, params: SurfaceSettings, device="cpu"):
        self.reconstructor = SurfaceReconstructor(h, params, device)
        self.format = self.reconstructor.params.format
        self.times = StageTimes(None, MESH_STAGES)

    def mesh(self, positions) -> SurfaceMesh:
        """The surface of ``positions`` (device work; adds its stage times)."""
        mesh = self.reconstructor.reconstruct(positions)
        self.times.merge(mesh.seconds)
        return mesh

    def target(self, path: Path) -> Path:
        """``path`` with the suffix of this mesher's format."""
        return Path(path).with_suffix(f".{self.format}")

    def export(self, mesh: SurfaceMesh, path: Path) -> Path:
        """Write ``mesh`` in the settings' format at ``path`` (its suffix made ``.obj`` or
        ``.ply``); host work only, so it may run on a writer thread. Returns the path written."""
        with self.times("export"):
            return write_mesh(path, mesh.vertices, mesh.faces, mesh.normals, self.format)

    def write(self, positions, path: Path) -> SurfaceMesh:
        """Mesh ``positions`` and write the mesh at ``path`` (suffix per the format)."""
        mesh = self.mesh(positions)
        self.export(mesh, path)
        return mesh


BLENDER_SCRIPT = "blender_scene.py"  # warp-iisph blender-script's file in the run folder


def mesh_settings(params: SurfaceSettings, spacing: float) -> dict:
    """What a set of meshes was made with, as recorded beside them."""
    return {**dataclasses.asdict(params), "spacing": float(spacing)}


def recorded_mesh_settings(made: dict | None, spacing: float) -> dict:
    """The settings a folder's source.json records, a key an older version did not record read as
    its default (the resume's check and ``mesh``'s read them alike)."""
    return {**mesh_settings(SurfaceSettings(), spacing), **((made or {}).get("settings") or {})}


def same_meshes(made: dict | None, run_id, settings: dict) -> bool:
    """Whether meshes recorded as ``made`` come from run ``run_id`` with ``settings``."""
    if made is None or made.get("run_id") != run_id:
        return False
    return recorded_mesh_settings(made, settings["spacing"]) == settings


def _settings(stored: dict, overrides: dict | None) -> SurfaceSettings:
    """The surface settings: a run's, changed by the command's options (named as options)."""
    known = {f.name for f in dataclasses.fields(SurfaceSettings)}
    try:
        params = SurfaceSettings(**{k: v for k, v in {**stored, **(overrides or {})}.items() if k in known})
        return params.validate()
    except ValueError as e:
        text = str(e)
        for key in overrides or {}:
            text = text.replace(f"surface.{key} ", f"--{key} ")
        raise RunError(text) from None


def _mesher(spacing, params: SurfaceSettings, device) -> FrameMesher:
    """The mesher, after its spacing is checked (what it is made with is valid before any file changes)."""
    spacing = positive(spacing, "--spacing", "metres")
    try:
        return FrameMesher(spacing, params, device)
    except ValueError as e:
        raise RunError(str(e)) from None


def _mesh_run(run: RunFolder, overrides, spacing, overwrite: bool, device, progress: bool) -> dict:
    """A run folder's frames meshed into ``mesh/``, after checking that the meshes already there
    were made from this run with these settings. With ``overwrite`` the new meshes are written
    beside the old ones and take their place (and the USD stage made of them goes) once every
    frame is meshed: settings refused, or a frame that fails, leave the old ones as they were."""
    record = run.record()
    frames = run.frames(PARTICLES)
    scene = record.get("scene") or {}
    if spacing is None:
        spacing = run.spacing(record)
        if spacing is None:
            raise RunError(f"{run.record_path}: has no particle spacing; pass --spacing")
    stored = scene.get("surface") or {}
    params = _settings(stored, overrides)
    mesher = _mesher(spacing, params, device)
    settings = mesh_settings(params, mesher.reconstructor.h)
    made = run.provenance(MESHES)
    folder = run.path / MESHES
    recover(folder)  # a swap of meshes that a killed process began
    meshes = run.frames(MESHES) if run.has_frames(MESHES) else []
    existing = bool(meshes)
    old_format = meshes[0].suffix.lower().lstrip(".") if existing else None
    if overwrite and existing:  # the new meshes replace the folder: a mesh with no particles to remake it from would go
        sources = {frame_index(f) for f in frames}
        orphan = next((m for m in meshes if frame_index(m) not in sources), None)
        if orphan is not None:
            raise RunError(
                f"{orphan}: its particle frame is missing, so --overwrite would delete a mesh it cannot make "
                "again; move it out first"
            )
    if existing and not overwrite and not same_meshes(made, record.get("run_id"), settings):
        what = "another run" if made and made.get("run_id") != record.get("run_id") else "other settings"
        raise RunError(f"{folder}: holds meshes made from {what}; pass --overwrite to replace them")
    if not (overwrite and folder.exists()):
        run.write_provenance(MESHES, record.get("run_id"), settings)
        jobs = [(f, run.mesh_frame(frame_index(f))) for f in frames]
        result = _mesh_jobs(jobs, mesher, overwrite, progress, folder)
        for old in _made_of_meshes(run, old_format, settings) if overwrite else []:  # nothing outlives its meshes
            old.unlink(missing_ok=True)
        return result
    target = Target(folder, folder, True, None)
    new, lock = stage(target, "mesh")
    try:
        write_json(new / SOURCE, {"run_id": record.get("run_id"), "settings": settings})
        jobs = [(f, new / run.mesh_frame(frame_index(f)).name) for f in frames]
        result = _mesh_jobs(jobs, mesher, True, progress, folder)
        with signals.held():  # the meshes and what was made of them change together
            _carry_foreign_files(folder, new)
            stale = _made_of_meshes(run, old_format, settings)  # a stage (and a script) made of the old meshes
            commit(target, new, lock)
            for old in stale:
                old.unlink(missing_ok=True)
    except BaseException:
        if new.exists():
            discard(new, lock)
        raise
    lock.release()
    return result


def _made_of_meshes(run: RunFolder, old_format: str | None, settings: dict) -> list[Path]:
    """What new meshes leave stale in the run folder: its USD stage (it holds the meshes), and the
    Blender script when the meshes change format (``old_format``: the suffix of those there; the
    script names their files)."""
    stale = run.usd_files()
    script = run.path / BLENDER_SCRIPT
    if script.is_file() and old_format is not None and old_format != settings.get("format"):
        stale.append(script)
    return stale


def _carry_foreign_files(folder: Path, new: Path) -> None:
    """Files in the meshes' folder that are not meshes (the user's) linked into the new one, so
    the swap keeps them (a link, not a move: a swap rolled back leaves them where they were);
    a folder there refuses the overwrite."""
    ours = {p.name for p in new.iterdir()} | {SOURCE, LOCK_NAME}
    meshes = {p.name for e in MESH_FORMATS for p in frame_files(folder, e)}
    for p in folder.iterdir():
        if p.name in ours or p.name in meshes or (p.name.startswith(".") and ".tmp" in p.name):
            continue
        if p.is_dir() and not p.is_symlink():
            raise RunError(f"{folder}: holds {p.name}/, not a mesh, which --overwrite would delete; move it first")
        try:
            os.link(p, new / p.name, follow_symlinks=False)
        except OSError:  # a file system without hard links
            shutil.copy2(p, new / p.name, follow_symlinks=False)


def _jobs_of_files(path: Path, overrides, spacing, out):
    """Another tool's particle file, or a folder of them: meshes beside them (or in ``out``)."""
    if spacing is None:
        raise RunError(f"{path}: not a warp-iisph run (no {RECORD}); pass --spacing, the particle spacing in metres")
    spacing = positive(spacing, "--spacing", "metres")
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in POINT_SUFFIXES and p.is_file())
        if not files:
            raise RunError(f"{path}: no particle files ({', '.join(POINT_SUFFIXES)})")
        target = Path(out) if out else path / MESHES
    else:
        files = [path]
        target = Path(out) if out else path.parent
    if target.exists() and not target.is_dir():
        raise RunError(f"--out {target}: is a file, not a folder")
    run = enclosing_run(target)
    if run is not None:  # meshes of other files would mix with a run's own, unrecorded
        raise RunError(f"{target}: lies in the run {run}; mesh the run itself (warp-iisph mesh {run}) or choose --out")
    return [(f, target / f"{f.stem}.obj") for f in files], spacing, _settings({}, overrides), target


def _check_targets(jobs, mesher: FrameMesher) -> None:
    """``RunError`` when a mesh would be written over a particle file being meshed (a mesh's name
    is its input's with the mesh format's suffix: ``a.ply`` meshed as PLY beside itself), or two
    inputs would be meshed into one file (``a.ply`` and ``a.vtu`` into ``a.obj``)."""
    inputs = {f.resolve(): f for f, _ in jobs}
    made = {}
    for source, mesh_file in jobs:
        target = mesher.target(mesh_file)
        key = target.resolve()
        if key in inputs:
            raise RunError(
                f"{target}: the mesh of {source.name} would be written over {inputs[key].name}, a particle file "
                "being meshed; choose another --out or --format"
            )
        if key in made:
            raise RunError(
                f"{target}: {made[key].name} and {source.name} would both be meshed into it; "
                "mesh them into separate folders (--out)"
            )
        made[key] = source


def _mesh_jobs(jobs, mesher: FrameMesher, overwrite: bool, progress: bool, out: Path) -> dict:
    """Mesh each (particle file, mesh file) pair, skipping meshes already there unless ``overwrite``."""
    bar = frame_bar(len(jobs), progress)
    written = skipped = 0
    try:
        for source, mesh_file in jobs:
            mesh_file = mesher.target(mesh_file)
            if mesh_file.exists() and not overwrite:
                skipped += 1
            else:
                x = read_particles(source)["x"]
                try:
                    mesh = mesher.write(x, mesh_file)
                except ValueError as e:
                    raise RunError(f"{source}: {e}") from None
                written += 1
                bar.set_postfix_str(f"{len(x)} particles, {len(mesh.faces)} triangles")
            bar.update(1)
    finally:
        bar.close()
    return {
        "frames": len(jobs),
        "written": written,
        "skipped": skipped,
        "stage_seconds": mesher.times.seconds,
        "surface": dataclasses.asdict(mesher.reconstructor.params),
        "out": out,
    }


def mesh_path(
    path,
    overrides: dict | None = None,
    device="cpu",
    overwrite: bool = False,
    progress: bool = True,
    spacing: float | None = None,
    out=None,
) -> dict:
    """Mesh a run folder's ``particles/frame_*.ply`` (or ``.vtu``) into ``mesh/frame_*.obj`` with the run's
    ``surface`` settings changed by ``overrides`` (e.g. ``{"smoothing": "taubin"}``), or any
    particle file (or folder of them) meshio reads, with ``spacing``. Meshes already there are kept
    unless ``overwrite``; a run's meshes made from other settings are refused. Every setting is
    checked before a file changes, and the folder written into is locked (one writer). Returns
    counts, seconds per stage, where the meshes went and whether they are a run's (``run``: their
    settings recorded and checked)."""
    path = Path(path)
    if not path.exists():
        raise RunError(f"{path}: no such run folder or particle file")
    if path.is_dir() and ((path / RECORD).is_file() or (path / PARTICLES).is_dir()):
        if out is not None:
            raise RunError(f"--out {out}: a run's meshes go into {path / MESHES}; --out is for particle files")
        run = RunFolder(path)
        with FolderLock(run.path):
            return {**_mesh_run(run, overrides, spacing, overwrite, device, progress), "run": True}
    jobs, spacing, params, target = _jobs_of_files(path, overrides, spacing, out)
    mesher = _mesher(spacing, params, device)
    _check_targets(jobs, mesher)
    target.mkdir(parents=True, exist_ok=True)
    with FolderLock(target, "folder"):
        return {**_mesh_jobs(jobs, mesher, overwrite, progress, target), "run": False}
