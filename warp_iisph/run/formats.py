"""File formats of a run: particle frames (PLY or VTU via meshio), meshes (OBJ or binary PLY),
statistics (JSON lines), records.

Every file is written to a temporary name in the same folder and renamed into place, so a frame
that exists is complete even if the run is interrupted.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import meshio
import numpy as np

from .atomic import atomic_write, flush_to_disk, jsonable
from .obj_text import NORMAL_LINE, obj_chunks


class FileFormatError(ValueError):
    """A file that cannot be read as what it should be; the message names the file."""


def write_particles(path, positions, velocities, densities, pressures, ids=None) -> None:
    """A particle frame in the format its suffix names: ``.ply``, a binary PLY point cloud with
    ``vx vy vz density pressure id`` vertex properties (meshio, ParaView and splashsurf read it), or
    ``.vtu``, a VTK unstructured grid with one vertex cell per particle and point data ``velocity``
    (one 3-vector field), ``density``, ``pressure`` and ``id``, which ParaView shows and colours
    with no filter."""
    path = Path(path)
    kind = path.suffix.lower().lstrip(".")
    if kind not in ("ply", "vtu"):
        raise FileFormatError(f"{path}: particle frames are .ply or .vtu")
    n = len(positions)
    v = np.asarray(velocities, dtype=np.float32).reshape(n, 3)
    scalars = {
        "density": np.asarray(densities, dtype=np.float32),
        "pressure": np.asarray(pressures, dtype=np.float32),
        "id": np.arange(n, dtype=np.int32) if ids is None else np.asarray(ids, dtype=np.int32),
    }
    points = np.asarray(positions, dtype=np.float32)
    if kind == "ply":
        velocity = {
            "vx": np.ascontiguousarray(v[:, 0]),
            "vy": np.ascontiguousarray(v[:, 1]),
            "vz": np.ascontiguousarray(v[:, 2]),
        }
        mesh = meshio.Mesh(points, [], point_data={**velocity, **scalars})
        atomic_write(path, lambda tmp: meshio.write(tmp, mesh, file_format="ply", binary=True))
    else:
        cells = [("vertex", np.arange(n, dtype=np.int64).reshape(n, 1))]
        mesh = meshio.Mesh(points, cells, point_data={"velocity": v, **scalars})
        # uncompressed: zlib halves the file but takes 6x as long (1.25 against 0.2 s for 200k particles)
        atomic_write(path, lambda tmp: meshio.write(tmp, mesh, file_format="vtu", binary=True, compression=None))


PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2}
PLY_SIZES.update({"int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8})


def cut_short(path) -> str | None:
    """Why the frame file ``path`` (as this package writes particle and mesh frames) is not whole,
    or ``None``: a binary PLY shorter or longer than its header's elements make it (a mesh's
    faces triangles), a VTU that does not end its XML, an OBJ whose last line is not the end of its
    last element or whose size is not what its counts make it. Reads the header and the last bytes
    only (a resume checks every frame); a file not of ours is not judged."""
    path = Path(path)
    kind = path.suffix.lower()
    try:
        size_on_disk = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(4096)
            f.seek(max(size_on_disk - 256, 0))
            tail = f.read()
    except OSError as e:
        return f"cannot be read ({e.strerror})"
    if kind == ".vtu":
        return None if tail.rstrip().endswith(b"</VTKFile>") else "its XML is cut off"
    if kind == ".obj":
        return _obj_cut_short(head, tail, size_on_disk)
    end = head.find(b"end_header\n")
    if not head.startswith(b"ply\n") or end < 0:
        return "no PLY header"
    size, count, row = end + len(b"end_header\n"), 0, 0
    for line in head[:end].decode("ascii", "replace").splitlines():
        words = line.split()
        if words[:1] == ["element"] and len(words) == 3:
            size, count, row = size + count * row, int(words[2]) if words[2].isdigit() else -1, 0
        elif words[:1] == ["property"] and len(words) == 3 and words[1] in PLY_SIZES:
            row += PLY_SIZES[words[1]]
        elif words[:2] == ["property", "list"] and words[2:4] == ["uchar", "int"]:
            row += 1 + 3 * PLY_SIZES["int"]  # our meshes' faces: triangles
        elif words[:1] == ["property"] or (words[:1] == ["format"] and "binary_little_endian" not in words):
            return None  # other lists, or ASCII: not ours, and not sized here
    size += count * row
    return None if count >= 0 and size_on_disk == size else f"{size_on_disk} bytes where its header makes {size}"


def _obj_cut_short(head: bytes, tail: bytes, size_on_disk: int) -> str | None:
    """:func:`cut_short` of an OBJ from :func:`write_obj`: its first line counts its vertices and
    triangles, its faces come last and every line ends; and since every line of a kind has one
    length (:func:`.obj_text.obj_chunks`), the file is its first line, V vertex lines (each as long
    as the second line), V normal lines where its faces say ``a//a`` (without faces: where its
    last line is one), and F face lines (each as long as the last), to the byte: a file cut at the
    end of a line is caught too (but for a mesh with no faces cut exactly before its normals)."""
    lines = head.split(b"\n", 2)
    first = lines[0].decode("ascii", "replace").split()
    ours = first[:3] == ["#", "warp_iisph", "surface:"] and len(first) >= 7
    if not (ours and first[3].isdigit() and first[5].isdigit()):
        return None
    if not tail.endswith(b"\n"):
        return "its last line is cut off"
    n_vertices, n_faces = int(first[3]), int(first[5])
    last = tail.rstrip(b"\n").rsplit(b"\n", 1)[-1]
    if n_faces > 0 and not last.startswith(b"f "):
        return "its faces are cut off"
    if n_vertices == 0 or len(lines) < 2:
        return None
    normals = b"//" in last if n_faces > 0 else last.startswith(b"vn ")
    v_len, f_len = len(lines[1]) + 1, len(last) + 1
    size = len(lines[0]) + 1 + n_vertices * (v_len + (NORMAL_LINE if normals else 0)) + n_faces * f_len
    return None if size_on_disk == size else f"{size_on_disk} bytes where its counts make {size}"


def read_points(path) -> "meshio.Mesh":
    """Any point file meshio reads (PLY, VTK, VTU, ...); ``FileFormatError`` naming the file and
    what is wrong, never meshio's own exit."""
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such file")
    try:
        with (
            contextlib.redirect_stdout(io.StringIO()),
            contextlib.redirect_stderr(io.StringIO()),
        ):  # meshio prints its complaints
            mesh = meshio.read(path)
    except SystemExit:  # meshio exits on some malformed headers
        raise FileFormatError(f"{path}: not a readable point file (malformed header)") from None
    except Exception as e:  # meshio and NumPy raise many kinds for a bad file
        if _empty_vtu(path):  # meshio writes a frame of no particles but cannot read it back
            return meshio.Mesh(np.zeros((0, 3), dtype=np.float32), [])
        raise FileFormatError(f"{path}: not a readable point file ({type(e).__name__}: {e})") from None
    points = np.asarray(mesh.points, dtype=np.float32)
    if points.ndim != 2 or points.shape[1] != 3:
        raise FileFormatError(f"{path}: holds no 3D points")
    return mesh


def _empty_vtu(path: Path) -> bool:
    """Whether ``path`` is a whole VTU file of pieces with no points (an emitter's frames before it
    starts)."""
    import xml.etree.ElementTree as ET

    if path.suffix.lower() != ".vtu":
        return False
    try:
        pieces = list(ET.parse(path).getroot().iter("Piece"))
    except (ET.ParseError, OSError):
        return False
    return bool(pieces) and all(p.get("NumberOfPoints") == "0" for p in pieces)


def read_mesh(path):
    """A triangle mesh file as a ``trimesh.Trimesh``, its vertices and faces in the file's order and
    its vertex normals the file's when it has them (``FileFormatError`` naming the file when it
    cannot be read, e.g. cut off mid-write by another program)."""
    import trimesh

    path = Path(path)
    try:
        mesh = trimesh.load(path, process=False, maintain_order=True)
        if not isinstance(mesh, trimesh.Trimesh):  # several parts, or none: one mesh of them all
            mesh = trimesh.load(path, process=False, force="mesh")
        faces = np.asarray(mesh.faces)
        vertices = np.asarray(mesh.vertices)
    except Exception as e:  # trimesh raises many kinds for a bad file
        raise FileFormatError(f"{path}: not a readable mesh ({type(e).__name__}: {e})") from None
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise FileFormatError(f"{path}: faces refer to missing vertices (cut off?)")
    return mesh


def read_particles(path) -> dict[str, np.ndarray]:
    """A particle frame: ``{"x": (N, 3), "v": (N, 3) or None, "density", "pressure", "id"}``; the
    fields a frame of another tool lacks are ``None`` (positions are enough to mesh it)."""
    mesh = read_points(path)
    pd = mesh.point_data
    x = np.asarray(mesh.points, dtype=np.float32)

    def field(name):
        v = pd.get(name)
        return (
            None if v is None else np.asarray(v).reshape(len(x), -1)[:, 0] if np.asarray(v).ndim > 1 else np.asarray(v)
        )

    if all(k in pd for k in ("vx", "vy", "vz")):
        v = np.stack([field("vx"), field("vy"), field("vz")], axis=1)
    else:
        vel = pd.get("velocity", pd.get("v"))
        v = None if vel is None or np.asarray(vel).shape != x.shape else np.asarray(vel)
    return {"x": x, "v": v, "density": field("density"), "pressure": field("pressure"), "id": field("id")}


class StatsWriter:
    """Appends one JSON object per step to ``stats.jsonl``; flushed at every frame. A run cut off
    mid-line (killed, disk full) leaves at most its last line incomplete: :func:`read_stats`
    skips it."""

    def __init__(self, path, keep: list[dict] | None = None):
        """A new ``stats.jsonl``, or with ``keep`` one holding those records (a resumed run's steps
        so far; replaced atomically) that the new records follow."""
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if keep is None:
            self._f = open(self.path, "w")
            return
        lines = "".join(json.dumps(r, default=jsonable) + "\n" for r in keep)
        atomic_write(self.path, lambda tmp: Path(tmp).write_text(lines))
        self._f = open(self.path, "a")

    def write(self, record: dict) -> None:
        self._f.write(json.dumps(record, default=jsonable) + "\n")

    def flush(self) -> None:
        flush_to_disk(self._f)

    def close(self) -> None:
        self._f.close()


def read_stats(path) -> list[dict]:
    """The records of a ``stats.jsonl``; an incomplete last line (a run cut off while writing
    it) is left out, any other bad line is a ``FileFormatError``."""
    path = Path(path)
    with open(path) as f:
        lines = f.read().split("\n")
    records = []
    for k, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as e:
            if k == len(lines) - 1:  # no newline after it: cut off mid-write
                break
            raise FileFormatError(f"{path}, line {k + 1}: not a JSON record ({e.msg})") from None
    return records


def write_obj(path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> None:
    """Wavefront OBJ (``v``, ``vn``, ``f a//a b//b c//c``, 1-based), as Blender's stop-motion-OBJ
    importer reads it (see :func:`obj_text.obj_bytes`)."""
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
    head = [
        "ply",
        "format binary_little_endian 1.0",
        "comment warp_iisph surface",
        f"element vertex {len(v)}",
        "property float x",
        "property float y",
        "property float z",
    ]
    if normals is not None:
        head += ["property float nx", "property float ny", "property float nz"]
        v = np.concatenate([v, np.asarray(normals, dtype="<f4").reshape(-1, 3)], axis=1)
    head += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    rows = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rows["n"] = 3
    rows["i"] = f
    return [  # byte views of the tables (a memoryview cast fails on an empty one)
        ("\n".join(head) + "\n").encode("ascii"),
        np.ascontiguousarray(v).reshape(-1).view(np.uint8),
        rows.view(np.uint8),
    ]


MESH_WRITERS = {"obj": obj_chunks, "ply": ply_chunks}


def write_mesh(
    path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None, fmt: str = "obj"
) -> Path:
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

    atomic_write(path, write)
