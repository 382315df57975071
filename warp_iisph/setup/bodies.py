"""Free bodies as boundary particles: each body's particles lie half a spacing inside its surface,
as a box tank's inner layer lies half a spacing outside the tank's faces (``sampling``), so the
liquid resting against a body has its first layer of particles half a spacing outside the surface
and fills the space the body leaves exactly: a floating body displaces what its surface encloses.
Where the body is thick enough a second layer lies a spacing inside, staggered, as the tank's
outer layer (a fast particle aimed at a gap of the first meets one behind it).

- A box: the lattice of the tank's walls, turned inside out (``_box_shell`` with negative offsets).
- A sphere: two Fibonacci spheres of radii ``r - h/2`` and ``r - h``, about one particle per ``h^2``.
- A mesh: the rasterised surface (``rasterize.sample_mesh``, one particle per cell it crosses),
  each particle moved to the closest surface point and from there inwards by ``h/2`` (``h``), or
  to the middle of a part thinner than a spacing; particles closer than ``h/2`` to one kept are
  dropped.

Each particle's ``depth`` below the surface is kept: the contacts' samples (``sph.contacts``).
"""

from __future__ import annotations

import numpy as np

from .rasterize import oriented, surface_layers
from .sampling import _box_shell


def sample_body(body, h: float, rho0: float, device) -> dict:
    """A :class:`~warp_iisph.scene.bodies.Body`'s particles (from its centre of mass, in the
    world's axes as the scene places it), their depths, its mass properties and starting motion,
    and its mesh (vertices from the centre of mass) for the containment and the viewers."""
    from ..scene import Box, Sphere

    mass, com, inertia = body.mass_properties()
    shape = body.shape
    mesh = oriented(body.mesh())
    if isinstance(shape, Box):
        points, depth = _box_layers(*shape.bounds, h)
    elif isinstance(shape, Sphere):
        points, depth = _sphere_layers(np.asarray(shape.center, np.float64), shape.radius, h)
    else:
        points, depth = surface_layers(mesh.vertices, mesh.faces, h, device, sign=1.0)
    added_mass, added_inertia = added_inertias(mesh, mass, inertia, rho0)
    return {
        "added_mass": added_mass,
        "added_inertia": added_inertia,
        "rest": points - com,
        "depth": depth,
        "mass": mass,
        "com": com,
        "inertia": inertia,
        "velocity": np.asarray(body.velocity, np.float64),
        "angular_velocity": np.asarray(body.angular_velocity, np.float64),
        "fixed_axes": list(body.fixed_axes),
        "restitution": float(body.restitution),
        "friction": float(body.friction),
        "release_time": float(body.release_time),
        "vertices": np.asarray(mesh.vertices, np.float64) - com,
        "faces": np.asarray(mesh.faces, np.int32),
    }


# the added mass of a body moving along an axis, in rho0 A^(3/2) (A: its area projected across the
# motion): a cube's face on (0.68, DNV-RP-H103 Table A-2), the largest of the cube, the disc
# broadside (0.48) and the sphere (0.38)
ADDED_MASS = 0.68


def added_inertias(mesh, mass: float, inertia: np.ndarray, rho0: float) -> tuple[np.ndarray, np.ndarray]:
    """The coupling's estimate of the liquid's added mass (per body axis) and added inertia of a
    body wholly under the liquid: ``ADDED_MASS rho0 A^(3/2)`` along each axis, and the body's own
    inertia scaled as its mass is by the largest of them."""
    normals = np.asarray(mesh.face_normals, np.float64)
    areas = np.asarray(mesh.area_faces, np.float64)
    projected = 0.5 * np.abs(normals).T @ areas  # a closed surface's silhouette across each axis
    added = ADDED_MASS * rho0 * projected**1.5
    return np.diag(added), np.asarray(inertia) * (float(added.max()) / mass)


def _box_layers(lo: np.ndarray, hi: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The lattice shells ``h/2`` and ``h`` inside a box; along an axis shorter than two spacings
    the first layer is its middle plane and there is no second."""
    size = hi - lo
    if np.all(size >= 2.0 * h):
        outer = _box_shell(lo, hi, h, -0.5 * h)
        depth = [np.full(len(outer), 0.5 * h)]
        layers = [outer]
        if np.all(size >= 4.0 * h):
            inner = _box_shell(lo, hi, h, -h)
            layers.append(inner)
            depth.append(np.full(len(inner), h))
        return np.concatenate(layers), np.concatenate(depth)
    # a plate or a rod: one layer in the middle of each thin axis
    axes = []
    for a in range(3):
        if size[a] < 2.0 * h:
            axes.append(np.array([0.5 * (lo[a] + hi[a])]))
        else:
            n = int(np.ceil(size[a] / h - 1e-6))
            axes.append(np.linspace(lo[a] + 0.5 * h, hi[a] - 0.5 * h, n))
    g = np.meshgrid(*axes, indexing="ij")
    idx = np.meshgrid(*[np.arange(len(ax)) for ax in axes], indexing="ij")
    shell = np.zeros(g[0].shape, dtype=bool)
    for a in range(3):
        if len(axes[a]) > 1:
            shell |= (idx[a] == 0) | (idx[a] == len(axes[a]) - 1)
        else:
            shell |= True
    points = np.stack([c[shell] for c in g], axis=1)
    return points, np.full(len(points), 0.5 * float(np.min(size)))


def _fibonacci(radius: float, h: float, turn: float) -> np.ndarray:
    n = max(int(round(4.0 * np.pi * radius * radius / (h * h))), 1)
    k = np.arange(n) + 0.5
    y = 1.0 - 2.0 * k / n
    r = np.sqrt(np.maximum(1.0 - y * y, 0.0))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k + turn
    return radius * np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


def _sphere_layers(center: np.ndarray, radius: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    layers, depth = [_fibonacci(radius - 0.5 * h, h, 0.0)], [0.5 * h]
    if radius - h >= 1.5 * h:
        layers.append(_fibonacci(radius - h, h, 0.5 * np.pi * (3.0 - np.sqrt(5.0))))
        depth.append(h)
    return (
        np.concatenate(layers) + center,
        np.concatenate([np.full(len(p), d) for p, d in zip(layers, depth)]),
    )
