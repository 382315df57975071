"""A validated scene turned into particles on a device: fluid, walls, obstacles, free bodies,
boundary psi. Boundary particles are ordered still ones (cell-sorted), then the keyframed
obstacles', then each free body's (contiguous: its range for the force sums)."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..engine.memory import host_memory_room
from ..scene import Box, MeshShape, Scene, shape_mesh
from ..sph.bodies import MovingBodies
from ..sph.containment import Containment
from ..sph.neighbors import FIRST_STRIDE, LIST_ENTRIES_LIMIT, cell_order, make_grid
from ..sph.rigid import RigidBodies
from .bodies import sample_body
from .boundary import compute_boundary_psi, overcompressed
from .model import Model, State
from .rasterize import CLEAR, NO_ROOM, fluid_room, oriented, sample_mesh, surface_layers
from .sampling import sample_box_faces, sample_fluid, sample_tank_walls

# Largest initial compression (fraction of rho0) a fluid particle beside a mesh may start with.
INITIAL_COMPRESSION = 0.005
# A mesh container whose liquid keeps less than this share of its blocks' lattice sites in it is
# warned of (Model.setup_warnings).
CONTAINER_SHARE = 0.9


def build_model(scene: Scene, device, until: float | None = None) -> tuple[Model, State]:
    """Sample a validated scene into particles and upload them to ``device``, with room for what
    its emitters inject until ``until`` seconds (default: ``output.duration``)."""
    device = wp.get_device(device)
    h = scene.spacing
    ph = scene.physics
    meshes = _shape_meshes(scene)
    _check_memory(*(int(c) for c in scene.particle_estimate()), device)  # before sampling allocates anything
    free = [sample_body(b, h, ph.rho0, device) for b in scene.bodies]
    xf, xb, bodies, owner, inside = sample_scene(scene, device, meshes, free)
    if len(xf) == 0 and not scene.emitters:
        raise ValueError(f"fluids: no particle fits at spacing = {h} m; make the blocks larger or the spacing smaller")
    n_moving = sum(len(rest) for _, rest in bodies) + sum(len(f["rest"]) for f in free)
    _check_memory(len(xf), len(xb) + n_moving, device)
    H = 2.0 * h
    xb_dev, owner = _cell_sorted(xb, H, device, owner)
    psi = compute_boundary_psi(xb_dev, h, ph.rho0, device)
    moving = rigid = None
    if bodies or free:
        # a body's psi comes from its own particles (rigid: it never changes); the walls keep theirs
        rests = [r for _, r in bodies] + [f["rest"] for f in free]
        rest = np.concatenate(rests)
        body_of = np.concatenate([np.full(len(r), k) for k, r in enumerate(rests)])
        psis = [psi.numpy()[: len(xb)]] + [
            compute_boundary_psi(
                wp.array(r.astype(np.float32), dtype=wp.vec3, device=device), h, ph.rho0, device
            ).numpy()[: len(r)]
            for r in rests
        ]
        at_start = np.concatenate([_placed(m, r, 0.0) for m, r in bodies] + [f["rest"] + f["com"] for f in free])
        xb_dev = wp.array(np.concatenate([xb_dev.numpy(), at_start]).astype(np.float32), dtype=wp.vec3, device=device)
        psi = wp.array(np.concatenate(psis).astype(np.float32), dtype=float, device=device)
        moving = MovingBodies([m for m, _ in bodies], rest, body_of, len(xb), device, n_free=len(free))
        # a moving obstacle's particles belong to it; a free body's to no obstacle (-1)
        movers = [k for k, o in enumerate(scene.obstacles) if o.motion is not None] + [-1] * len(free)
        owner = np.concatenate([owner, np.asarray(movers, dtype=np.int32)[body_of]])
    containment = _containment(scene, meshes, h, moving, free, device)
    if free:
        counts = [len(f["rest"]) for f in free]
        first = len(xb) + sum(len(r) for _, r in bodies) + np.concatenate([[0], np.cumsum(counts)[:-1]])
        for f, b in zip(free, scene.bodies):
            f["name"] = b.name
        box = _tank_faces(scene)
        rigid = RigidBodies(free, first.tolist(), len(bodies), ph.gravity, h, box, containment.solids.count, device)
    if scene.obstacles or scene.bodies or not isinstance(scene.tank, Box):
        # Rasterised meshes are not a calibrated wall: fluid sampled where they make it denser
        # than rest is left out rather than kicked away in the first step.
        xf = xf[~overcompressed(xf, xb_dev, psi, h, ph.rho0, INITIAL_COMPRESSION, device)]
    notes = []
    if inside and len(xf) < CONTAINER_SHARE * inside:
        notes.append(
            f"tank: the liquid starts with {len(xf)} of the {inside} lattice sites its blocks have in the container "
            f"({100 * len(xf) / inside:.0f} %): the sites closer than a spacing to the container's wall particles "
            "(within about h/2 of a curved wall, the lattice not lying along it) and made denser than rest "
            "beside it are left out, so the liquid stands lower than the blocks say; a finer spacing loses less "
            "(docs/scenes.md, The tank)"
        )
    lo, hi = scene.tank.bounds
    # A box tank's walls start h/2 outside its faces; a mesh container's cells reach h outside.
    margin = 0.5 * h if isinstance(scene.tank, Box) else 2.0 * h
    n = len(xf)
    if scene.max_particles is not None and n > scene.max_particles:
        raise ValueError(f"max_particles = {scene.max_particles}: below the {n} fluid particles the scene starts with")
    capacity = max(n, int(np.ceil(scene.capacity_estimate(h, n, until))), 1)
    _check_memory(capacity, len(xb) + n_moving, device)
    containment.reserve(capacity)
    model = Model(
        device=device,
        physics=ph,
        n_fluid=n,
        spacing=h,
        support_radius=H,
        mass=ph.rho0 * h**3,
        boundary_x=xb_dev,
        boundary_psi=psi,
        boundary_v=wp.zeros(max(xb_dev.shape[0], 1), dtype=wp.vec3, device=device),
        boundary_a=wp.zeros(max(xb_dev.shape[0], 1), dtype=wp.vec3, device=device),
        boundary_owner=wp.array((owner if len(owner) else np.full(1, -1)).astype(np.int32), device=device),
        bodies=moving,
        rigid=rigid,
        containment=containment,
        domain_lower=lo - margin,
        domain_upper=hi + margin,
        capacity=capacity,
        setup_warnings=notes,
    )
    x = np.zeros((capacity, 3), dtype=np.float32)
    x[:n] = xf
    ids = np.arange(capacity, dtype=np.int32)
    state = State(
        x=wp.array(x, dtype=wp.vec3, device=device),
        v=wp.zeros(capacity, dtype=wp.vec3, device=device),
        rho=wp.full(capacity, ph.rho0, dtype=float, device=device),
        p=wp.zeros(capacity, dtype=float, device=device),
        id=wp.array(ids, dtype=wp.int32, device=device),
        count=n,
        next_id=n,
    )
    return model, state


def _containment(scene: Scene, meshes: dict, h: float, moving, free: list, device) -> Containment:
    """The walls fluid may never cross: the box tank's faces, or the container mesh, every closed
    obstacle (open ``shell`` meshes have no inside to keep fluid out of) and every free body (its
    mesh from its centre of mass, in its pose)."""
    solids = []
    if not isinstance(scene.tank, Box):  # its wall, the inner boundary layer, h/2 outside its surface
        m = meshes[id(scene.tank)]
        solids.append((m.vertices, m.faces, -1, True, 0.5 * h))
    body = 0
    for o in scene.obstacles:
        m = meshes[id(o)]
        k = -1
        if o.motion is not None:
            k, body = body, body + 1
        if m.is_watertight and not getattr(o, "shell", False):
            # an obstacle sampled in layers has its wall, the inner boundary layer, h/2 inside its
            # faces (the surface where it is thinner: Containment); one sampled on its cells, its
            # surface
            solids.append((m.vertices, m.faces, k, False, 0.5 * h if _layered(o, m) else 0.0))
    for f in free:
        solids.append((f["vertices"], f["faces"], body, False))
        body += 1
    # a box tank's wall is its inner layer of boundary particles, h/2 beyond the faces (the fluid's
    # first layer rests h/2 inside them): a particle past that layer has gone through the wall
    box = None
    if isinstance(scene.tank, Box):
        lo, hi = scene.tank.bounds
        box = (lo - 0.5 * h, hi + 0.5 * h)
    return Containment(device, box, solids, h, moving)


def _tank_faces(scene: Scene):
    """A box tank's faces (lower, upper), which free bodies rest against; None for a mesh tank."""
    return scene.tank.bounds if isinstance(scene.tank, Box) else None


def _shape_meshes(scene: Scene) -> dict:
    """The triangle mesh of every mesh tank and obstacle, built or read once, by ``id`` of the
    shape; a closed one wound outwards (:func:`~warp_iisph.setup.rasterize.oriented`)."""
    shapes = ([] if isinstance(scene.tank, Box) else [scene.tank]) + list(scene.obstacles)
    meshes = {id(s): shape_mesh(s) for s in shapes}
    return {k: oriented(m) if m.is_watertight else m for k, m in meshes.items()}


def _layered(shape, mesh) -> bool:
    """Whether an obstacle is sampled in two layers inside its surface: a closed mesh (not an open
    shell), a sphere, a box sampled by ``faces`` (the default); else (an open shell, a box sampled
    by ``cells``) one particle per cell its faces cross."""
    if isinstance(shape, MeshShape):
        return mesh.is_watertight and not shape.shell
    return getattr(shape, "sampling", "faces") == "faces"


def _placed(motion, points: np.ndarray, time: float) -> np.ndarray:
    """``points`` of a moving body where its motion has them at ``time``."""
    m = motion.matrix(time, np.asarray(motion.pivot))
    return points @ m[:3, :3].T + m[:3, 3]


def sample_scene(
    scene: Scene, device, meshes: dict, free: list = ()
) -> tuple[np.ndarray, np.ndarray, list, np.ndarray, int | None]:
    """Fluid particles, the static boundary particles (tank and still obstacles) and, per moving
    obstacle, its motion and its boundary particles where the scene places it (``meshes``: the
    shapes' meshes, from :func:`_shape_meshes`; ``free``: the free bodies as :func:`sample_body`
    samples them), and which shape each static boundary particle belongs to (its obstacle's index,
    -1 for the tank). A scene without obstacles and bodies and with a box tank costs no mesh work;
    fluid overlapping an obstacle or a body (where it is at t = 0) or outside a mesh container is
    dropped; last, how many lattice sites lay in a mesh container before those closer than a
    spacing to its walls' particles were left out (None for a box tank)."""
    h = scene.spacing
    box_tank = isinstance(scene.tank, Box)
    xf = sample_fluid(scene.fluids, scene.tank if box_tank else None, h)
    walls = [sample_tank_walls(scene.tank, h)] if box_tank else []
    shapes = ([] if box_tank else [scene.tank]) + list(scene.obstacles)
    if not shapes and not free:
        return xf, walls[0], [], np.full(len(walls[0]), -1, dtype=np.int32), None
    trimeshes = [meshes[id(s)] for s in shapes]
    # the tank's mesh in layers outside it; a box sampled by faces in layers inside its faces, as
    # the tank's walls are; other closed obstacles (meshes, spheres, boxes thinner than those
    # layers need) in layers inside their surface; open shells and boxes sampled by cells on the
    # cells their faces cross
    sampled = [
        surface_layers(m.vertices, m.faces, h, device, -1.0)[0]
        if s is scene.tank
        else sample_box_faces(s, h)
        if isinstance(s, Box) and s.sampling == "faces" and not s.too_thin_for_faces(h)
        else surface_layers(m.vertices, m.faces, h, device, 1.0)[0]
        if _layered(s, m)
        else sample_mesh(m.vertices, m.faces, h, device)
        for s, m in zip(shapes, trimeshes)
    ]
    labels = ([] if box_tank else [-1]) + list(range(len(scene.obstacles)))
    # where everything is at t = 0: moving bodies as their first keyframe places them
    start = [_placed(o.motion, x, 0.0) if getattr(o, "motion", None) else x for x, o in zip(sampled, shapes)]
    start += [f["rest"] + f["com"] for f in free]
    solids = [
        (_placed(o.motion, np.asarray(m.vertices), 0.0) if getattr(o, "motion", None) else m.vertices, m.faces)
        for m, o in zip(trimeshes, shapes)
        if o is not scene.tank and m.is_watertight and not getattr(o, "shell", False)
    ]
    solids += [(f["vertices"] + f["com"], f["faces"]) for f in free]
    containers = [] if box_tank else [(trimeshes[0].vertices, trimeshes[0].faces)]
    room = fluid_room(xf, np.concatenate(start), solids, h, containers, device)
    # the lattice sites in a container, before those beside its walls are left out
    inside = int(np.sum(room != NO_ROOM)) if containers else None
    xf = xf[room == CLEAR]
    still = walls + [x for x, o in zip(sampled, shapes) if not getattr(o, "motion", None)]
    owner = [np.full(len(w), -1) for w in walls] + [
        np.full(len(x), k) for x, o, k in zip(sampled, shapes, labels) if not getattr(o, "motion", None)
    ]
    bodies = [(o.motion, x) for x, o in zip(sampled, shapes) if getattr(o, "motion", None)]
    if not still:
        return xf, np.zeros((0, 3)), bodies, np.zeros(0, dtype=np.int32), inside
    return xf, np.concatenate(still), bodies, np.concatenate(owner).astype(np.int32), inside


def _cell_sorted(points: np.ndarray, H: float, device, labels: np.ndarray) -> tuple[wp.array, np.ndarray]:
    """Upload points sorted by hash-grid cell, so that neighbouring walls are close in memory;
    ``labels`` (one per point) in the same order."""
    arr = wp.array(points.astype(np.float32), dtype=wp.vec3, device=device)
    if len(points) == 0:
        return arr, labels
    grid = make_grid(device)
    grid.build(arr, H)
    order = wp.zeros(len(points), dtype=wp.int32, device=device)
    wp.launch(cell_order, dim=len(points), inputs=[grid.id, order], device=device)
    order = order.numpy()
    return wp.array(points[order].astype(np.float32), dtype=wp.vec3, device=device), labels[order]


# Bytes per fluid particle: state, solver scratch and about 40 neighbour entries of 20 bytes
# (index, grad W, W).
BYTES_PER_FLUID_PARTICLE = 1100
BYTES_PER_BOUNDARY_PARTICLE = 40


def _check_memory(n_fluid: int, n_boundary: int, device) -> None:
    """Refuse (``ValueError``) a liquid the memory this process may still take on the device cannot
    hold (on the host: free memory, the control group's limit and ulimit, see engine.memory), or whose fluid
    lists at their first stride would need more entries than 32-bit indices address."""
    need = n_fluid * BYTES_PER_FLUID_PARTICLE + n_boundary * BYTES_PER_BOUNDARY_PARTICLE
    room = (device.free_memory, "free") if device.is_cuda else host_memory_room()
    if room is not None and need > room[0]:
        raise ValueError(
            f"spacing: {n_fluid} fluid and {n_boundary} boundary particles need about "
            f"{need / 2**30:.2f} GiB but {room[0] / 2**30:.2f} GiB is {room[1]} on {device}; increase spacing"
        )
    if n_fluid * FIRST_STRIDE > LIST_ENTRIES_LIMIT:
        raise ValueError(
            f"spacing: {n_fluid:,} fluid particles need more neighbour-list entries than 32-bit indices "
            f"address ({LIST_ENTRIES_LIMIT:,}); increase spacing"
        )
