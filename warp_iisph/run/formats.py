"""File formats of a run: particle frames (PLY via meshio), meshes (OBJ), statistics (JSON lines), records.

Every file is written to a temporary name in the same folder and renamed into place, so a frame
that exists is complete even if the run is interrupted.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import meshio
import numpy as np

from .obj_text import obj_bytes


def _atomic_target(path: Path, write) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def write_particles(path, positions, velocities, densities, pressures, ids=None) -> None:
    """Binary PLY point cloud with ``vx vy vz density pressure id`` vertex properties,
    readable by meshio, ParaView and splashsurf."""
    path = Path(path)
    n = len(positions)
    data = {
        "vx": np.ascontiguousarray(velocities[:, 0], dtype=np.float32),
        "vy": np.ascontiguousarray(velocities[:, 1], dtype=np.float32),
        "vz": np.ascontiguousarray(velocities[:, 2], dtype=np.float32),
        "density": np.asarray(densities, dtype=np.float32),
        "pressure": np.asarray(pressures, dtype=np.float32),
        "id": np.arange(n, dtype=np.int32) if ids is None else np.asarray(ids, dtype=np.int32),
    }
    mesh = meshio.Mesh(np.asarray(positions, dtype=np.float32), [], point_data=data)
    _atomic_target(path, lambda tmp: meshio.write(tmp, mesh, file_format="ply", binary=True))


def read_particles(path) -> dict[str, np.ndarray]:
    """Inverse of :func:`write_particles`: ``{"x": (N, 3), "v": (N, 3), "density", "pressure", "id"}``."""
    mesh = meshio.read(path, file_format="ply")
    pd = mesh.point_data
    return {
        "x": np.asarray(mesh.points, dtype=np.float32),
        "v": np.stack([pd["vx"], pd["vy"], pd["vz"]], axis=1),
        "density": np.asarray(pd["density"]),
        "pressure": np.asarray(pd["pressure"]),
        "id": np.asarray(pd["id"]),
    }


def write_json(path, obj) -> None:
    path = Path(path)

    def write(tmp):
        with open(tmp, "w") as f:
            json.dump(obj, f, indent=2, default=_jsonable)
            f.write("\n")

    _atomic_target(path, write)


def _jsonable(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


class StatsWriter:
    """Appends one JSON object per step to ``stats.jsonl``; flushed at every frame."""

    def __init__(self, path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "w")

    def write(self, record: dict) -> None:
        self._f.write(json.dumps(record, default=_jsonable) + "\n")

    def flush(self) -> None:
        self._f.flush()

    def close(self) -> None:
        self._f.close()


def read_stats(path) -> list[dict]:
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def write_obj(path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Wavefront OBJ (``v``, ``vn``, ``f a//a b//b c//c``, 1-based), as Blender's stop-motion-OBJ
    importer reads it (see :func:`obj_bytes`)."""
    data = obj_bytes(vertices, faces, normals)

    def write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(data)

    _atomic_target(Path(path), write)
