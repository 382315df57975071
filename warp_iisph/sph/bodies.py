"""Moving bodies on the device: keyframed obstacles and free bodies share one path. Each step,
every moving body has a pose at the step's start and at its end (:class:`Poses`); its boundary
particles are placed by the start pose and carry the body's velocity and acceleration into the
liquid's equations, and the containment holds the liquid out of the body at the end pose.

A keyframed obstacle's poses are those of :class:`warp_iisph.scene.motion.Motion` at the step's
start, end and a step before its start (interpolated here by the same formulas as its NumPy
``at``); its particles move with the velocity that carries them to the end pose (so the fluid sees
exactly the displacement the wall makes during the step) and the acceleration of the central
difference of the three places. The time is read from the device, so a graph replays moving walls
without the host. A free body's start pose, velocity, spin and accelerations come from its
rigid-body state (:mod:`.rigid`), which writes its end pose after its update; its particles carry
the rigid velocity ``V + w x r`` and acceleration ``A + alpha x r + w x (w x r)``.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch, launch_particles

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@wp.struct
class BodyKeys:
    """Keyframes of every keyframed body, flattened: body b's keys are ``first[b] .. first[b+1]-1``."""

    first: wp.array(dtype=wp.int32)
    smooth: wp.array(dtype=wp.int32)
    pivot: wp.array(dtype=wp.vec3)
    times: wp.array(dtype=wp.float64)
    translate: wp.array(dtype=wp.vec3)
    rotate: wp.array(dtype=wp.vec3)  # degrees about x, then y, then z
    slope_translate: wp.array(dtype=wp.vec3)
    slope_rotate: wp.array(dtype=wp.vec3)


@wp.struct
class Poses:
    """Every moving body's rigid transforms in a step (a point ``rest`` of body b is at
    ``wp.transform_point(start[b], rest)`` at the step's start), and a free body's motion at the
    step's start (zero for keyframed ones, ``free[b] = 0``)."""

    start: wp.array(dtype=wp.transform)
    end: wp.array(dtype=wp.transform)
    before: wp.array(dtype=wp.transform)  # keyframed: a step before the start
    free: wp.array(dtype=wp.int32)
    velocity: wp.array(dtype=wp.vec3)  # of the centre of mass, m/s
    spin: wp.array(dtype=wp.vec3)  # angular velocity, rad/s
    acceleration: wp.array(dtype=wp.vec3)  # of the centre of mass, m/s^2
    angular_acceleration: wp.array(dtype=wp.vec3)  # rad/s^2


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
    """Keyframed body b's rigid transform at time ``t``: a point ``rest`` placed by the scene is at
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
    """Where the point ``rest`` of keyframed body b (as the scene places it) is at time ``t``."""
    return wp.transform_point(body_transform(keys, b, t), rest)


@wp.func
def point_velocity(poses: Poses, b: int, x: wp.vec3, h: float) -> wp.vec3:
    """The velocity of body b's material point at ``x`` (where the start pose has it) over a step
    of ``h``: a free body's rigid velocity, a keyframed one's displacement to the end pose over h."""
    start = poses.start[b]
    if poses.free[b] != 0:
        return poses.velocity[b] + wp.cross(poses.spin[b], x - wp.transform_get_translation(start))
    rest = wp.transform_point(wp.transform_inverse(start), x)
    return (wp.transform_point(poses.end[b], rest) - x) / h


@wp.kernel
def key_poses(keys: BodyKeys, time: wp.array(dtype=wp.float64), dt: wp.array(dtype=wp.float64), poses: Poses):
    """Keyframed body b's poses at the step's start, its end and a step before its start."""
    b = wp.tid()
    t = time[0]
    h = dt[0]
    poses.start[b] = body_transform(keys, b, t)
    poses.end[b] = body_transform(keys, b, t + h)
    poses.before[b] = body_transform(keys, b, t - h)


@wp.kernel
def place_bodies(
    offset: int,
    poses: Poses,
    body: wp.array(dtype=wp.int32),
    rest: wp.array(dtype=wp.vec3),
    dt: wp.array(dtype=wp.float64),
    first: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    acc: wp.array(dtype=wp.vec3),
):
    """Boundary particle ``first + k`` of a moving body: its place at the step's start, its
    velocity and its acceleration (a keyframed body: the displacement to the end pose over the
    step, the central difference of its places a step before, at and after the step's start;
    before the motion's first key, the body stands where that key puts it)."""
    k = wp.tid() + offset
    b = body[k]
    h = dt[0]
    a = wp.transform_point(poses.start[b], rest[k])
    x[first + k] = a
    if poses.free[b] != 0:
        r = a - wp.transform_get_translation(poses.start[b])
        w = poses.spin[b]
        v[first + k] = poses.velocity[b] + wp.cross(w, r)
        acc[first + k] = (
            poses.acceleration[b] + wp.cross(poses.angular_acceleration[b], r) + wp.cross(w, wp.cross(w, r))
        )
    else:
        e = wp.transform_point(poses.end[b], rest[k])
        before = wp.transform_point(poses.before[b], rest[k])
        v[first + k] = (e - a) / float(h)
        acc[first + k] = (e - 2.0 * a + before) / float(h * h)


class MovingBodies:
    """The moving bodies' boundary particles ``first .. first + n - 1`` of a boundary array: their
    places in their body's frame (``rest``: as the scene places a keyframed obstacle, relative to
    the centre of mass for a free body), which body each belongs to, the keyframed bodies'
    keyframes (bodies ``0 .. len(motions) - 1``) and every body's :class:`Poses` (the free ones
    after the keyframed ones, ``n_free`` of them)."""

    def __init__(self, motions: list, rest: np.ndarray, body: np.ndarray, first: int, device, n_free: int = 0):
        self.device = device
        self.first = int(first)
        self.n = len(rest)
        self.motions = motions
        self.n_keyed = len(motions)
        self.n_bodies = self.n_keyed + int(n_free)
        self.rest = wp.array(np.asarray(rest, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
        self.body = wp.array(np.asarray(body, np.int32), dtype=wp.int32, device=device)
        self.keys = keyframes(motions, device)
        m = max(self.n_bodies, 1)
        p = Poses()
        identity = np.tile(np.array([0, 0, 0, 0, 0, 0, 1], np.float32), (m, 1))
        p.start, p.end, p.before = (wp.array(identity, dtype=wp.transform, device=device) for _ in range(3))
        free = np.zeros(m, np.int32)
        free[self.n_keyed : self.n_bodies] = 1
        p.free = wp.array(free, dtype=wp.int32, device=device)
        p.velocity, p.spin, p.acceleration, p.angular_acceleration = (
            wp.zeros(m, dtype=wp.vec3, device=device) for _ in range(4)
        )
        self.poses = p

    def place(
        self, boundary_x: wp.array, boundary_v: wp.array, boundary_a: wp.array, time: wp.array, dt: wp.array
    ) -> None:
        """The keyframed bodies' poses at ``time`` with the step ``dt``, then every moving body's
        particles where the start poses have them, with their velocity and acceleration (the free
        bodies' poses are set before, :meth:`.rigid.RigidBodies.begin_step`)."""
        if self.n_keyed:
            launch(key_poses, dim=self.n_keyed, inputs=[self.keys, time, dt, self.poses], device=self.device)
        if self.n:
            launch_particles(
                place_bodies,
                self.n,
                [self.poses, self.body, self.rest, dt, self.first, boundary_x, boundary_v, boundary_a],
                self.device,
            )


def keyframes(motions: list, device) -> BodyKeys:
    """The :class:`BodyKeys` of ``motions`` (one key at the origin where there are none, so the
    struct's arrays are never empty)."""
    k = BodyKeys()
    if not motions:
        k.first = wp.zeros(1, dtype=wp.int32, device=device)
        k.smooth = wp.zeros(1, dtype=wp.int32, device=device)
        k.pivot = wp.zeros(1, dtype=wp.vec3, device=device)
        k.times = wp.zeros(1, dtype=wp.float64, device=device)
        for name in ("translate", "rotate", "slope_translate", "slope_rotate"):
            setattr(k, name, wp.zeros(1, dtype=wp.vec3, device=device))
        return k
    counts = [len(m.times) for m in motions]
    k.first = wp.array(np.concatenate([[0], np.cumsum(counts)]).astype(np.int32), dtype=wp.int32, device=device)
    k.smooth = wp.array(
        np.array([m.interpolation == "smooth" for m in motions], dtype=np.int32), dtype=wp.int32, device=device
    )
    k.pivot = wp.array(np.array([m.pivot for m in motions], dtype=np.float32), dtype=wp.vec3, device=device)
    k.times = wp.array(np.concatenate([m.times for m in motions]).astype(np.float64), dtype=wp.float64, device=device)
    slopes = [m.slopes() for m in motions]

    def vec(rows):
        return wp.array(np.concatenate(rows).astype(np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)

    k.translate = vec([m.translate for m in motions])
    k.rotate = vec([m.rotate for m in motions])
    k.slope_translate = vec([s[0] for s in slopes])
    k.slope_rotate = vec([s[1] for s in slopes])
    return k
