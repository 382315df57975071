"""The last line: after each step, no fluid particle is beyond a wall. A particle past a box
tank's wall (its inner layer of boundary particles, h/2 beyond the faces), inside a closed obstacle
(still or moving) or outside a mesh container is put back on the surface it crossed and loses the
velocity that carried it through (relative to the wall); every such correction is counted in the
step's statistics. As for the tank, a wall is where its inner layer of boundary particles lies:
for an obstacle sampled on the cells its surface crosses, the surface; for one sampled in layers
h/2 and h inside its surface (a closed mesh, a box sampled by faces), h/2 inside it
(``Solids.depth``), so that a particle that touches it, its centre a little past the face but
short of the layer, is the pressure's to push back, as it is at the tank's walls; where such a
solid is thinner than a spacing (its layers meet at its middle), the surface. A free body's wall
stays its surface: no particle's centre may be inside a body. The pressure solver is meant to do
nearly all of this work: the count says how much it left.

Obstacles are queried as ``wp.Mesh`` signed distances, in their own frame (a moving body's
pose at the step's end), only for particles that had wall neighbours at the step's start
(others cannot reach a wall within a CFL-limited step). A free body is also met along the way:
a particle whose path over the step (from ``x - dt v``, in the body's frame at the step's start,
to ``x``, in its frame at the end) enters the body's surface is put back where it entered, so that
a body thinner than a step's relative motion is not crossed either; its velocity is then the
motion it kept over the step (as position-based dynamics sets it), less any part into the body.
Only a path that could reach the surface is traced: one ending within the query's reach (two
spacings) of it, or at least that long (a ray cast per particle and body was 0.57 of the 1.90 ms
a step the flood's last line took).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.launch import launch, launch_particles
from .bodies import MovingBodies, Poses
from .neighbors import NeighborList

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile

# A particle put back lands this far (a fraction of the spacing) on the fluid's side of the surface.
CLEARANCE = 1.0e-3


@wp.struct
class Solids:
    """Closed surfaces fluid may not cross: ``meshes[k]`` (its ``wp.Mesh`` id, in the frame of
    moving body ``body[k]``, -1 for a still one); ``container[k]`` is 1 where the fluid belongs
    inside (a mesh tank), 0 where it belongs outside (an obstacle or a body); ``depth[k]`` how far
    inside the surface its inner layer of boundary particles, the wall, lies (module docstring)."""

    meshes: wp.array(dtype=wp.uint64)
    body: wp.array(dtype=wp.int32)
    container: wp.array(dtype=wp.int32)
    depth: wp.array(dtype=float)  # how far past the surface its wall (inner boundary layer) lies
    center: wp.array(dtype=wp.vec3)  # a sphere holding each surface, in its own frame (contacts cull by it)
    radius: wp.array(dtype=float)
    count: int
    box_lower: wp.vec3
    box_upper: wp.vec3
    has_box: int


@wp.func
def wall_depth(mesh: wp.uint64, face: int, c: wp.vec3, depth: float, container: int) -> float:
    """How far behind surface point ``c`` (on ``face``) the wall lies: ``depth``, or 0 where the
    solid is thinner than twice that (its layers meet at its middle there, and a last line behind
    the surface would lie past it: a particle there is put back onto the surface)."""
    if depth <= 0.0:
        return depth
    into = -wp.mesh_eval_face_normal(mesh, face)  # the solid's side of an obstacle's surface
    if container != 0:
        into = -into
    eps = 1.0e-4 * depth
    ray = wp.mesh_query_ray(mesh, c + eps * into, into, 2.0 * depth)
    if ray.result:
        if ray.t < 2.0 * depth - eps:
            return 0.0
    return depth


@wp.func
def clamp_to_box(x: wp.vec3, v: wp.vec3, lo: wp.vec3, hi: wp.vec3):
    """``x`` inside [lo, hi], the velocity out through a crossed face removed; and whether it moved."""
    moved = int(0)
    for a in range(3):
        if x[a] < lo[a]:
            x[a] = lo[a]
            v[a] = wp.max(v[a], 0.0)
            moved = 1
        elif x[a] > hi[a]:
            x[a] = hi[a]
            v[a] = wp.min(v[a], 0.0)
            moved = 1
    return x, v, moved


@wp.func
def entered(mesh: wp.uint64, a: wp.vec3, e: wp.vec3):
    """Whether the path from ``a`` to ``e`` (outside at ``a``) enters the closed ``mesh``, and where."""
    d = e - a
    length = wp.length(d)
    hit = int(0)
    c = e
    n = wp.vec3(0.0)
    if length > 0.0:
        q = wp.mesh_query_ray(mesh, a, d / length, length)
        if q.result:
            if wp.dot(q.normal, d) < 0.0:
                hit = 1
                c = a + q.t * (d / length)
                n = wp.normalize(q.normal)
    return hit, c, n


@wp.kernel
def contain(
    offset: int,
    x: wp.array(dtype=wp.vec3),
    v: wp.array(dtype=wp.vec3),
    nb: NeighborList,
    solids: Solids,
    poses: Poses,
    dt: wp.array(dtype=wp.float64),
    reach: float,
    clearance: float,
    codes: wp.array(dtype=wp.int32),
):
    """Particle i put back within the walls; ``codes[i]``: bit 0 set when put back inside the
    tank, bit 1 when out of an obstacle or a body (no atomics: the launch is split over CPU
    threads, :func:`count_codes` counts them)."""
    i = offset + wp.tid()
    x_i = x[i]
    v_i = v[i]
    code = int(0)
    if solids.has_box != 0:
        x_i, v_i, moved = clamp_to_box(x_i, v_i, solids.box_lower, solids.box_upper)
        if moved != 0:
            code = 1
    if nb.count[i] > 0:
        h = float(dt[0])
        for k in range(solids.count):
            b = solids.body[k]
            frame = wp.transform_identity()
            if b >= 0:
                frame = poses.end[b]
            p = wp.transform_point(wp.transform_inverse(frame), x_i)
            q = wp.mesh_query_point_sign_normal(solids.meshes[k], p, reach)
            escaped = int(0)
            through = int(0)
            c = p
            n = wp.vec3(0.0)
            if q.result:
                inside = q.sign < 0.0
                if solids.container[k] != 0:
                    inside = q.sign >= 0.0
                if inside:
                    c = wp.mesh_eval_position(solids.meshes[k], q.face, q.u, q.v)
                    past = wp.length(c - p)
                    wall = wall_depth(solids.meshes[k], q.face, c, solids.depth[k], solids.container[k])
                    if past > wall:
                        escaped = 1
                        n = wp.normalize(c - p)  # towards the fluid's side
                        c = c - wall * n  # on the wall
            if escaped == 0 and b >= 0:
                if poses.free[b] != 0:  # through a free body within the step
                    a = wp.transform_point(wp.transform_inverse(poses.start[b]), x_i - h * v_i)
                    # a path shorter than its end's distance to the surface (beyond ``reach`` where
                    # the query found none) stays outside: only the others are traced
                    if q.result or wp.length(p - a) >= reach:
                        escaped, c, n = entered(solids.meshes[k], a, p)
                        through = escaped
            if escaped != 0:
                x_new = wp.transform_point(frame, c + clearance * n)
                n_world = wp.transform_vector(frame, n)
                v_wall = wp.vec3(0.0)
                if b >= 0:
                    v_wall = (x_new - wp.transform_point(poses.start[b], c)) / h
                if through != 0:
                    # put back where its path entered: the motion past that point is undone, so the
                    # velocity is the motion kept (else a particle pinned there keeps the velocity its
                    # pressure gives it, step after step, and runs away where it stands)
                    v_i = (x_new - (x_i - h * v_i)) / h
                vn = wp.dot(v_i - v_wall, n_world)
                if vn < 0.0:
                    v_i = v_i - vn * n_world
                x_i = x_new
                code = code | 2
    x[i] = x_i
    v[i] = v_i
    codes[i] = code


@wp.kernel
def count_codes(codes: wp.array(dtype=wp.int32), corrections: wp.array(dtype=wp.int32)):
    """corrections[0]: particles :func:`contain` put back inside the tank; corrections[1]: out of
    obstacles and bodies (an atomic only where a particle was put back: few, on any device)."""
    c = codes[wp.tid()]
    if c & 1 != 0:
        wp.atomic_add(corrections, 0, 1)
    if c & 2 != 0:
        wp.atomic_add(corrections, 1, 1)


def _bounding_spheres(vertices: list, device) -> tuple:
    """Each surface's bounding sphere: the centre of its vertices' box and the farthest vertex
    from it (a triangle lies within the sphere of its corners), grown by a millionth of its size
    and of its distance from the origin against float32's rounding."""
    centers, radii = [], []
    for v in vertices:
        v = np.asarray(v, np.float64).reshape(-1, 3)
        c = 0.5 * (v.min(axis=0) + v.max(axis=0)) if len(v) else np.zeros(3)
        r = float(np.linalg.norm(v - c, axis=1).max()) if len(v) else 0.0
        centers.append(c)
        radii.append(r * (1.0 + 1.0e-6) + 1.0e-6 * (1.0 + float(np.abs(c).max())))
    center = wp.array(np.asarray(centers, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    return center, wp.array(np.asarray(radii, np.float32), dtype=float, device=device)


class Containment:
    """The walls a step's particles are held within: a box tank's faces and the closed meshes
    (obstacles, a mesh container). Built once per model."""

    def __init__(self, device, box=None, meshes=(), spacing: float = 1.0, bodies: MovingBodies | None = None):
        """``box``: (lower, upper) of a box tank, or None; ``meshes``: (vertices, faces, body,
        container[, depth]) per closed surface (vertices where the scene places the shape; depth
        0 unless given)."""
        self.device = device
        self.spacing = float(spacing)
        self._meshes = [
            wp.Mesh(
                points=wp.array(np.asarray(v, np.float32), dtype=wp.vec3, device=device),
                indices=wp.array(np.asarray(f, np.int32).reshape(-1), dtype=wp.int32, device=device),
            )
            for v, f, *_ in meshes
        ]
        s = Solids()
        s.meshes = wp.array(np.array([m.id for m in self._meshes], dtype=np.uint64), dtype=wp.uint64, device=device)
        s.body = wp.array(np.array([m[2] for m in meshes], dtype=np.int32), dtype=wp.int32, device=device)
        s.container = wp.array(np.array([int(m[3]) for m in meshes], dtype=np.int32), dtype=wp.int32, device=device)
        depth = [float(m[4]) if len(m) > 4 else 0.0 for m in meshes]
        s.depth = wp.array(np.array(depth, dtype=np.float32), dtype=float, device=device)
        s.center, s.radius = _bounding_spheres([m[0] for m in meshes], device)
        s.count = len(self._meshes)
        s.has_box = int(box is not None)
        lo, hi = box if box is not None else (np.zeros(3), np.zeros(3))
        s.box_lower, s.box_upper = wp.vec3(*np.asarray(lo, float)), wp.vec3(*np.asarray(hi, float))
        self.solids = s
        self.poses = bodies.poses if bodies is not None else MovingBodies([], np.zeros((0, 3)), [], 0, device).poses
        self.corrections = wp.zeros(2, dtype=wp.int32, device=device)
        self.codes = wp.zeros(0, dtype=wp.int32, device=device)

    def reserve(self, capacity: int) -> None:
        """Room for ``capacity`` particles' codes (the model's: a graph's step never allocates)."""
        if self.codes.shape[0] < capacity:
            self.codes = wp.zeros(capacity, dtype=wp.int32, device=self.device)

    def apply(self, x: wp.array, v: wp.array, nb: NeighborList, n: int, dt: wp.array) -> None:
        """Put the ``n`` particles back within the walls, counting into ``corrections`` (zeroed here)."""
        self.corrections.zero_()
        if n:
            if self.codes.shape[0] < n and wp.get_device(self.device).is_capturing:
                raise RuntimeError("Containment: reserve the particles' codes before a graph is captured")
            self.reserve(n)
            inputs = [x, v, nb, self.solids, self.poses, dt, 2.0 * self.spacing, CLEARANCE * self.spacing, self.codes]
            launch_particles(contain, n, inputs, self.device)
            launch(count_codes, dim=n, inputs=[self.codes, self.corrections], device=self.device)
