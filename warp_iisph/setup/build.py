"""A validated scene turned into particles on a device: fluid, walls, obstacles, boundary psi."""

from __future__ import annotations

import os

import numpy as np
import warp as wp

from ..scene import Box, Scene, shape_mesh
from ..sph.neighbors import cell_order, make_grid
from .boundary import compute_boundary_psi, overcompressed
from .model import Model, State
from .rasterize import clear_fluid, sample_mesh
from .sampling import sample_fluid, sample_tank_walls


# Largest initial compression (fraction of rho0) a fluid particle beside a mesh may start with.
INITIAL_COMPRESSION = 0.005


def build_model(scene: Scene, device) -> tuple[Model, State]:
    """Sample a validated scene into particles and upload them to ``device``."""
    device = wp.get_device(device)
    h = scene.spacing
    ph = scene.physics
    meshes = _shape_meshes(scene)
    _check_memory(*(int(c) for c in scene.particle_estimate()), device)  # before sampling allocates anything
    xf, xb = sample_scene(scene, device, meshes)
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
        physics=ph,
        n_fluid=n,
        spacing=h,
        support_radius=H,
        mass=ph.rho0 * h**3,
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


def _shape_meshes(scene: Scene) -> dict:
    """The triangle mesh of every mesh tank and obstacle, built or read once, by ``id`` of the shape."""
    shapes = ([] if isinstance(scene.tank, Box) else [scene.tank]) + list(scene.obstacles)
    return {id(s): shape_mesh(s) for s in shapes}


def sample_scene(scene: Scene, device, meshes: dict) -> tuple[np.ndarray, np.ndarray]:
    """Fluid and boundary particles of a scene (``meshes``: its shapes' meshes, from
    :func:`_shape_meshes`). A scene without obstacles and with a box tank costs no mesh work;
    fluid overlapping an obstacle or outside a mesh container is dropped."""
    h = scene.spacing
    box_tank = isinstance(scene.tank, Box)
    xf = sample_fluid(scene.fluids, scene.tank if box_tank else None, h)
    walls = [sample_tank_walls(scene.tank, h)] if box_tank else []
    shapes = ([] if box_tank else [scene.tank]) + list(scene.obstacles)
    if not shapes:
        return xf, walls[0]
    trimeshes = [meshes[id(s)] for s in shapes]
    sampled = [sample_mesh(m.vertices, m.faces, h, device) for m in trimeshes]
    solids = [(m.vertices, m.faces) for m, o in zip(trimeshes, shapes) if o is not scene.tank and m.is_watertight and not getattr(o, "shell", False)]
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


def _check_memory(n_fluid: int, n_boundary: int, device) -> None:
    need = n_fluid * BYTES_PER_FLUID_PARTICLE + n_boundary * BYTES_PER_BOUNDARY_PARTICLE
    if device.is_cuda:
        free = device.free_memory
    else:
        try:
            free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return
    if need > free:
        raise ValueError(
            f"spacing: {n_fluid} fluid and {n_boundary} boundary particles need about "
            f"{need / 2**30:.1f} GiB but {free / 2**30:.1f} GiB is free on {device}; increase spacing"
        )
