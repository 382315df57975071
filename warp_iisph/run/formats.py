"""File formats of a run: particle frames (PLY via meshio), meshes (OBJ or binary PLY), statistics (JSON lines), records.

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

from .obj_text import obj_bytes, obj_chunks


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
    _write_chunks(Path(path), obj_chunks(vertices, faces, normals))


def ply_bytes(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY: ``x y z [nx ny nz]`` float per vertex, a ``vertex_indices``
    list (uchar count 3, int indices) per face; read by Blender 4, meshio, trimesh, ParaView."""
    return b"".join(ply_chunks(vertices, faces, normals))


def ply_chunks(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> list:
    """:func:`ply_bytes` as its header, vertex table and face table, each packed by NumPy in
    one pass (no per-element Python) and not copied into one."""
    v = np.asarray(vertices, dtype="<f4").reshape(-1, 3)
    f = np.asarray(faces).reshape(-1, 3)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"face indices outside 0..{len(v) - 1}")
    head = ["ply", "format binary_little_endian 1.0", "comment warp_iisph surface", f"element vertex {len(v)}",
            "property float x", "property float y", "property float z"]
    if normals is not None:
        head += ["property float nx", "property float ny", "property float nz"]
        v = np.concatenate([v, np.asarray(normals, dtype="<f4").reshape(-1, 3)], axis=1)
    head += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    rows = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rows["n"] = 3
    rows["i"] = f
    return [("\n".join(head) + "\n").encode("ascii"), memoryview(np.ascontiguousarray(v)).cast("B"),
            memoryview(rows).cast("B")]


MESH_WRITERS = {"obj": obj_chunks, "ply": ply_chunks}


def write_mesh(path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None, fmt: str = "obj") -> Path:
    """Write a triangle mesh as ``fmt`` (``obj`` or ``ply``) at ``path`` with that suffix (it
    replaces the one given); returns the path written."""
    if fmt not in MESH_WRITERS:
        raise ValueError(f"mesh format {fmt!r}: must be one of {', '.join(MESH_WRITERS)}")
    path = Path(path).with_suffix(f".{fmt}")
    _write_chunks(path, MESH_WRITERS[fmt](vertices, faces, normals))
    return path


def _write_chunks(path: Path, chunks: list) -> None:
    def write(tmp):
        with open(tmp, "wb") as fh:
            for chunk in chunks:
                fh.write(chunk)

    _atomic_target(path, write)


def write_ply(path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Binary PLY mesh (see :func:`ply_bytes`)."""
    write_mesh(path, vertices, faces, normals, "ply")
