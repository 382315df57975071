"""The held bar's buoyancy against the weights of its boundary particles at its convex edges
(docs/physics.md 6.2, "a line of holes beside every edge").

A box obstacle sampled by faces is a tank's walls inside out, and its particles weigh Akinci's
``gamma rho0 / sum_k W_bk`` (``gamma`` calibrated on a flat wall). At a convex edge the sum lacks
the neighbours beyond the edge, the weight grows, and the fluid lattice site beside a face next to
the edge reads about 2 % above rho0; the build leaves out fluid sampled more than 0.5 % above rho0
beside an obstacle, so a line of holes runs beside each edge. This study builds validation.py's
held bar with three weightings of its boundary particles, the package's and two that leave no
hole, and measures it as held_bar.py does, from the hydrostatic (default) warm start:

- ``akinci``: the package's weights;
- ``flat``: no particle weighs more than one in the middle of a flat wall;
- ``calibrated``: no particle weighs more than ``c`` flat-wall particles, ``c`` bisected so that
  the fluid resting beside a convex edge (a lattice box's, the fluid filling the three quarters of
  space around it) has exactly the rest density, as ``gamma`` makes it beside a flat wall.

The bar's weights are changed by wrapping the build's ``compute_boundary_psi`` (a study's device,
not an option of the package); the bar's are those within its box, which takes in the tank's
side-wall particles where the bar runs into the walls (they weigh at most a flat wall's particle,
to float rounding, so neither cap changes them); the tank's others keep Akinci's (at its edges,
concave from the fluid, some weigh more than the caps too: counted, not changed).

Writes benchmarks/results/edge_weights.json and edge_weights.png.

    python benchmarks/edge_weights.py [--spacings 8,12,16] [--quick]

--quick (the test suite's): 8 spacings for 0.6 s, the package's and the calibrated weights.
"""

import argparse
import contextlib
import functools

import held_bar
import numpy as np
import warp as wp
from common import RESULTS, header, pyplot, save
from validation import RHO0

import warp_iisph.setup.build as build
from warp_iisph.scene import Box
from warp_iisph.setup.boundary import flat_wall_gamma, flat_wall_psi
from warp_iisph.setup.sampling import sample_box_faces
from warp_iisph.sph.kernel import cubic_W_np

WEIGHTS = ("akinci", "flat", "calibrated")


@functools.lru_cache(maxsize=1)
def edge_patch() -> tuple[float, np.ndarray, np.ndarray]:
    """A fluid particle resting one spacing from a face of a lattice box, next to its convex edge
    (h = 1, the fluid filling the three quarters of space around the edge): the fluid's part of its
    density, and the box's particles within its reach as Akinci weights them and as its kernel
    weighs them."""
    L = 10.0
    wall = sample_box_faces(Box((0.0, 0.0, -L / 2), (L, L, L / 2), sampling="faces"), 1.0)
    probe = np.array([-0.5, 0.5, 0.5])  # beside the face x = 0, next to the edge along z
    k = np.arange(-4, 5) + 0.5
    fluid = np.stack([a.ravel() for a in np.meshgrid(k, k, k, indexing="ij")], axis=1)
    fluid = fluid[(fluid[:, 0] < 0.0) | (fluid[:, 1] < 0.0)]
    near = wall[np.linalg.norm(wall - probe, axis=1) < 2.0]
    psi = flat_wall_gamma() / np.array([cubic_W_np(np.linalg.norm(wall - b, axis=1), 2.0).sum() for b in near])
    rho_fluid = float(cubic_W_np(np.linalg.norm(fluid - probe, axis=1), 2.0).sum())
    return rho_fluid, psi, cubic_W_np(np.linalg.norm(near - probe, axis=1), 2.0)


def edge_density(cap: float) -> float:
    """The density (in rho0) of :func:`edge_patch`'s fluid particle with the box's weights capped
    at ``cap`` flat-wall particles (the result does not depend on h)."""
    rho_fluid, psi, w = edge_patch()
    return float(rho_fluid + (np.minimum(psi, cap * flat_wall_psi(1.0, 1.0)) * w).sum())


@functools.lru_cache(maxsize=1)
def calibrated_factor() -> float:
    """The cap ``c`` (flat-wall particles) at which :func:`edge_density` is 1 (bisection: the
    density grows with the cap)."""
    lo, hi = 1.0, 2.0
    for _ in range(50):
        c = 0.5 * (lo + hi)
        lo, hi = (c, hi) if edge_density(c) < 1.0 else (lo, c)
    return 0.5 * (lo + hi)


@contextlib.contextmanager
def weights(kind: str, lo, hi, counts: dict):
    """Build simulations with the ``kind`` weights on the particles within the box ``lo``..``hi``
    (the bar's); ``counts`` gets how many weights were capped there and how many of the others
    weigh more than the cap."""
    original = build.compute_boundary_psi
    factor = {"akinci": None, "flat": 1.0, "calibrated": calibrated_factor()}[kind]

    def capped(xb, h, rho0, device):
        psi = original(xb, h, rho0, device)
        if factor is None or xb.shape[0] == 0:
            return psi
        values = psi.numpy()[: xb.shape[0]].copy()
        cap = factor * flat_wall_psi(h, rho0)
        x = xb.numpy()
        bar = np.all((x > np.asarray(lo) - 1e-9) & (x < np.asarray(hi) + 1e-9), axis=1)
        counts["capped"] = int(np.count_nonzero((values > cap) & bar))
        counts["over_cap_in_tank"] = int(np.count_nonzero((values > cap) & ~bar))
        values[bar] = np.minimum(values[bar], cap)
        return wp.array(values.astype(np.float32), dtype=float, device=device)

    build.compute_boundary_psi = capped
    try:
        yield
    finally:
        build.compute_boundary_psi = original


def measure(n: int, kind: str, duration: float, window: float) -> dict:
    """The held bar at ``n`` spacings across with the ``kind`` weights (see the module)."""
    _, lo, hi = held_bar.loads_scene(held_bar.LENGTH / n, True, held_bar.LENGTH)
    counts = {"capped": None, "over_cap_in_tank": None}  # None: nothing capped (Akinci's weights)
    with weights(kind, lo, hi, counts):
        r = held_bar.measure(n, "hydrostatic", duration, window)
    return {"weights": kind, **counts, **{k: v for k, v in r.items() if k != "series"}}


def chart(record: dict, path) -> None:
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for kind, mark in zip(WEIGHTS, "os^"):
        rows = [r for r in record["results"] if r["weights"] == kind]
        if rows:
            a.plot([r["L_over_h"] for r in rows], [r["ratio"] for r in rows], mark + "-", label=f"{kind} weights")
    a.axhspan(0.98, 1.02, color="0.9", label="issue 29's 2 %")
    a.axhline(1.0, color="k", lw=0.8)
    a.set(xlabel="spacings across the bar", ylabel="force / rho0 g V", title="held bar, hydrostatic start")
    cal = record["calibration"]
    kinds = list(cal["edge_density"])
    b.bar(kinds, [100 * (cal["edge_density"][k] - 1.0) for k in kinds], color="0.5")
    b.axhline(0.5, color="r", lw=0.8, ls="--", label="the build leaves out fluid above +0.5 %")
    b.set(ylabel="density - rho0 (%)", title="fluid beside a convex edge, at rest spacing")
    for ax in (a, b):
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacings", default="8,12,16", help="spacings across the bar")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    spacings = [8] if args.quick else [int(s) for s in args.spacings.split(",")]
    kinds = ("akinci", "calibrated") if args.quick else WEIGHTS
    duration, window = (0.6, 0.2) if args.quick else (3.0, 0.5)
    record = header("edge_weights", duration=duration, window=window, rho0=RHO0)
    c = calibrated_factor()
    record["calibration"] = {
        "factor": c,
        "edge_density": {
            "akinci": edge_density(float("inf")),
            "flat": edge_density(1.0),
            "calibrated": edge_density(c),
        },
    }
    print(
        "fluid beside a convex edge at rest spacing: "
        + ", ".join(f"{k} {100 * (v - 1):+.2f} %" for k, v in record["calibration"]["edge_density"].items())
        + f" (calibrated cap {c:.4f} flat-wall particles)",
        flush=True,
    )
    record["results"] = []
    for n in spacings:
        for kind in kinds:
            r = measure(n, kind, duration, window)
            record["results"].append(r)
            print(
                f"{n:3d} spacings, {kind:10s} weights: force / rho0 g V {r['ratio']:.4f}, {r['particles']} particles, "
                f"{r['capped']} of the bar's weights capped ({r['over_cap_in_tank']} of the tank's over the cap, "
                f"kept), slope beside "
                f"{r['beside_slope']:.4f} rho0 g, {r['wall_seconds']:.0f} s",
                flush=True,
            )
    chart(record, save(record, args.out, "edge_weights", args.quick))


if __name__ == "__main__":
    main()
