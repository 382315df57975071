"""Free rigid bodies' dynamics on the device: the liquid's force and moment (:mod:`.wall_forces`),
gravity and contacts (:mod:`.contacts`) move each body as a rigid body.

The state of body f, in float64: its centre of mass ``position``, ``orientation`` (a unit
quaternion taking the body's axes as the scene placed it to the world's), linear ``velocity`` and
angular ``momentum`` about its centre of mass (world axes). A step of length h, after the liquid's
(semi-implicit Euler, the liquid's own integrator: velocities first, then positions with the new
velocities; symplectic, so a floating body's heave neither gains nor loses energy by the
integration):

    V* = V + h (F / M + g),     L* = L + h T,     w* = I_w^-1 L*     (I_w = R I_body R^T)
    contacts: impulses on (V*, w*) (:func:`.contacts.resolve`)
    L = I_w w*,   x += h V*,   q = R(h w_m) q,   w_m = I_w(R(h w_m / 2) q)^-1 L
    (R(a): the turn by |a| about a)

Holding the angular momentum (not the angular velocity) keeps a free body's L exact without a
torque, and its angular velocity follows its inertia as it turns; turning at the angular velocity
of the step's midpoint orientation (``w_m``, found by a few fixed-point iterations) makes the turn
time-symmetric, so a body spinning freely keeps its kinetic energy too (turning at ``w*``, the
start's, it gained 2.4 % in 4 s spinning at 3.7 rad/s in 5 ms steps). ``fixed_axes`` zero the held
translations and rotations (world axes); a body before its ``release`` time is held whole (at rest,
and to the contacts as heavy as a fixed obstacle). The last step's accelerations, ``(V - V_before) / h``
and ``(w - w_before) / h``, are what the body's boundary particles carry into the walls'
extrapolated pressure (:mod:`.wall_pressure`).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch, launch_particles
from ..scene.bodies import quaternion_matrix
from .bodies import Poses
from .contacts import FACES, ContactSet, Motion, near_partners, pool_contacts, resolve, sample_gaps
from .containment import Solids

# never differentiated: no adjoint code; loops not unrolled (one thread a body: the unrolled
# midpoint and contact loops took NVRTC 12 s to compile, 1.6 s rolled)
wp.set_module_options({"enable_backward": False, "max_unroll": 1})

# Fixed-point iterations of the turn's midpoint angular velocity: each gains a factor of about
# h |w| (under 0.1 at any step the CFL rule allows a body turning less than 20 rad/s).
MIDPOINT_ITERATIONS = 4


@wp.struct
class RigidState:
    """What every step changes (float64): checkpointed, restored bitwise."""

    position: wp.array(dtype=wp.vec3d)  # centre of mass (m)
    orientation: wp.array(dtype=wp.quatd)
    velocity: wp.array(dtype=wp.vec3d)  # of the centre of mass (m/s)
    momentum: wp.array(dtype=wp.vec3d)  # angular momentum about the centre of mass, world axes (kg m^2/s)
    acceleration: wp.array(dtype=wp.vec3d)  # over the last step (m/s^2)
    angular_acceleration: wp.array(dtype=wp.vec3d)  # (rad/s^2)
    coupled: wp.array(dtype=wp.vec3d)  # the last step's acceleration by the liquid and gravity alone (m/s^2)
    coupled_angular: wp.array(dtype=wp.vec3d)  # (rad/s^2)


@wp.struct
class RigidConstants:
    """What a run does not change."""

    mass: wp.array(dtype=wp.float64)  # kg
    inertia: wp.array(dtype=wp.mat33d)  # about the centre of mass, in the body's axes (kg m^2)
    inv_inertia: wp.array(dtype=wp.mat33d)
    added_mass: wp.array(dtype=wp.mat33d)  # the coupling's estimate of the liquid's, body axes (kg)
    added_inertia: wp.array(dtype=wp.mat33d)  # (kg m^2)
    linear_free: wp.array(dtype=wp.vec3d)  # 1 along a free world axis, 0 along a fixed one
    angular_free: wp.array(dtype=wp.vec3d)
    radius: wp.array(dtype=wp.float64)  # the farthest sample from the centre of mass (m)
    samples: wp.array(dtype=wp.int32)  # its boundary particles
    restitution: wp.array(dtype=wp.float64)
    friction: wp.array(dtype=wp.float64)
    release: wp.array(dtype=wp.float64)  # held still until this time (s)
    gravity: wp.vec3d
    keyed: int  # body f's poses are at keyed + f


@wp.func
def world_inertia(c: RigidConstants, f: int, q: wp.quatd, inverse: int) -> wp.mat33d:
    R = wp.quat_to_matrix(q)
    m = c.inertia[f]
    if inverse != 0:
        m = c.inv_inertia[f]
    return R * m * wp.transpose(R)


@wp.func
def spin_of(c: RigidConstants, s: RigidState, f: int) -> wp.vec3d:
    """Angular velocity from the angular momentum, fixed rotations removed."""
    return wp.cw_mul(c.angular_free[f], world_inertia(c, f, s.orientation[f], 1) * s.momentum[f])


@wp.kernel
def begin_step(c: RigidConstants, s: RigidState, poses: Poses):
    """Body f's pose and motion at the step's start, as its boundary particles read them."""
    f = wp.tid()
    b = c.keyed + f
    pose = wp.transform(wp.vec3(s.position[f]), wp.quat(s.orientation[f]))
    poses.start[b] = pose
    poses.end[b] = pose
    poses.before[b] = pose
    poses.velocity[b] = wp.vec3(s.velocity[f])
    poses.spin[b] = wp.vec3(spin_of(c, s, f))
    poses.acceleration[b] = wp.vec3(s.acceleration[f])
    poses.angular_acceleration[b] = wp.vec3(s.angular_acceleration[f])


@wp.func
def turned(q: wp.quatd, w: wp.vec3d, h: wp.float64) -> wp.quatd:
    """Orientation ``q`` turned at angular velocity ``w`` (world axes) for ``h`` seconds."""
    angle = wp.length(w) * h
    if angle > wp.float64(0.0):
        q = wp.normalize(wp.quat_from_axis_angle(w / wp.length(w), angle) * q)
    return q


@wp.kernel
def advance(
    c: RigidConstants,
    s: RigidState,
    loads: wp.array2d(dtype=wp.float64),
    wetted: wp.array(dtype=wp.int32),
    motion: Motion,
    contacts: ContactSet,
    solids: Solids,
    poses: Poses,
    time: wp.array(dtype=wp.float64),
    dt: wp.array(dtype=wp.float64),
    n_free: int,
):
    """One step of every free body (the module's docstring), from ``time``; one thread, so that
    contacts between bodies are resolved in one order."""
    h = dt[0]
    for f in range(n_free):
        force = wp.vec3d(loads[f, 0] + loads[f, 3], loads[f, 1] + loads[f, 4], loads[f, 2] + loads[f, 5])
        torque = wp.vec3d(loads[f, 6] + loads[f, 9], loads[f, 7] + loads[f, 10], loads[f, 8] + loads[f, 11])
        m = c.mass[f]
        q = s.orientation[f]
        R = wp.quat_to_matrix(q)
        Rt = wp.transpose(R)
        free_v = c.linear_free[f]
        free_w = c.angular_free[f]
        if time[0] < c.release[f] - wp.float64(1.0e-9):  # held: free from the first step starting at its release
            free_v = wp.vec3d(0.0)
            free_w = wp.vec3d(0.0)
        # the liquid's load and gravity, with the added-mass term of the partitioned coupling (the
        # estimate of a body under the liquid, by the wet share of its particles)
        wet = wp.float64(wetted[f]) / wp.float64(c.samples[f])
        added = wet * (R * c.added_mass[f] * Rt)
        a = wp.inverse(m * wp.identity(3, wp.float64) + added) * (force + m * c.gravity + added * s.coupled[f])
        v = wp.cw_mul(free_v, s.velocity[f] + h * a)
        spin = spin_of(c, s, f)
        added_i = wet * (R * c.added_inertia[f] * Rt)
        inertia = R * c.inertia[f] * Rt
        w = wp.inverse(inertia + added_i) * (s.momentum[f] + h * torque + added_i * (spin + h * s.coupled_angular[f]))
        w = wp.cw_mul(free_w, w)
        s.coupled[f] = (v - s.velocity[f]) / h
        s.coupled_angular[f] = (w - spin) / h
        motion.centre[f] = s.position[f]
        motion.velocity[f] = v
        motion.spin[f] = w
        motion.inv_mass[f] = free_v / m  # a held body or axis takes no impulse
        P = wp.diag(free_w)
        motion.inv_inertia[f] = P * (R * c.inv_inertia[f] * Rt) * P
        motion.restitution[f] = c.restitution[f]
        motion.friction[f] = c.friction[f]
    resolve(motion, contacts, solids, poses, n_free, h)
    for f in range(n_free):
        q = s.orientation[f]
        v = motion.velocity[f]
        w = motion.spin[f]
        s.acceleration[f] = (v - s.velocity[f]) / h
        s.angular_acceleration[f] = (w - spin_of(c, s, f)) / h
        L = world_inertia(c, f, q, 0) * w
        s.momentum[f] = L
        s.velocity[f] = v
        x = s.position[f] + h * v
        # the turn at the angular velocity of the step's midpoint orientation (implicit midpoint,
        # by fixed-point iteration): time-symmetric, so a freely spinning body keeps its energy
        w_mid = w
        for _ in range(MIDPOINT_ITERATIONS):
            half = turned(q, w_mid, wp.float64(0.5) * h)
            w_mid = wp.cw_mul(c.angular_free[f], world_inertia(c, f, half, 1) * L)
        q = turned(q, w_mid, h)
        s.position[f] = x
        s.orientation[f] = q
        poses.end[c.keyed + f] = wp.transform(wp.vec3(x), wp.quat(q))


@wp.kernel
def body_speeds(c: RigidConstants, s: RigidState, speed2: wp.array(dtype=float)):
    """The fastest a point of body f moves, squared, into the step's top speed (the CFL rule's)."""
    f = wp.tid()
    top = wp.length(s.velocity[f]) + wp.length(spin_of(c, s, f)) * c.radius[f]
    wp.atomic_max(speed2, 0, float(top * top))


class RigidBodies:
    """The free bodies of a model: constants, state and contact buffers on ``device``. ``bodies``
    holds per body a dict of its sampled data (``setup.bodies``): ``mass``, ``com``, ``inertia``
    (3x3, about the centre of mass), ``rest`` (its boundary particles from the centre of mass),
    ``depth`` (how deep each lies inside the surface), ``velocity``, ``angular_velocity``,
    ``fixed_axes``, ``restitution``, ``friction``, ``release_time``; ``first`` is its first boundary particle,
    ``keyed`` the number of keyframed bodies before the free ones in the poses."""

    def __init__(self, bodies: list, first: list, keyed: int, gravity, spacing: float, box, partners: int, device):
        self.device = device
        self.n = len(bodies)
        self.keyed = int(keyed)
        self.first = [int(k) for k in first]
        self.counts = [len(b["rest"]) for b in bodies]
        self.names = [b["name"] for b in bodies]
        n = max(self.n, 1)

        def arr(values, dtype, shape=None):
            a = np.asarray(values, dtype=np.float64)
            return wp.array(a.reshape(shape) if shape else a, dtype=dtype, device=device)

        c = RigidConstants()
        c.mass = arr([b["mass"] for b in bodies], wp.float64)
        c.inertia = arr([b["inertia"] for b in bodies], wp.mat33d, (-1, 3, 3))
        c.inv_inertia = arr([np.linalg.inv(b["inertia"]) for b in bodies], wp.mat33d, (-1, 3, 3))
        axes = ("x", "y", "z", "rx", "ry", "rz")
        held = [[0.0 if a in b["fixed_axes"] else 1.0 for a in axes] for b in bodies]
        c.added_mass = arr([b["added_mass"] for b in bodies], wp.mat33d, (-1, 3, 3))
        c.added_inertia = arr([b["added_inertia"] for b in bodies], wp.mat33d, (-1, 3, 3))
        c.linear_free = arr([m[:3] for m in held], wp.vec3d, (-1, 3))
        c.angular_free = arr([m[3:] for m in held], wp.vec3d, (-1, 3))
        c.radius = arr([float(np.max(np.linalg.norm(b["rest"], axis=1))) for b in bodies], wp.float64)
        c.samples = wp.array(np.asarray(self.counts or [1], np.int32), dtype=wp.int32, device=device)
        c.restitution = arr([b["restitution"] for b in bodies], wp.float64)
        c.friction = arr([b["friction"] for b in bodies], wp.float64)
        c.release = arr([b["release_time"] for b in bodies], wp.float64)
        c.gravity = wp.vec3d(*[float(g) for g in gravity])
        c.keyed = self.keyed
        self.constants = c
        self.initial = {
            "position": np.array([b["com"] for b in bodies], np.float64).reshape(-1, 3),
            "orientation": np.tile([0.0, 0.0, 0.0, 1.0], (self.n, 1)),
            # the start's motion along and about fixed axes is dropped, as every step drops it
            "velocity": np.array([np.multiply(m[:3], b["velocity"]) for m, b in zip(held, bodies)]).reshape(-1, 3),
            "momentum": np.array(
                [np.asarray(b["inertia"]) @ np.multiply(m[3:], b["angular_velocity"]) for m, b in zip(held, bodies)],
                np.float64,
            ).reshape(-1, 3),
            "acceleration": np.zeros((self.n, 3)),
            "angular_acceleration": np.zeros((self.n, 3)),
            "coupled": np.zeros((self.n, 3)),
            "coupled_angular": np.zeros((self.n, 3)),
        }
        s = RigidState()
        for name, dtype in self.fields().items():
            setattr(s, name, wp.array(self.initial[name], dtype=dtype, device=device))
        self.state = s
        m = Motion()
        for name in ("centre", "velocity", "spin", "inv_mass"):
            setattr(m, name, wp.zeros(n, dtype=wp.vec3d, device=device))
        m.inv_inertia = wp.zeros(n, dtype=wp.mat33d, device=device)
        m.restitution, m.friction = (
            wp.zeros(n, dtype=wp.float64, device=device),
            wp.zeros(n, dtype=wp.float64, device=device),
        )
        self.motion = m
        self.contacts = _contact_set(bodies, self.first, keyed, spacing, gravity, box, partners, device)
        self.n_samples = int(sum(self.counts))

    @staticmethod
    def fields() -> dict:
        """The state's arrays by name, with their types."""
        vec = wp.vec3d
        return {
            "position": vec,
            "orientation": wp.quatd,
            "velocity": vec,
            "momentum": vec,
            "acceleration": vec,
            "angular_acceleration": vec,
            "coupled": vec,
            "coupled_angular": vec,
        }

    def arrays(self) -> list:
        """The state's device arrays (a graph's redo restores them)."""
        return [getattr(self.state, name) for name in self.fields()]

    def begin_step(self, poses: Poses) -> None:
        if self.n:
            launch(begin_step, dim=self.n, inputs=[self.constants, self.state, poses], device=self.device)

    def advance(self, loads, solids: Solids, poses: Poses, boundary_x: wp.array, time: wp.array, dt: wp.array) -> None:
        """The step's contacts, then every body's update (``loads``: the liquid's, per body, a
        :class:`.wall_forces.WallForces` whose totals and wetted counts are this step's; ``time``
        the step's start)."""
        if not self.n:
            return
        cs, dev = self.contacts, self.device
        # a sample's queries against every partner are a large piece of work: a thread from 256
        if solids.count:
            launch(near_partners, (self.n, solids.count), [cs, solids, poses, self.constants.radius], dev)
        launch_particles(
            sample_gaps, self.n_samples, [cs, solids, poses, boundary_x, self.n_samples], dev, min_chunk=256
        )
        launch(pool_contacts, dim=(self.n, cs.partners), inputs=[cs, boundary_x], device=dev)
        inputs = [self.constants, self.state, loads.totals, loads.wetted, self.motion, cs, solids, poses]
        inputs += [time, dt, self.n]
        launch(advance, dim=1, inputs=inputs, device=dev)

    def speeds(self, speed2: wp.array) -> None:
        if self.n:
            launch(body_speeds, dim=self.n, inputs=[self.constants, self.state, speed2], device=self.device)

    def values(self) -> dict:
        """The state on the host: name -> (bodies, components) float64 array."""
        state = self.state
        return {name: getattr(state, name).numpy().astype(np.float64).reshape(self.n, -1) for name in self.fields()}

    def host(self) -> dict:
        """:meth:`values` and the angular velocity ``spin`` (rad/s)."""
        out = self.values()
        inertia = self.constants.inertia.numpy().reshape(-1, 3, 3)
        free = self.constants.angular_free.numpy().reshape(-1, 3)
        spin = []
        for f in range(self.n):
            R = quaternion_matrix(out["orientation"][f])
            spin.append(free[f] * (R @ np.linalg.inv(inertia[f]) @ R.T @ out["momentum"][f]))
        out["spin"] = np.array(spin).reshape(-1, 3)
        return out

    def assign(self, values: dict) -> None:
        """Set the state from ``values`` (name -> array), as :meth:`host` gives them (less ``spin``)."""
        for name in self.fields():
            getattr(self.state, name).assign(np.asarray(values[name], np.float64).reshape(self.n, -1))


def _contact_set(bodies, first, keyed, spacing, gravity, box, partners, device) -> ContactSet:
    """The contact buffers: ``partners`` is the number of the containment's solids; ``box`` the box
    tank's faces (lower, upper) or None."""
    cs = ContactSet()
    counts = [len(b["rest"]) for b in bodies]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32) if counts else np.zeros(1, np.int32)
    cs.sample_first = wp.array(np.asarray(first or [0], np.int32), dtype=wp.int32, device=device)
    cs.sample_count = wp.array(np.asarray(counts or [0], np.int32), dtype=wp.int32, device=device)
    cs.sample_start = wp.array(starts, dtype=wp.int32, device=device)
    total = max(int(sum(counts)), 1)
    depth = np.concatenate([b["depth"] for b in bodies]) if bodies else np.zeros(1)
    cs.depth = wp.array(depth.astype(np.float32), dtype=float, device=device)
    owner = np.concatenate([np.full(c, f) for f, c in enumerate(counts)]) if bodies else np.zeros(1)
    cs.owner = wp.array(owner.astype(np.int32), dtype=wp.int32, device=device)
    cs.faces = FACES if box is not None else 0
    cs.partners = cs.faces + int(partners)
    width = max(cs.partners, 1)
    cs.gap = wp.zeros(total * width, dtype=float, device=device)
    cs.normal = wp.zeros(total * width, dtype=wp.vec3, device=device)
    lo, hi = box if box is not None else (np.zeros(3), np.zeros(3))
    cs.box_lower, cs.box_upper = wp.vec3(*np.asarray(lo, float)), wp.vec3(*np.asarray(hi, float))
    cs.reach = float(spacing)
    cs.deepest = float(np.max(depth)) if len(depth) else 0.0
    cs.near = wp.zeros(max(len(bodies) * max(int(partners), 1), 1), dtype=wp.int32, device=device)
    cs.bounce_speed = wp.float64(np.sqrt(float(np.linalg.norm(gravity)) * spacing))
    cs.keyed = int(keyed)
    pairs = max(len(bodies) * width, 1)
    cs.active = wp.zeros(pairs, dtype=wp.int32, device=device)
    cs.point, cs.direction, cs.friction_impulse = (wp.zeros(pairs, dtype=wp.vec3d, device=device) for _ in range(3))
    cs.closest, cs.impulse, cs.speed = (wp.zeros(pairs, dtype=wp.float64, device=device) for _ in range(3))
    return cs
