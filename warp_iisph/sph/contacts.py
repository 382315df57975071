"""Contacts of free bodies with the tank, the obstacles and each other, on signed distances.

Every boundary particle of a free body is a contact sample: it sits ``depth`` (half a spacing, or
less in a thin part) inside its body's surface, so the body's surface is ``gap = d - depth`` from
a partner's surface, ``d`` the sample's signed distance to it (a box tank's six faces, each a
partner of its own, or any closed surface the containment keeps the liquid out of: a mesh
container, the obstacles, keyframed or still, the other free bodies, each in its pose at the
step's start). Per body and partner, the samples closer than one spacing are pooled into one
contact: the deepest gap, and the point and normal averaged with weights ``spacing - gap`` (a
body tilted onto an edge has its contact at that edge, one lying flat at the middle of its face).
Sums run over each body's samples in order, one thread per body and partner: the same bits on
every path.

The contacts are then resolved on velocities (:func:`resolve`): sequential impulses, a few sweeps
over all contacts, each keeping its normal impulse non-negative and its friction within Coulomb's
cone. A contact whose gap is open lets the bodies close it within the step (a speculative
contact: no body passes through another at any speed the step resolves, and a resting one comes
to rest touching, without bouncing); one that overlaps pushes apart at a fifth of the overlap per
step; an impact faster than ``sqrt(|g| h)`` keeps ``restitution`` of its normal speed. Why this
and not a penalty: a spring stiff enough to hold a heavy block within a fraction of a spacing
would need steps far below the liquid's CFL step; impulses hold at any step.
"""

from __future__ import annotations

import warp as wp

from .bodies import Poses, point_velocity
from .containment import Solids

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

NO_GAP = wp.constant(1.0e30)  # a sample far from a partner
FACES = 6  # a box tank's partners: its faces, lower x, upper x, lower y, ...
SWEEPS = 8  # sweeps of sequential impulses over all contacts
PUSH_OUT = wp.constant(wp.float64(0.2))  # share of an overlap removed per step


@wp.struct
class ContactSet:
    """Each free body's contact samples and its contacts with each partner (``partners`` per
    body: the tank's faces first, then the containment's solids)."""

    sample_first: wp.array(dtype=wp.int32)  # body f's samples are boundary particles sample_first[f] + k
    sample_count: wp.array(dtype=wp.int32)
    sample_start: wp.array(dtype=wp.int32)  # and entries sample_start[f] + k of the sample arrays
    depth: wp.array(dtype=float)  # how far each sample lies inside its body's surface (m)
    owner: wp.array(dtype=wp.int32)  # the free body of each sample
    gap: wp.array(dtype=float)  # sample s, partner j at s * partners + j
    normal: wp.array(dtype=wp.vec3)  # towards the sample's body, away from the partner
    partners: int
    faces: int  # FACES for a box tank, else 0
    box_lower: wp.vec3
    box_upper: wp.vec3
    reach: float  # samples closer than this (m) take part: one spacing
    deepest: float  # the deepest sample's depth (m)
    near: wp.array(dtype=wp.int32)  # body f, solid k at f * solids.count + k: 1 where a sample may touch it
    bounce_speed: wp.float64  # impacts slower than this (m/s) do not bounce: sqrt(|g| h)
    keyed: int  # the free bodies' poses follow the keyframed ones'
    # per body and partner (f * partners + j)
    active: wp.array(dtype=wp.int32)
    point: wp.array(dtype=wp.vec3d)
    direction: wp.array(dtype=wp.vec3d)
    closest: wp.array(dtype=wp.float64)  # the deepest gap
    impulse: wp.array(dtype=wp.float64)  # the normal impulse accumulated in the sweeps (N s)
    friction_impulse: wp.array(dtype=wp.vec3d)
    speed: wp.array(dtype=wp.float64)  # the normal speed before the sweeps (restitution's)


@wp.func
def partner_pose(solids: Solids, poses: Poses, k: int) -> wp.transform:
    frame = wp.transform_identity()
    b = solids.body[k]
    if b >= 0:
        frame = poses.start[b]
    return frame


@wp.kernel
def near_partners(contacts: ContactSet, solids: Solids, poses: Poses, radius: wp.array(dtype=wp.float64)):
    """Whether free body f may have a sample within reach of solid k's surface: not where the
    spheres holding the body's samples (``radius[f]`` about its centre of mass, grown by a
    millionth and a micrometre) and the solid lie further apart than a sample's reach (one spacing
    past its depth; a hundredth of a spacing more against rounding). A container's sphere holds
    the bodies inside it: never ruled out."""
    f, k = wp.tid()
    centre = wp.transform_get_translation(poses.start[contacts.keyed + f])
    other = wp.transform_point(partner_pose(solids, poses, k), solids.center[k])
    held = float(radius[f] * wp.float64(1.000001) + wp.float64(1.0e-6))
    apart = wp.length(centre - other) - held - solids.radius[k]
    reach = 1.01 * contacts.reach + contacts.deepest
    contacts.near[f * solids.count + k] = wp.where(apart < reach, 1, 0)


@wp.kernel
def sample_gaps(
    offset: int, contacts: ContactSet, solids: Solids, poses: Poses, xb: wp.array(dtype=wp.vec3), n_samples: int
):
    """Each sample's gap to and normal from every partner (``NO_GAP`` beyond the reach)."""
    s = offset + wp.tid()
    f = contacts.owner[s]
    x = xb[contacts.sample_first[f] + s - contacts.sample_start[f]]
    depth = contacts.depth[s]
    base = s * contacts.partners
    reach = contacts.reach
    for j in range(contacts.faces):
        a = j // 2
        n = wp.vec3(0.0)
        d = float(0.0)
        if j % 2 == 0:
            d = x[a] - contacts.box_lower[a]
            n[a] = 1.0
        else:
            d = contacts.box_upper[a] - x[a]
            n[a] = -1.0
        contacts.gap[base + j] = wp.where(d - depth < reach, d - depth, NO_GAP)
        contacts.normal[base + j] = n
    for k in range(solids.count):
        j = contacts.faces + k
        contacts.gap[base + j] = NO_GAP
        contacts.normal[base + j] = wp.vec3(0.0)
        if solids.body[k] == contacts.keyed + f:
            continue  # its own surface
        if contacts.near[f * solids.count + k] == 0:
            continue  # too far for any of its samples
        frame = partner_pose(solids, poses, k)
        p = wp.transform_point(wp.transform_inverse(frame), x)
        q = wp.mesh_query_point_sign_normal(solids.meshes[k], p, reach + depth)
        if q.result:
            c = wp.mesh_eval_position(solids.meshes[k], q.face, q.u, q.v)
            in_material = q.sign < 0.0
            if solids.container[k] != 0:
                in_material = q.sign >= 0.0
            d = wp.length(p - c)
            n = wp.mesh_eval_face_normal(solids.meshes[k], q.face)
            if solids.container[k] != 0:
                n = -n
            if d > 1.0e-9:
                n = (p - c) / d
                if in_material:
                    n = -n
            if in_material:
                d = -d
            if d - depth < reach:
                contacts.gap[base + j] = d - depth
                contacts.normal[base + j] = wp.transform_vector(frame, n)


@wp.kernel
def pool_contacts(contacts: ContactSet, xb: wp.array(dtype=wp.vec3)):
    """Body f's contact with partner j from its samples, in order: the deepest gap, the point (on
    the body's surface) and normal weighted by ``reach - gap``."""
    f, j = wp.tid()
    w_sum = wp.float64(0.0)
    at = wp.vec3d(0.0)
    towards = wp.vec3d(0.0)
    closest = wp.float64(NO_GAP)
    first = contacts.sample_first[f]
    start = contacts.sample_start[f]
    for k in range(contacts.sample_count[f]):
        e = (start + k) * contacts.partners + j
        g = contacts.gap[e]
        if g < contacts.reach:
            w = wp.float64(contacts.reach - g)
            n = wp.vec3d(contacts.normal[e])
            w_sum += w
            at += w * (wp.vec3d(xb[first + k]) - wp.float64(contacts.depth[start + k]) * n)
            towards += w * n
            closest = wp.min(closest, wp.float64(g))
    c = f * contacts.partners + j
    contacts.active[c] = wp.where(w_sum > wp.float64(0.0) and wp.length(towards) > wp.float64(0.0), 1, 0)
    if contacts.active[c] != 0:
        contacts.point[c] = at / w_sum
        contacts.direction[c] = wp.normalize(towards)
        contacts.closest[c] = closest
    contacts.impulse[c] = wp.float64(0.0)
    contacts.friction_impulse[c] = wp.vec3d(0.0)


@wp.struct
class Motion:
    """The free bodies' velocities while their contacts are resolved, and how they respond to an
    impulse: ``inv_mass`` (per axis, zero along a fixed one) and the inverse inertia in world axes
    (fixed rotations removed)."""

    centre: wp.array(dtype=wp.vec3d)
    velocity: wp.array(dtype=wp.vec3d)
    spin: wp.array(dtype=wp.vec3d)
    inv_mass: wp.array(dtype=wp.vec3d)
    inv_inertia: wp.array(dtype=wp.mat33d)
    restitution: wp.array(dtype=wp.float64)
    friction: wp.array(dtype=wp.float64)


@wp.func
def velocity_at(motion: Motion, f: int, x: wp.vec3d) -> wp.vec3d:
    return motion.velocity[f] + wp.cross(motion.spin[f], x - motion.centre[f])


@wp.func
def response(motion: Motion, f: int, x: wp.vec3d, d: wp.vec3d) -> wp.float64:
    """How much free body f's velocity at ``x`` along ``d`` changes per unit impulse along ``d``."""
    r = x - motion.centre[f]
    rd = wp.cross(r, d)
    return wp.dot(d, wp.cw_mul(motion.inv_mass[f], d)) + wp.dot(rd, motion.inv_inertia[f] * rd)


@wp.func
def push(motion: Motion, f: int, x: wp.vec3d, j: wp.vec3d):
    """Impulse ``j`` on free body f at ``x``."""
    motion.velocity[f] = motion.velocity[f] + wp.cw_mul(motion.inv_mass[f], j)
    motion.spin[f] = motion.spin[f] + motion.inv_inertia[f] * wp.cross(x - motion.centre[f], j)


@wp.func
def partner_velocity(
    motion: Motion, contacts: ContactSet, solids: Solids, poses: Poses, j: int, x: wp.vec3d, h: float
) -> wp.vec3d:
    """The velocity of partner j's surface at ``x``: zero for the tank and still obstacles."""
    v = wp.vec3d(0.0)
    if j >= contacts.faces:
        b = solids.body[j - contacts.faces]
        if b >= contacts.keyed:
            v = velocity_at(motion, b - contacts.keyed, x)
        elif b >= 0:
            v = wp.vec3d(point_velocity(poses, b, wp.vec3(x), h))
    return v


@wp.func
def resolve(motion: Motion, contacts: ContactSet, solids: Solids, poses: Poses, n_free: int, h: wp.float64):
    """Sequential impulses over every active contact (module docstring), :data:`SWEEPS` sweeps."""
    P = contacts.partners
    for sweep in range(SWEEPS):
        for f in range(n_free):
            for j in range(P):
                c = f * P + j
                if contacts.active[c] == 0:
                    continue
                x = contacts.point[c]
                n = contacts.direction[c]
                other = int(-1)
                if j >= contacts.faces:
                    b = solids.body[j - contacts.faces]
                    if b >= contacts.keyed:
                        other = b - contacts.keyed
                v_rel = velocity_at(motion, f, x) - partner_velocity(motion, contacts, solids, poses, j, x, float(h))
                vn = wp.dot(v_rel, n)
                if sweep == 0:
                    contacts.speed[c] = vn
                gap = contacts.closest[c]
                target = -gap / h  # an open gap may close within the step
                if gap < wp.float64(0.0):
                    target = PUSH_OUT * (-gap) / h
                impact = contacts.speed[c]
                if impact < -contacts.bounce_speed and gap + impact * h < wp.float64(0.0):
                    target = wp.max(target, -motion.restitution[f] * impact)
                k = response(motion, f, x, n)
                if other >= 0:
                    k += response(motion, other, x, n)
                if k <= wp.float64(0.0):
                    continue
                total = wp.max(contacts.impulse[c] + (target - vn) / k, wp.float64(0.0))
                dj = total - contacts.impulse[c]
                contacts.impulse[c] = total
                push(motion, f, x, dj * n)
                if other >= 0:
                    push(motion, other, x, -dj * n)
                # friction: the tangential slip stopped, within mu times the normal impulse
                v_rel = velocity_at(motion, f, x) - partner_velocity(motion, contacts, solids, poses, j, x, float(h))
                slip = v_rel - wp.dot(v_rel, n) * n
                speed = wp.length(slip)
                if speed > wp.float64(1.0e-12):
                    t = slip / speed
                    kt = response(motion, f, x, t)
                    if other >= 0:
                        kt += response(motion, other, x, t)
                    if kt > wp.float64(0.0):
                        old = contacts.friction_impulse[c]
                        want = old - (speed / kt) * t
                        limit = motion.friction[f] * contacts.impulse[c]
                        size = wp.length(want)
                        if size > limit:
                            want = want * (limit / size)
                        contacts.friction_impulse[c] = want
                        push(motion, f, x, want - old)
                        if other >= 0:
                            push(motion, other, x, old - want)
