"""Model (static data on one device) and State (what changes every step)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from .boundary import compute_boundary_psi
from .launch import launch_particles
from .neighbors import cell_order, make_grid
from .sampling import sample_fluid, sample_tank_walls
from .scene import Scene


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

    @property
    def n(self) -> int:
        return int(self.x.shape[0])

    def reorder(self, order: wp.array) -> None:
        """Permute every per-particle array so that particle i becomes ``order[i]``."""
        n = self.n
        for name in ("x", "v", "rho", "p", "id"):
            src = getattr(self, name)
            dst = wp.empty_like(src)
            launch_particles(_GATHER[src.dtype], n, [order, src, dst], src.device)
            setattr(self, name, dst)

    def numpy_by_id(self, name: str) -> np.ndarray:
        """Host copy of a per-particle array in original particle order."""
        values = getattr(self, name).numpy()
        out = np.empty_like(values)
        out[self.id.numpy()] = values
        return out


def build_model(scene: Scene, device) -> tuple[Model, State]:
    """Sample the scene into particles and upload them to ``device``."""
    scene.validate()
    device = wp.get_device(device)
    h = scene.spacing
    ph = scene.physics
    xf = sample_fluid(scene.fluids, scene.tank, h)
    if len(xf) == 0:
        raise ValueError(f"fluids: no particle fits at spacing = {h} m; make the blocks larger or the spacing smaller")
    xb = sample_tank_walls(scene.tank, h)
    _check_memory(len(xf), len(xb), device)
    H = 2.0 * h
    xb_dev = _cell_sorted(xb, H, device)
    psi = compute_boundary_psi(xb_dev, h, ph.rho0, device)
    lo, hi = scene.tank.bounds
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
        domain_lower=lo - 0.5 * h,
        domain_upper=hi + 0.5 * h,
    )
    state = State(
        x=wp.array(xf.astype(np.float32), dtype=wp.vec3, device=device),
        v=wp.zeros(n, dtype=wp.vec3, device=device),
        rho=wp.full(n, ph.rho0, dtype=float, device=device),
        p=wp.zeros(n, dtype=float, device=device),
        id=wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=device),
    )
    return model, state


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
            import os

            free = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return
    if need > free:
        raise ValueError(
            f"spacing: {n_fluid} fluid and {n_boundary} boundary particles need about "
            f"{need / 2**30:.1f} GiB but {free / 2**30:.1f} GiB is free on {device}; increase spacing"
        )
