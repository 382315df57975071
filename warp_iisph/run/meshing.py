"""Surface meshes for a run's frames: one OBJ (or binary PLY, ``surface.format``) per particle frame
(``mesh/frame_00000.obj`` ...)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..engine.timing import StageTimes
from ..scene import SurfaceSettings
from ..surface import SurfaceMesh, SurfaceReconstructor
from .folder import PARTICLES, RunError, RunFolder, frame_index
from .formats import read_particles, write_mesh
from .progress import frame_bar

MESH_STAGES = ("distance_field", "marching_cubes", "smoothing", "export")


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


def mesh_run(run_dir, overrides: dict | None = None, device="cpu", overwrite: bool = False, progress: bool = True) -> dict:
    """Mesh every ``particles/frame_*.ply`` of a run folder into ``mesh/frame_*.obj`` (``.ply``
    with ``{"format": "ply"}``) with the
    run's ``surface`` settings, changed by ``overrides`` (e.g. ``{"smoothing": "taubin"}``).
    Frames already meshed are kept unless ``overwrite``. Returns counts and seconds per stage."""
    run = RunFolder.existing(run_dir)
    frames = run.frames(PARTICLES)
    record = run.record()
    try:
        h = float(record["scene"]["spacing"])
        stored = record["scene"].get("surface", {})
    except (ValueError, KeyError, TypeError) as e:
        raise RunError(f"{run.record_path}: cannot read the particle spacing ({e})") from None
    known = {f.name for f in dataclasses.fields(SurfaceSettings)}
    params = SurfaceSettings(**{k: v for k, v in {**stored, **(overrides or {})}.items() if k in known})
    params.validate()
    mesher = FrameMesher(h, params, device)
    bar = frame_bar(len(frames), progress)
    written = skipped = 0
    try:
        for f in frames:
            target = mesher.target(run.mesh_frame(frame_index(f)))
            if target.exists() and not overwrite:
                skipped += 1
            else:
                x = read_particles(f)["x"]
                try:
                    mesh = mesher.write(x, target)
                except ValueError as e:
                    raise RunError(f"{f}: {e}") from None
                written += 1
                bar.set_postfix_str(f"{len(x)} particles, {len(mesh.faces)} triangles")
            bar.update(1)
    finally:
        bar.close()
    return {"frames": len(frames), "written": written, "skipped": skipped, "stage_seconds": mesher.times.seconds,
            "surface": dataclasses.asdict(params)}
