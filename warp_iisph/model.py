"""Model (static data on one device) and State (what changes every step)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .boundary import compute_boundary_psi, overcompressed
from .launch import launch_particles
from .neighbors import cell_order, make_grid
from .mesh_sampling import clear_fluid, sample_mesh
from .sampling import sample_fluid, sample_tank_walls
from .scene import Box, Scene, shape_mesh


@dataclass
class Model:
    """Everything a solver needs that does not change during a run.

    ``spacing`` is the particle diameter h, ``support_radius`` the kernel's support 2h,
    ``mass`` = rho0 h^3. ``domain_lower/upper`` bound where particles may go: a particle
    beyond them has left the tank.
    """

    device: object
    n_fluid: int
    spacing: float
    support_radius: float
    mass: float
    rho0: float
    gravity: np.ndarray
    viscosity: float
    boundary_viscosity: float
    boundary_x: wp.array
    boundary_psi: wp.array
    domain_lower: np.ndarray
    domain_upper: np.ndarray

    @property
    def n_boundary(self) -> int:
        return 0 if self.boundary_x is None else int(self.boundary_x.shape[0])


@wp.kernel
def gather_vec3(offset: int, order: wp.array(dtype=wp.int32), src: wp.array(dtype=wp.vec3), dst: wp.array(dtype=wp.vec3)):
    i = wp.tid() + offset
    dst[i] = src[order[i]]


@wp.kernel
def gather_float(offset: int, order: wp.array(dtype=wp.int32), src: wp.array(dtype=float), dst: wp.array(dtype=float)):
    i = wp.tid() + offset
    dst[i] = src[order[i]]


@wp.kernel
def gather_int(offset: int, order: wp.array(dtype=wp.int32), src: wp.array(dtype=wp.int32), dst: wp.array(dtype=wp.int32)):
    i = wp.tid() + offset
    dst[i] = src[order[i]]


_GATHER = {wp.vec3: gather_vec3, wp.float32: gather_float, wp.int32: gather_int}


@dataclass
class State:
    """Per-particle fluid data: position ``x``, velocity ``v``, density ``rho``, pressure ``p``
    and the particle's original index ``id`` (particles are reordered in memory by grid cell)."""

    x: wp.array
    v: wp.array
    rho: wp.array
    p: wp.array
    id: wp.array
    _scratch: dict = field(default_factory=dict, repr=False)  # reorder's buffers, one per dtype

    @property
    def n(self) -> int:
        return int(self.x.shape[0])

    def reorder(self, order: wp.array) -> None:
        """Permute every per-particle array in place so that particle i becomes ``order[i]``
        (through one scratch array per type: the arrays keep their memory, which captured
        graphs point at)."""
        n = self.n
        scratch = self._scratch
        for name in ("x", "v", "rho", "p", "id"):
            src = getattr(self, name)
            tmp = scratch.get(src.dtype)
            if tmp is None:
                tmp = scratch[src.dtype] = wp.empty_like(src)
            launch_particles(_GATHER[src.dtype], n, [order, src, tmp], src.device)
            wp.copy(src, tmp)

    def numpy_by_id(self, name: str) -> np.ndarray:
        """Host copy of a per-particle array in original particle order."""
        values = getattr(self, name).numpy()
        out = np.empty_like(values)
        out[self.id.numpy()] = values
        return out


# Largest initial compression (fraction of rho0) a fluid particle beside a mesh may start with.
INITIAL_COMPRESSION = 0.005


def build_model(scene: Scene, device) -> tuple[Model, State]:
    """Sample the scene into particles and upload them to ``device``."""
    scene.validate()
    device = wp.get_device(device)
    h = scene.spacing
    ph = scene.physics
    _check_memory(*_estimate_counts(scene), device)  # before sampling allocates anything
    xf, xb = sample_scene(scene, device)
    if len(xf) == 0:
        raise ValueError(f"fluids: no particle fits at spacing = {h} m; make the blocks larger or the spacing smaller")
    _check_memory(len(xf), len(xb), device)
    H = 2.0 * h
    xb_dev = _cell_sorted(xb, H, device)
    psi = compute_boundary_psi(xb_dev, h, ph.rho0, device)
    if scene.obstacles or not isinstance(scene.tank, Box):
        # Rasterised meshes are not a calibrated wall: fluid sampled where they make it denser
        # than rest is left out rather than kicked away in the first step.
        xf = xf[~overcompressed(xf, xb_dev, psi, h, ph.rho0, INITIAL_COMPRESSION, device)]
    lo, hi = scene.tank.bounds
    # A box tank's walls start h/2 outside its faces; a mesh container's cells reach h outside.
    margin = 0.5 * h if isinstance(scene.tank, Box) else 2.0 * h
    n = len(xf)
    model = Model(
        device=device,
        n_fluid=n,
        spacing=h,
        support_radius=H,
        mass=ph.rho0 * h**3,
        rho0=ph.rho0,
        gravity=np.asarray(ph.gravity, dtype=np.float64),
        viscosity=ph.viscosity,
        boundary_viscosity=ph.boundary_viscosity,
        boundary_x=xb_dev,
        boundary_psi=psi,
        domain_lower=lo - margin,
        domain_upper=hi + margin,
    )
    state = State(
        x=wp.array(xf.astype(np.float32), dtype=wp.vec3, device=device),
        v=wp.zeros(n, dtype=wp.vec3, device=device),
        rho=wp.full(n, ph.rho0, dtype=float, device=device),
        p=wp.zeros(n, dtype=float, device=device),
        id=wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=device),
    )
    return model, state


def sample_scene(scene: Scene, device) -> tuple[np.ndarray, np.ndarray]:
    """Fluid and boundary particles of a scene. A scene without obstacles and with a box tank
    costs no mesh work; fluid overlapping an obstacle or outside a mesh container is dropped."""
    h = scene.spacing
    box_tank = isinstance(scene.tank, Box)
    xf = sample_fluid(scene.fluids, scene.tank if box_tank else None, h)
    walls = [sample_tank_walls(scene.tank, h)] if box_tank else []
    meshes = ([] if box_tank else [scene.tank]) + list(scene.obstacles)
    if not meshes:
        return xf, walls[0]
    trimeshes = [shape_mesh(m) for m in meshes]
    sampled = [sample_mesh(m.vertices, m.faces, h, device) for m in trimeshes]
    solids = [(m.vertices, m.faces) for m, o in zip(trimeshes, meshes) if o is not scene.tank and m.is_watertight]
    containers = [] if box_tank else [(trimeshes[0].vertices, trimeshes[0].faces)]
    xf = clear_fluid(xf, np.concatenate(sampled), solids, h, containers, device)
    return xf, np.concatenate(walls + sampled)


def _cell_sorted(points: np.ndarray, H: float, device) -> wp.array:
    """Upload points sorted by hash-grid cell, so that neighbouring walls are close in memory."""
    arr = wp.array(points.astype(np.float32), dtype=wp.vec3, device=device)
    if len(points) == 0:
        return arr
    grid = make_grid(device)
    grid.build(arr, H)
    order = wp.zeros(len(points), dtype=wp.int32, device=device)
    wp.launch(cell_order, dim=len(points), inputs=[grid.id, order], device=device)
    return wp.array(points[order.numpy()].astype(np.float32), dtype=wp.vec3, device=device)


# Bytes per fluid particle: state, solver scratch and about 40 neighbour entries of 16 bytes.
BYTES_PER_FLUID_PARTICLE = 900
BYTES_PER_BOUNDARY_PARTICLE = 40


def _estimate_counts(scene: Scene) -> tuple[int, int]:
    """Fluid and boundary particle counts from volumes and areas, without sampling."""
    h = scene.spacing
    volume = 0.0
    for f in scene.fluids:
        lo, hi = f.bounds
        volume += float(np.prod(hi - lo)) if isinstance(f, Box) else 4.0 / 3.0 * np.pi * f.radius**3
    area = 0.0
    for shape in [scene.tank, *scene.obstacles]:
        if isinstance(shape, Box):
            e = np.subtract(*shape.bounds[::-1])
            area += 2.0 * float(e[0] * e[1] + e[1] * e[2] + e[0] * e[2])
        else:
            area += float(shape_mesh(shape).area)
    return int(volume / h**3), int(2.0 * area / h**2)


def _check_memory(n_fluid: int, n_boundary: int, device) -> None:
    need = n_fluid * BYTES_PER_FLUID_PARTICLE + n_boundary * BYTES_PER_BOUNDARY_PARTICLE
    if device.is_cuda:
        free = device.free_memory
    else:
        try:
            import os

            free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return
    if need > free:
        raise ValueError(
            f"spacing: {n_fluid} fluid and {n_boundary} boundary particles need about "
            f"{need / 2**30:.1f} GiB but {free / 2**30:.1f} GiB is free on {device}; increase spacing"
        )
