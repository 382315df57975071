"""Model (what a run does not change, on one device) and State (what every step changes)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import warp as wp

from ..engine.launch import launch_particles
from ..scene import Physics
from ..sph.bodies import MovingBodies
from ..sph.containment import Containment
from ..sph.rigid import RigidBodies

wp.set_module_options({"enable_backward": False})  # never differentiated: no adjoint code to compile


@dataclass
class Model:
    """Everything a solver needs that does not change during a run.

    ``physics`` is the scene's validated physics (rest density, gravity, viscosities and the
    solver's settings are read from it, never copied). ``spacing`` is the particle diameter h,
    ``support_radius`` the kernel's support 2h, ``mass`` = rho0 h^3. ``domain_lower/upper``
    bound where particles may go: a particle beyond them has left the tank.
    """

    device: object
    physics: Physics
    n_fluid: int  # at the start; the state's count changes with emitters and sinks
    spacing: float
    support_radius: float
    mass: float
    boundary_x: wp.array
    boundary_psi: wp.array
    domain_lower: np.ndarray
    domain_upper: np.ndarray
    boundary_v: wp.array = None  # zero for still walls; moving obstacles' particles carry their velocity
    boundary_a: wp.array = None  # and their acceleration (the walls' extrapolated pressure uses it)
    boundary_owner: wp.array = None  # each boundary particle's obstacle (its index in the scene), -1: the tank
    bodies: Optional[MovingBodies] = None  # the moving obstacles and free bodies: the last boundary particles
    rigid: Optional[RigidBodies] = None  # the free bodies' dynamics (their particles are the last ones)
    containment: Optional[Containment] = None  # the walls no particle may be beyond after a step
    capacity: int = 0  # fluid particles the arrays hold at most (more than n_fluid with emitters)
    setup_warnings: list = field(default_factory=list)  # what the set-up says its user should know

    @property
    def n_boundary(self) -> int:
        return 0 if self.boundary_x is None else int(self.boundary_x.shape[0])

    @property
    def n_still(self) -> int:
        """Boundary particles that never move (the first ones)."""
        return self.n_boundary if self.bodies is None else self.bodies.first


@wp.kernel
def gather_vec3(
    offset: int, order: wp.array(dtype=wp.int32), src: wp.array(dtype=wp.vec3), dst: wp.array(dtype=wp.vec3)
):
    i = wp.tid() + offset
    dst[i] = src[order[i]]


@wp.kernel
def gather_float(offset: int, order: wp.array(dtype=wp.int32), src: wp.array(dtype=float), dst: wp.array(dtype=float)):
    i = wp.tid() + offset
    dst[i] = src[order[i]]


@wp.kernel
def gather_int(
    offset: int, order: wp.array(dtype=wp.int32), src: wp.array(dtype=wp.int32), dst: wp.array(dtype=wp.int32)
):
    i = wp.tid() + offset
    dst[i] = src[order[i]]


_GATHER = {wp.vec3: gather_vec3, wp.float32: gather_float, wp.int32: gather_int}


def id_order(ids: np.ndarray) -> np.ndarray:
    """The permutation that puts particles in the order of their ids (unique): a scatter when
    they are 0..n-1 (no emitter or sink has changed them; a tenth of a sort's time at 1M), else
    a sort."""
    n = len(ids)
    if n and int(ids.min()) == 0 and int(ids.max()) == n - 1:
        order = np.empty(n, dtype=np.int64)
        order[ids] = np.arange(n)
        return order
    return np.argsort(ids, kind="stable")


# every State's per-particle fields, in the order its arrays are declared: what reordering moves,
# checkpoints keep and a particle frame is made of (the one list; a solver's own fields are ``carried``)
PARTICLE_FIELDS = ("x", "v", "rho", "p", "id")


@dataclass
class State:
    """Per-particle fluid data: position ``x``, velocity ``v``, density ``rho``, pressure ``p``
    and the particle's identity ``id`` (particles are reordered in memory by grid cell). The
    arrays hold ``capacity`` particles, the first ``count`` of which are the liquid (emitters add
    particles, sinks remove them; ``next_id`` names the next one emitted). ``carried`` holds a
    solver's own per-particle arrays that outlive a step (DFSPH's warm starts): they move with
    the particles, start at zero for emitted ones and go into checkpoints (:meth:`carry`)."""

    x: wp.array
    v: wp.array
    rho: wp.array
    p: wp.array
    id: wp.array
    count: int = -1
    next_id: int = -1
    carried: dict = field(default_factory=dict)
    _scratch: dict = field(default_factory=dict, repr=False)  # reorder's buffers, one per dtype

    def __post_init__(self):
        if self.count < 0:
            self.count = self.capacity
        if self.next_id < 0:
            self.next_id = self.count

    @property
    def n(self) -> int:
        return self.count

    @property
    def capacity(self) -> int:
        return int(self.x.shape[0])

    def carry(self, name: str, array: wp.array) -> None:
        """Keep ``array`` (one value per particle, ``capacity`` long) with the particles."""
        if array.shape[0] != self.capacity or array.dtype not in _GATHER:
            raise ValueError(f"carry {name!r}: needs {self.capacity} values of float32, int32 or vec3")
        self.carried[name] = array

    def clear_carried(self, first: int, count: int) -> None:
        """Zero the carried values of particles ``first .. first + count - 1`` (just emitted)."""
        for array in self.carried.values():
            array[first : first + count].zero_()

    def keep(self, indices: np.ndarray) -> None:
        """Keep only the particles at ``indices`` (in that order): the others leave the liquid."""
        k = len(indices)
        if k:
            order = self._scratch.get("keep")
            if order is None:
                order = self._scratch["keep"] = wp.zeros(self.capacity, dtype=wp.int32, device=self.x.device)
            order[:k].assign(np.asarray(indices, dtype=np.int32))
            self.count = k
            self.reorder(order)
        self.count = k

    def reorder(self, order: wp.array) -> None:
        """Permute every per-particle array in place so that particle i becomes ``order[i]``
        (through one scratch array per type: the arrays keep their memory, which captured
        graphs point at)."""
        n = self.n
        scratch = self._scratch
        for src in [*self.fields().values(), *self.carried.values()]:
            tmp = scratch.get(src.dtype)
            if tmp is None:
                tmp = scratch[src.dtype] = wp.empty_like(src)
            launch_particles(_GATHER[src.dtype], n, [order, src, tmp], src.device)
            wp.copy(src, tmp)

    def fields(self) -> dict[str, wp.array]:
        """The :data:`PARTICLE_FIELDS` by name (each ``capacity`` long)."""
        return {name: getattr(self, name) for name in PARTICLE_FIELDS}

    def numpy_by_id(self, name: str) -> np.ndarray:
        """Host copy of a per-particle array of the liquid, in the order of the particles' ids."""
        return self.host(name)[id_order(self.host("id"))]

    def host(self, name: str) -> np.ndarray:
        """Host copy of the liquid's ``name`` in memory order (see :func:`id_order`), its own
        (the simulation may go on while it is read)."""
        return self._host(name, self.count)

    def _host(self, name: str, count: int) -> np.ndarray:
        """The first ``count`` of ``name`` on the host. From a GPU they come through a
        page-locked buffer kept for it (a copy from pageable memory runs at about half the bus's
        speed)."""
        src = getattr(self, name)
        if not src.device.is_cuda:
            return src.numpy()[:count].copy()  # .numpy() is a view of the live array on the CPU
        key = ("pinned", name)
        buf = self._scratch.get(key)
        if buf is None or buf.shape != src.shape:
            buf = self._scratch[key] = wp.empty(src.shape, dtype=src.dtype, device="cpu", pinned=True)
        if count:
            wp.copy(buf, src, count=count)
            wp.synchronize_device(src.device)
        return buf.numpy()[:count].copy()
