"""Moving obstacles on the device: each step, their boundary particles are placed by their keyframed
rigid motion at the step's start and given the velocity that carries them to where they are at its
end (so the fluid sees exactly the displacement the wall makes during the step).

The keyframes are those of :class:`warp_iisph.scene.motion.Motion` (interpolated here by the same
formulas as its NumPy ``at``); the time is read from the device, so a graph replays moving walls
without the host.
"""

from __future__ import annotations

import numpy as np
import warp as wp


@wp.struct
class BodyKeys:
    """Keyframes of every moving body, flattened: body b's keys are ``first[b] .. first[b+1]-1``."""

    first: wp.array(dtype=wp.int32)
    smooth: wp.array(dtype=wp.int32)
    pivot: wp.array(dtype=wp.vec3)
    times: wp.array(dtype=wp.float64)
    translate: wp.array(dtype=wp.vec3)
    rotate: wp.array(dtype=wp.vec3)  # degrees about x, then y, then z
    slope_translate: wp.array(dtype=wp.vec3)
    slope_rotate: wp.array(dtype=wp.vec3)


@wp.func
def hermite(a: wp.vec3, ma: wp.vec3, b: wp.vec3, mb: wp.vec3, s: float, dt: float, smooth: int) -> wp.vec3:
    if smooth == 0:
        return a + s * (b - a)
    s2 = s * s
    s3 = s2 * s
    return (
        (2.0 * s3 - 3.0 * s2 + 1.0) * a
        + (s3 - 2.0 * s2 + s) * dt * ma
        + (-2.0 * s3 + 3.0 * s2) * b
        + (s3 - s2) * dt * mb
    )


@wp.func
def rotation_xyz(deg: wp.vec3) -> wp.mat33:
    """``Rz Ry Rx`` for angles in degrees (as scene.motion.rotation_xyz)."""
    r = deg * (wp.pi / 180.0)
    cx = wp.cos(r[0])
    sx = wp.sin(r[0])
    cy = wp.cos(r[1])
    sy = wp.sin(r[1])
    cz = wp.cos(r[2])
    sz = wp.sin(r[2])
    rx = wp.mat33(1.0, 0.0, 0.0, 0.0, cx, -sx, 0.0, sx, cx)
    ry = wp.mat33(cy, 0.0, sy, 0.0, 1.0, 0.0, -sy, 0.0, cy)
    rz = wp.mat33(cz, -sz, 0.0, sz, cz, 0.0, 0.0, 0.0, 1.0)
    return rz * ry * rx


@wp.func
def body_transform(keys: BodyKeys, b: int, t: wp.float64) -> wp.transform:
    """Body b's rigid transform at time ``t``: a point ``rest`` placed by the scene is at
    ``wp.transform_point(T, rest)``."""
    k0 = keys.first[b]
    k1 = keys.first[b + 1] - 1
    tr = keys.translate[k0]
    rot = keys.rotate[k0]
    if t >= keys.times[k1]:
        tr = keys.translate[k1]
        rot = keys.rotate[k1]
    elif t > keys.times[k0]:
        k = k0
        while keys.times[k + 1] <= t:
            k += 1
        span = keys.times[k + 1] - keys.times[k]
        s = float((t - keys.times[k]) / span)
        sm = keys.smooth[b]
        tr = hermite(
            keys.translate[k],
            keys.slope_translate[k],
            keys.translate[k + 1],
            keys.slope_translate[k + 1],
            s,
            float(span),
            sm,
        )
        rot = hermite(
            keys.rotate[k], keys.slope_rotate[k], keys.rotate[k + 1], keys.slope_rotate[k + 1], s, float(span), sm
        )
    p = keys.pivot[b]
    R = rotation_xyz(rot)
    return wp.transform(p + tr - R * p, wp.quat_from_matrix(R))


@wp.func
def body_place(keys: BodyKeys, b: int, t: wp.float64, rest: wp.vec3) -> wp.vec3:
    """Where the point ``rest`` of body b (as the scene places it) is at time ``t``."""
    return wp.transform_point(body_transform(keys, b, t), rest)


@wp.kernel
def move_bodies(
    keys: BodyKeys,
    body: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=wp.vec3),
    time: wp.array(dtype=wp.float64),
    dt: wp.array(dtype=wp.float64),
    first: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    acc: wp.array(dtype=wp.vec3),
):
    """Boundary particle ``first + k`` of a moving body: its place at the step's start, the
    velocity that brings it to its place at the step's end, and its acceleration (the central
    difference of its places a step before, at and after the step's start; before the motion's
    first key, the body stands where that key puts it)."""
    k = wp.tid()
    b = body[k]
    t = time[0]
    h = dt[0]
    a = body_place(keys, b, t, rest[k])
    e = body_place(keys, b, t + h, rest[k])
    before = body_place(keys, b, t - h, rest[k])
    x[first + k] = a
    v[first + k] = (e - a) / float(h)
    acc[first + k] = (e - 2.0 * a + before) / float(h * h)


class MovingBodies:
    """The moving obstacles' boundary particles ``first .. first + n - 1`` of a boundary array:
    their places as the scene sets them (``rest``), which body each belongs to, and the bodies'
    keyframes."""

    def __init__(self, motions: list, rest: np.ndarray, body: np.ndarray, first: int, device):
        self.device = device
        self.first = int(first)
        self.n = len(rest)
        self.motions = motions
        self.rest = wp.array(rest.astype(np.float32), dtype=wp.vec3, device=device)
        self.body = wp.array(body.astype(np.int32), dtype=wp.int32, device=device)
        k = BodyKeys()
        counts = [len(m.times) for m in motions]
        k.first = wp.array(np.concatenate([[0], np.cumsum(counts)]).astype(np.int32), dtype=wp.int32, device=device)
        k.smooth = wp.array(
            np.array([m.interpolation == "smooth" for m in motions], dtype=np.int32), dtype=wp.int32, device=device
        )
        k.pivot = wp.array(np.array([m.pivot for m in motions], dtype=np.float32), dtype=wp.vec3, device=device)
        k.times = wp.array(
            np.concatenate([m.times for m in motions]).astype(np.float64), dtype=wp.float64, device=device
        )
        slopes = [m.slopes() for m in motions]

        def vec(rows):
            return wp.array(np.concatenate(rows).astype(np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)

        k.translate = vec([m.translate for m in motions])
        k.rotate = vec([m.rotate for m in motions])
        k.slope_translate = vec([s[0] for s in slopes])
        k.slope_rotate = vec([s[1] for s in slopes])
        self.keys = k

    def place(
        self, boundary_x: wp.array, boundary_v: wp.array, boundary_a: wp.array, time: wp.array, dt: wp.array
    ) -> None:
        """Put the bodies where they are at ``time`` with the velocity of the step ``dt`` and their
        acceleration (device arrays)."""
        if self.n:
            wp.launch(
                move_bodies,
                dim=self.n,
                inputs=[self.keys, self.body, self.rest, time, dt, self.first, boundary_x, boundary_v, boundary_a],
                device=self.device,
            )
