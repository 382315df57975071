"""Surface meshes for a run: one OBJ per particle frame (``mesh/frame_00000.obj`` ...)."""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

from .io import read_particles, write_obj
from .scene import Surface
from .surface import SurfaceReconstructor

MESH_STAGES = ("distance_field", "marching_cubes", "smoothing", "export")


class FrameMesher:
    """Meshes frames of particles of spacing ``h`` and writes them; keeps per-stage seconds."""

    def __init__(self, h: float, params: Surface, device="cpu"):
        self.reconstructor = SurfaceReconstructor(h, params, device)
        self.seconds = dict.fromkeys(MESH_STAGES, 0.0)

    def mesh(self, positions):
        """The surface of ``positions`` (device work; adds its stage times)."""
        mesh = self.reconstructor.reconstruct(positions)
        for k, v in mesh.ms.items():
            self.seconds[k] += v / 1e3
        return mesh

    def export(self, mesh, path: Path) -> None:
        """Write ``mesh`` as OBJ (host work only, so it may run on a writer thread)."""
        t = time.perf_counter()
        write_obj(path, mesh.vertices, mesh.faces, mesh.normals)
        self.seconds["export"] += time.perf_counter() - t

    def write(self, positions, path: Path):
        mesh = self.mesh(positions)
        self.export(mesh, path)
        return mesh


def mesh_run(run_dir, overrides: dict | None = None, device="cpu", overwrite: bool = False, progress: bool = True) -> dict:
    """Mesh every ``particles/frame_*.ply`` of a run folder into ``mesh/frame_*.obj`` with the
    run's ``surface`` settings, changed by ``overrides`` (e.g. ``{"smoothing": "taubin"}``).
    Frames already meshed are kept unless ``overwrite``. Returns counts and seconds per stage."""
    run_dir = Path(run_dir)
    frames = sorted((run_dir / "particles").glob("frame_*.ply"))
    if not frames:
        raise ValueError(f"{run_dir}: no particles/frame_*.ply to mesh (was it run with output.particles = false?)")
    try:
        record = json.loads((run_dir / "run.json").read_text())
        h = float(record["scene"]["spacing"])
        stored = record["scene"].get("surface", {})
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{run_dir / 'run.json'}: cannot read the particle spacing ({e})") from None
    known = {f.name for f in dataclasses.fields(Surface)}
    params = Surface(**{k: v for k, v in {**stored, **(overrides or {})}.items() if k in known})
    params.validate()
    mesher = FrameMesher(h, params, device)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(frames), unit="frame", dynamic_ncols=True, file=sys.stderr)
    written = skipped = 0
    try:
        for f in frames:
            target = run_dir / "mesh" / f"{f.stem}.obj"
            if target.exists() and not overwrite:
                skipped += 1
            else:
                x = read_particles(f)["x"]
                try:
                    mesh = mesher.write(x, target)
                except ValueError as e:
                    raise ValueError(f"{f}: {e}") from None
                written += 1
                if bar:
                    bar.set_postfix_str(f"{len(x)} particles, {len(mesh.faces)} triangles")
            if bar:
                bar.update(1)
    finally:
        if bar:
            bar.close()
    result = {"frames": len(frames), "written": written, "skipped": skipped, "stage_seconds": mesher.seconds,
              "surface": dataclasses.asdict(params)}
    return result
