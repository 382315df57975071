"""How an obstacle's boundary particles are sampled, and the load and the contacts that follow
(docs/method.md, "Density and walls").

The held bar of validation.py's loads case (a bar 0.12 m square through a 0.3 x 0.42 x 0.12 m
tank, its ends in the side walls, held clear of the floor in water 0.32 m deep; the force probe
on it averaged over the last 0.5 s of 3 s, against its buoyancy rho0 g V) at 8 spacings across,
sampled four ways:

- ``box_cells``: a box obstacle with ``sampling = "cells"`` (one particle per grid cell its faces
  cross; the default until 2026-12-05, and what every mesh obstacle was: the same bar given as a
  mesh gave the same particles, and read the same to the last digit);
- ``box_faces``: a box with ``sampling = "faces"`` (two staggered layers inside its faces, the
  default);
- ``mesh``: the same bar as a closed mesh (two layers inside its surface, rasterised), with its
  faces on the fluid lattice's planes and shifted by a quarter and half a spacing along x and y.

And the bundled ``dam_break`` for 1 s at its defaults: the particles the last line puts back out
of its submarine (a closed mesh: hull, sail and tail fins, the fins 0.8 spacing thick), and the
fastest particle.

Writes benchmarks/results/obstacle_sampling.json and obstacle_sampling.png.

    python benchmarks/obstacle_sampling.py [--quick]

--quick (the test suite's): 6 spacings across the bar for 0.5 s (the last 0.2 s averaged), the
box's two samplings and the mesh on the lattice; the dam break for 0.1 s.
"""

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
from common import RESULTS, header, pyplot, save
from validation import LOADS_TANK, RHO0, G

from warp_iisph import Simulation
from warp_iisph.scene import Box, MeshShape, Probe, Scene, load_scene

LENGTH = 0.12  # the bar's side (m)


def bar_scene(h: float, kind: str, shift: float, folder: Path) -> Scene:
    """The loads case's tank and water with the bar sampled as ``kind``, moved by ``shift``
    spacings along x and y."""
    X, depth, W = LOADS_TANK
    y0 = round(0.1 / h) * h + shift * h
    lo = np.array((X / 2 - LENGTH / 2 + shift * h, y0, -5 * h))
    hi = np.array((X / 2 + LENGTH / 2 + shift * h, y0 + LENGTH, W + 5 * h))
    scene = Scene(spacing=h, tank=Box((0.0, 0.0, 0.0), (X, depth + 0.1, W)), name="bar")
    scene.add_fluid_box((0.0, 0.0, 0.0), (X, depth, W))
    if kind == "mesh":
        path = folder / f"bar_{shift:g}.obj"
        trimesh.creation.box(bounds=[lo, hi]).export(path)
        scene.add_obstacle(MeshShape(path.name, base_dir=str(folder), name="bar"))
    else:
        scene.add_obstacle(Box(tuple(lo), tuple(hi), name="bar", sampling=kind.split("_")[1]))
    scene.add_probe(Probe("bar", "force", obstacle="bar"))
    return scene


def held_bar(h: float, kind: str, shift: float, duration: float, window: float, folder: Path) -> dict:
    t0 = time.perf_counter()
    sim = Simulation(bar_scene(h, kind, shift, folder), "cpu", history=1)
    sim.advance(duration)
    late = sim.probes.time > duration - window
    force = float(sim.probes["bar.Fp_y"][late].mean())
    V = LENGTH * LENGTH * LOADS_TANK[2]
    return {
        "kind": kind,
        "shift": shift,
        "ratio": force / (RHO0 * G * V),
        "fluid_particles": sim.n_particles,
        "boundary_particles": int(sim.model.boundary_x.shape[0]),
        "wall_seconds": time.perf_counter() - t0,
    }


def dam_break(duration: float) -> dict:
    t0 = time.perf_counter()
    sim = Simulation(load_scene("dam_break"), "cpu")
    sim.advance(duration)
    return {
        "duration": duration,
        "steps": len(sim.stats),
        "obstacle_corrections": int(sum(r["obstacle_corrections"] for r in sim.stats)),
        "wall_corrections": int(sum(r["wall_corrections"] for r in sim.stats)),
        "max_velocity": float(max(r["max_velocity"] for r in sim.stats)),
        "fluid_particles": sim.n_particles,
        "wall_seconds": time.perf_counter() - t0,
    }


def chart(record: dict, png: Path) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.6))
    bars = record["bar"]["runs"]
    labels = [r["kind"] + (f"\n+{r['shift']:g} h" if r["kind"] == "mesh" else "") for r in bars]
    ax.bar(range(len(bars)), [r["ratio"] - 1.0 for r in bars], color="tab:blue")
    ax.axhspan(-0.02, 0.02, color="tab:green", alpha=0.15, label="within 2 %")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(range(len(bars)), labels)
    ax.set_ylabel("force / rho0 g V - 1")
    ax.set_title(f"held bar, {record['bar']['across']:g} spacings across: buoyancy by sampling")
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(png, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    across, duration, window = (6, 0.5, 0.2) if args.quick else (8, 3.0, 0.5)
    variants = [("box_cells", 0.0), ("box_faces", 0.0), ("mesh", 0.0)]
    if not args.quick:
        variants += [("mesh", 0.25), ("mesh", 0.5)]
    h = LENGTH / across
    record = header("obstacle_sampling")
    with tempfile.TemporaryDirectory() as folder:
        runs = []
        for kind, shift in variants:
            runs.append(held_bar(h, kind, shift, duration, window, Path(folder)))
            print(f"bar {kind:9s} +{shift:g} h: force / rho0 g V = {runs[-1]['ratio']:.4f}", flush=True)
    record["bar"] = {"across": across, "spacing": h, "duration": duration, "window": window, "runs": runs}
    record["dam_break"] = dam_break(0.1 if args.quick else 1.0)
    print(f"dam_break: {record['dam_break']}", flush=True)
    chart(record, save(record, args.out, "obstacle_sampling", args.quick))


if __name__ == "__main__":
    main()
