"""OBJ text formatted by a kernel: printf's ``%.6f`` / ``%.4f`` / ``%d`` digit by digit, one line per
thread, because Python's own formatting took as long as meshing the frame."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch_particles

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.func
def put_number(buf: wp.array(dtype=wp.uint8), start: int, width: int, value: wp.float64, decimals: int):
    """``value`` as printf's ``%{width}.{decimals}f`` (right-aligned, space-padded) at ``start``."""
    q = wp.int64(wp.round(wp.abs(value) * wp.pow(wp.float64(10.0), wp.float64(decimals))))
    p = start + width - 1
    for _ in range(decimals):
        buf[p] = wp.uint8(48 + int(q % wp.int64(10)))
        q = q // wp.int64(10)
        p -= 1
    if decimals > 0:
        buf[p] = wp.uint8(46)  # '.'
        p -= 1
    buf[p] = wp.uint8(48 + int(q % wp.int64(10)))  # at least one integer digit
    q = q // wp.int64(10)
    p -= 1
    while q > wp.int64(0):
        buf[p] = wp.uint8(48 + int(q % wp.int64(10)))
        q = q // wp.int64(10)
        p -= 1
    if value < wp.float64(0.0):
        buf[p] = wp.uint8(45)  # '-'
        p -= 1
    while p >= start:
        buf[p] = wp.uint8(32)
        p -= 1


@wp.func
def put_char(buf: wp.array(dtype=wp.uint8), p: int, c: int) -> int:
    buf[p] = wp.uint8(c)
    return p + 1


@wp.func
def digit_count(i: int) -> int:
    n = int(1)
    while i >= 10:
        i = i // 10
        n += 1
    return n


@wp.func
def put_int(buf: wp.array(dtype=wp.uint8), p: int, i: int, n: int) -> int:
    """The ``n`` digits of ``i`` at ``p``; returns the position after them."""
    q = i
    for k in range(n):
        buf[p + n - 1 - k] = wp.uint8(48 + q % 10)
        q = q // 10
    return p + n


@wp.kernel
def format_obj(
    offset: int,
    verts: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    faces: wp.array(dtype=wp.int32),
    has_normals: int,
    coord_width: int,
    index_width: int,
    line_len: wp.vec3i,
    buf: wp.array(dtype=wp.uint8),
):
    """Line ``wp.tid() + offset`` of the OBJ body: V ``v`` lines, then V ``vn`` lines (with
    normals), then F ``f`` lines; every line of a kind has one length (``line_len``: v, vn, f),
    so each thread knows where its line starts and writes it alone."""
    line = wp.tid() + offset
    nv = verts.shape[0]
    v_len = line_len[0]
    n_len = line_len[1]
    f_len = line_len[2]
    n_lines = nv * has_normals
    if line < nv:
        p = put_char(buf, line * v_len, 118)  # 'v'
        for c in range(3):
            p = put_char(buf, p, 32)
            put_number(buf, p, coord_width, wp.float64(verts[line][c]), 6)
            p += coord_width
        put_char(buf, p, 10)
    elif line < nv + n_lines:
        k = line - nv
        p = put_char(buf, nv * v_len + k * n_len, 118)
        p = put_char(buf, p, 110)  # 'vn'
        for c in range(3):
            p = put_char(buf, p, 32)
            put_number(buf, p, 7, wp.float64(normals[k][c]), 4)
            p += 7
        put_char(buf, p, 10)
    else:
        t = line - nv - n_lines
        p = put_char(buf, nv * v_len + n_lines * n_len + t * f_len, 102)  # 'f'
        for c in range(3):
            i = faces[3 * t + c] + 1
            n = digit_count(i)
            for _ in range((1 + has_normals) * (index_width - n) + 1):  # pad before the token
                p = put_char(buf, p, 32)
            p = put_int(buf, p, i, n)
            if has_normals:
                p = put_char(buf, p, 47)
                p = put_char(buf, p, 47)  # 'a//a': vertex and normal share an index
                p = put_int(buf, p, i, n)
        put_char(buf, p, 10)


def obj_bytes(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> bytes:
    """The OBJ text of a mesh: ``v`` as ``%.6f``, ``vn`` as ``%.4f``, ``f a//a b//b c//c``
    (1-based), formatted by a kernel on the CPU: Python's own formatting took about half a
    second per 200k-triangle frame, as long as meshing it."""
    return b"".join(obj_chunks(vertices, faces, normals))


NORMAL_LINE = 2 + 3 * (1 + 7) + 1  # bytes of a normal's line: 'vn' + 3 x ' %7.4f' + newline


def obj_chunks(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> list:
    """:func:`obj_bytes` as a list of byte buffers (the header and the kernel's text, not
    copied into one): write them one after the other."""
    v = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
    if not np.all(np.isfinite(v)):
        raise ValueError("mesh has non-finite vertex positions")
    header = f"# warp_iisph surface: {len(v)} vertices, {len(f)} triangles\n".encode()
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"mesh faces index vertices outside 0..{len(v) - 1}")
    big = float(np.abs(v).max()) if len(v) else 0.0
    coord_width = 1 + len(str(int(round(big * 1e6)) // 10**6)) + 1 + 6  # sign, integer digits, '.', decimals
    index_width = len(str(max(len(v), 1)))
    has_normals = normals is not None
    n_lines = len(v) * (2 if has_normals else 1) + len(f)
    # 'v' + 3 x (' ' + number) + newline; 'f' + 3 x (' ' + a or a//a) + newline
    v_len, n_len = 1 + 3 * (1 + coord_width) + 1, NORMAL_LINE
    f_len = 1 + 3 * (1 + (2 * index_width + 2 if has_normals else index_width)) + 1
    size = len(v) * (v_len + (n_len if has_normals else 0)) + len(f) * f_len
    cpu = wp.get_device("cpu")
    buf = wp.empty(size, dtype=wp.uint8, device=cpu)
    n = np.ascontiguousarray(normals if has_normals else np.zeros((0, 3)), dtype=np.float32).reshape(-1, 3)
    inputs = [
        wp.array(v, dtype=wp.vec3, device=cpu),
        wp.array(n, dtype=wp.vec3, device=cpu),
        wp.array(f.reshape(-1), dtype=wp.int32, device=cpu),
        int(has_normals),
        coord_width,
        index_width,
        wp.vec3i(v_len, n_len, f_len),
        buf,
    ]
    launch_particles(format_obj, n_lines, inputs, cpu)
    return [header, memoryview(buf.numpy())]
