"""How much of a block of liquid or of a nozzle the spacing's lattice holds, against what the scene
declares: a box holds the whole layers that fit along each side (only ever less), a sphere the
lattice points inside it (more or less, by the shells its radius cuts), a nozzle's layer the
lattice points on it, so an emitter pours its layer's particles, not its area, each spacing. The
run says so before it starts where the difference passes 10 %."""

from __future__ import annotations

import math

import numpy as np

from ..scene.flows import Emitter
from ..scene.shapes import whole_layers

# A block or nozzle whose lattice holds a share of its declared volume or area outside this range
# is warned of.
LATTICE_SHARE = (0.9, 1.1)


def _outside(share: float) -> bool:
    # a hair of tolerance: 0.18 m of a 0.2 m side is 90 % in decimal, a hair less in floating point
    return share < LATTICE_SHARE[0] - 1.0e-9 or share > LATTICE_SHARE[1] + 1.0e-9


def sphere_points(radius: float, h: float) -> int:
    """How many lattice points :func:`.sampling.sample_sphere` places in a sphere (by the same
    comparison), counted a plane of the lattice at a time so that a large sphere costs no memory."""
    n = int(np.ceil(radius / h)) + 1
    k = np.arange(-n, n + 1) * h
    b, c = (g.reshape(-1) for g in np.meshgrid(k, k, indexing="ij"))
    return sum(int(np.sum(np.linalg.norm(np.stack([np.full(b.shape, a), b, c], axis=1), axis=1) < radius)) for a in k)


def sphere_share(radius: float, h: float) -> float:
    """The share of a sphere's volume its lattice points hold (``h^3`` each)."""
    return sphere_points(radius, h) * h**3 / (4.0 / 3.0 * math.pi * radius**3)


def _nearest_exact_radius(radius: float, h: float, dims: int, inclusive: bool, holds=None) -> float | None:
    """The radius nearest ``radius`` (within a quarter of it) at which the lattice points of a ball
    of ``dims`` dimensions (those closer to its centre than its radius, or as close with
    ``inclusive``) fill its volume (its area) exactly, at ``h^dims`` each: each run of radii between
    two shells of the lattice holds one count c, and the radius whose ball c fills exactly is a
    candidate where it falls in that run (and ``holds`` it, where given)."""
    measure = math.pi if dims == 2 else 4.0 / 3.0 * math.pi  # of the unit ball
    n = int(np.ceil(1.25 * radius / h)) + 1
    k = np.arange(-n, n + 1)
    d = np.sqrt(sum(g**2 for g in np.meshgrid(*([k] * dims), indexing="ij"))).ravel()
    shells, counts = np.unique(np.round(d, 9), return_counts=True)
    best = None
    for i, c in enumerate(np.cumsum(counts)[:-1]):
        r = (c / measure) ** (1.0 / dims) * h
        lo, hi = shells[i] * h, shells[i + 1] * h
        within = lo <= r < hi if inclusive else lo < r <= hi
        if within and abs(r - radius) <= 0.25 * radius and (holds is None or holds(r)):
            if best is None or abs(r - radius) < abs(best - radius):
                best = r
    return best


def matching_sphere_radius(radius: float, h: float) -> float | None:
    """The radius nearest ``radius`` (within a quarter of it) whose lattice points hold its volume
    to 1 %: a sphere holds the points closer than its radius to its centre."""
    return _nearest_exact_radius(radius, h, 3, inclusive=False)


def _holding(radius: float, count) -> float:
    """``radius`` to the fewest significant digits (from 4) at which ``count`` (of a radius) gives
    what it gives at ``radius``: a printed radius that holds what the sentence says."""
    for digits in range(4, 16):
        r = float(f"{radius:.{digits}g}")
        if count(r) == count(radius):
            return r
    return radius


def disc_points(radius: float, h: float) -> int:
    """How many points a disc nozzle's layer of ``radius`` has (its facing does not change it)."""
    return Emitter(center=(0.0, 0.0, 0.0), direction=(0.0, -1.0, 0.0), speed=1.0, radius=radius).layer_size(h)


def nozzle_share(emitter: Emitter, h: float) -> tuple[float, float]:
    """(the share of the nozzle's area its layer's particles carry, ``h^2`` each; the area)."""
    if emitter.shape == "disc":
        area = math.pi * emitter.radius**2
    else:
        area = emitter.size[0] * emitter.size[1]
    return emitter.layer_size(h) * h * h / area, area


def matching_disc_radius(radius: float, h: float) -> float | None:
    """The disc radius nearest ``radius`` (within a quarter of it) whose layer carries its area to
    1 %: a layer holds the points as close as its radius to its centre (at least one)."""

    def holds(r: float) -> bool:
        return r >= 0.5 * h and abs(disc_points(r, h) * h * h / (math.pi * r * r) - 1.0) <= 0.01

    return _nearest_exact_radius(radius, h, 2, inclusive=True, holds=holds)


def lattice_shortfalls(scene: dict) -> list[str]:
    """For each block of liquid in a scene table whose lattice holds less than 90 % of it (a box:
    the whole layers that fit along each side, 0.05 m of water at 0.02 m being two layers, 0.04 m)
    or, for a sphere, outside 90-110 %, one sentence naming it."""
    h = scene.get("spacing")
    out = []
    for k, f in enumerate(scene.get("fluids") or ()):
        if not h:
            continue
        if "radius" in f:
            share = sphere_share(f["radius"], h)
            if _outside(share):
                better = matching_sphere_radius(f["radius"], h)
                if better:
                    better = _holding(better, lambda r: sphere_points(r, h))
                out.append(
                    f"fluids[{k}]: the lattice of spacing = {h:g} m holds {100 * share:.0f} % of this sphere's volume "
                    f"(the points within its radius of {f['radius']:g} m): the liquid starts "
                    f"{abs(100 * (share - 1)):.0f} % {'short' if share < 1 else 'over'}"
                    + (f"; a radius of {better:g} m holds its volume within 1 %" if better else "")
                    + " (docs/scenes.md, Fluid blocks)"
                )
            continue
        if "lower" not in f or "upper" not in f:
            continue
        sides = [b - a for a, b in zip(f["lower"], f["upper"])]
        filled = [h * whole_layers(s, h) for s in sides]
        share = math.prod(filled) / math.prod(sides) if math.prod(sides) > 0.0 else 1.0
        if _outside(share):
            out.append(
                f"fluids[{k}]: whole layers of spacing = {h:g} m fill only {100 * share:.0f} % of it "
                f"({' x '.join(f'{v:g}' for v in filled)} m of its {' x '.join(f'{v:g}' for v in sides)} m): the "
                f"liquid started {100 * (1 - share):.0f} % short; sides that are whole numbers of spacings keep it "
                "all (docs/scenes.md, Fluid blocks)"
            )
    return out


def nozzle_flows(scene: dict) -> list[str]:
    """For each emitter in a scene table whose layer carries a share of its nozzle's area outside
    90-110 % (so it pours that share of area x speed), one sentence naming it, its flow and a
    nozzle size that pours what it declares."""
    h = scene.get("spacing")
    out = []
    for k, e in enumerate(scene.get("emitters") or ()):
        if not h:
            continue
        emitter = Emitter(**e)
        share, area = nozzle_share(emitter, h)
        if not _outside(share):
            continue
        if emitter.shape == "disc":
            better = matching_disc_radius(emitter.radius, h)
            cure = (
                f"a radius of {_holding(better, lambda r: disc_points(r, h)):g} m pours its area within 1 %"
                if better
                else "a radius of five spacings or more pours its area within 10 %"
            )
        else:
            w, ht = (max(1, round(s / h)) * h for s in emitter.size)
            cure = f"sides that are whole numbers of spacings ({w:g} x {ht:g} m) pour their area"
        out.append(
            f"emitters[{k}]: its layer of {emitter.layer_size(h)} particles at spacing = {h:g} m carries "
            f"{100 * share:.0f} % of the nozzle's area ({area:.3g} m^2), so it pours "
            f"{1000 * share * area * emitter.speed:.3g} l/s, not the {1000 * area * emitter.speed:.3g} l/s of area x "
            f"speed; {cure} (docs/scenes.md, Emitters)"
        )
    return out
