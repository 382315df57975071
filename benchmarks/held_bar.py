"""The held bar's buoyancy against resolution and the pressure solve's start: where the force
probe's excess over rho0 g V sits (docs/physics.md 6.2).

The loads case of validation.py (a bar 0.12 m square through a 0.3 x 0.42 x 0.12 m tank, its ends
in the side walls, held clear of the floor in water 0.32 m deep) at 8, 12 and 16 spacings across
the bar, from each warm start (``physics.warm_start``: "hydrostatic", the default here, and
"half"). Over the last 0.5 s of 3 s, after every 10 ms:

- the force probe's vertical pressure force on the bar, and the same sum split over the bar's
  boundary particles (the step's own wall-force sums, :class:`warp_iisph.sph.wall_forces.WallForces`,
  one group per part): the top and the bottom face's interiors (particles more than 1.75 spacings
  from an edge, between two lattice planes; they stand for L - 3.5 h of the face's width, and
  their load per area is taken against rho0 g times the face's depth below the level gauge), the
  side faces' interiors, and the rest (the edges);
- the resting water's pressure slope beside the bar, in rho0 g: least squares of the particles'
  pressure against height, over those between 0.04 and 0.26 m high, more than two spacings from
  the tank's walls and from the bar's sides.

Every 50 ms from the start (between steps; in the window above its 10 ms pieces land steps as
before), the force's 50 ms mean and the number of fluid particles under the bar (within its
width, below its bottom face) are kept as a series: the reading's history.

``completed`` (the third part): the plain runs from the hydrostatic start with the walls completing
the kernel gradient in the pressure force (``physics.wall_gradient = "completed"``,
warp_iisph/sph/wall_gradient.py); the other parts take Akinci's walls, the default without free
bodies.

``--crossed`` (the second part): the same bar settled from one start for the first second and
run on from the other to 3 s, both ways, at the ``--crossed`` spacings: whether the excess
belongs to the solve that holds the water or to the packing it settled into.

Writes benchmarks/results/held_bar.json (a part not run this time kept from the file there, with
the day each part was measured) and held_bar.png.

    python benchmarks/held_bar.py [--spacings 8,12,16] [--crossed 12,16] [--parts plain,crossed,completed] [--quick]

--quick (the test suite's): 8 spacings for 0.6 s, the last 0.2 s measured; crossed at 0.3 s.
"""

import argparse
import time

import numpy as np
import warp as wp
from common import RESULTS, header, keep_parts, pyplot, save
from validation import LOADS_TANK, RHO0, G, loads_scene

from warp_iisph import Simulation
from warp_iisph.sph.wall_forces import WallForces

STARTS = ("hydrostatic", "half")
CROSSINGS = (("half", "hydrostatic"), ("hydrostatic", "half"))  # (settled from, then)
PARTS = ("top", "bottom", "sides", "edges")
LENGTH = 0.12  # the bar's side (m)
# a face's interior ends 1.75 spacings from an edge: between the lattice planes of its two layers
# (at whole and half spacings from the edge), so no particle sits on the cut; the interior's
# columns stand for L - 3 h of the outer layer and L - 4 h of the inner one, L - 3.5 h together
EDGE = 1.75


def bar_parts(xb: np.ndarray, lo, hi, h: float) -> np.ndarray:
    """Each of the bar's boundary particles' part, an index into PARTS."""
    inner_x = (xb[:, 0] > lo[0] + EDGE * h) & (xb[:, 0] < hi[0] - EDGE * h)
    inner_y = (xb[:, 1] > lo[1] + EDGE * h) & (xb[:, 1] < hi[1] - EDGE * h)
    part = np.full(len(xb), 3, dtype=np.int32)
    part[inner_x & (xb[:, 1] > hi[1] - 2 * h)] = 0
    part[inner_x & (xb[:, 1] < lo[1] + 2 * h)] = 1
    part[inner_y & ~inner_x] = 2
    return part


def beside_slope(x: np.ndarray, p: np.ndarray, lo, hi, h: float) -> float:
    """The pressure's slope against height beside the bar (see the module), in rho0 g."""
    X, _, W = LOADS_TANK
    across = ((x[:, 0] > 2 * h) & (x[:, 0] < lo[0] - 2 * h)) | ((x[:, 0] > hi[0] + 2 * h) & (x[:, 0] < X - 2 * h))
    keep = across & (x[:, 2] > 2 * h) & (x[:, 2] < W - 2 * h) & (x[:, 1] > 0.04) & (x[:, 1] < 0.26)
    return float(-np.polyfit(x[keep, 1], p[keep], 1)[0] / (RHO0 * G))


SERIES = 0.05  # seconds between the history's samples
SWITCH = 1.0  # the crossed runs' change of start (s): settled by then (the force moves < 1 % after)


def use_start(sim: Simulation, start: str) -> None:
    """Change a running IISPH solve's warm start. A study's device, not an API: a scene's
    ``physics.warm_start`` is resolved when the solver is built (and the simulation's physics is
    read-only), so the simulation must have been built with the hydrostatic start, whose estimate
    it then has, and keeps that start's floor of 4 iterations (the half start's own floor is 2; it
    iterates to eta in 20 or more anyway). Switched between steps of the plain path (no graph)."""
    solver = sim.solver
    if start != "half" and solver.hydrostatic is None:
        raise ValueError("build the simulation with a hydrostatic start to switch to one")
    solver.warm_start = start


def under_bar(x: np.ndarray, lo, hi) -> int:
    """Fluid particles within the bar's width and below its bottom face."""
    return int(np.count_nonzero((x[:, 0] > lo[0]) & (x[:, 0] < hi[0]) & (x[:, 1] < lo[1])))


def measure(
    n: int,
    start: str,
    duration: float,
    window: float,
    settled_from: str | None = None,
    switch: float = SWITCH,
    wall_gradient: str = "akinci",
) -> dict:
    """The bar at ``n`` spacings across from warm start ``start`` (see the module); with
    ``settled_from``, from that start up to ``switch`` seconds and from ``start`` after; with
    ``wall_gradient`` the walls' gradient in the pressure force (``physics.wall_gradient``)."""
    h = LENGTH / n
    scene, lo, hi = loads_scene(h, True, LENGTH)
    scene.physics.wall_gradient = wall_gradient
    first = settled_from or start
    scene.physics.warm_start = "hydrostatic" if "hydrostatic" in (first, start) else start
    t0 = time.perf_counter()
    sim = Simulation(scene, "cpu", history=1)
    use_start(sim, first)
    model = sim.model
    xb = model.boundary_x.numpy()[: model.n_boundary]
    labels = np.full(model.n_boundary, -1, dtype=np.int32)
    bar = model.boundary_owner.numpy()[: model.n_boundary] == 0  # the scene's one obstacle
    labels[bar] = bar_parts(xb[bar], lo, hi, h)
    split = WallForces(model, sim.solver, labels)
    iterations = []

    buoyancy = RHO0 * G * LENGTH * LENGTH * LOADS_TANK[2]
    series = {"time": [0.0], "under": [under_bar(sim.positions, lo, hi)]}
    phases, switched_at = [], None  # mean iterations a step before and after the switch

    def on_step(record: dict) -> None:
        """Count, switch the start and sample the history between steps: no step is cut short
        to land on a sampling time (a landing's shortened step disturbs the pressure it leaves,
        and the packing the water settles into with it)."""
        nonlocal switched_at
        iterations.append(record.get("iterations", 0))
        t = record["t"]
        if settled_from and switched_at is None and t >= switch - 1e-9:
            phases.append(float(np.mean(iterations)))
            switched_at = len(iterations)
            use_start(sim, start)
        if t >= series["time"][-1] + SERIES - 1e-9:
            series["time"].append(t)
            series["under"].append(under_bar(sim.positions, lo, hi))

    sim.advance(duration - window, callback=on_step)
    probe, parts, slopes, levels = [], [], [], []
    while sim.time < duration - 1e-9:
        sim.advance(min(0.01, duration - sim.time), callback=on_step)
        split.compute(sim.state)
        parts.append(split.totals.numpy()[: len(PARTS), 1].copy())  # numpy() of a CPU array is a view
        probe.append(float(sim.probes["bar.Fp_y"][-1]))
        levels.append(float(sim.probes["level"][-1]))
        n_now = sim.state.n
        slopes.append(beside_slope(sim.state.x.numpy()[:n_now], sim.state.p.numpy()[:n_now], lo, hi, h))
    if settled_from:
        phases.append(float(np.mean(iterations[switched_at:])))
    t, force = sim.probes.time, sim.probes["bar.Fp_y"]  # every step's reading: 50 ms means
    series["ratio"] = [None] + [
        float(np.mean(force[(t > a - SERIES + 1e-9) & (t <= a + 1e-9)])) / buoyancy for a in series["time"][1:]
    ]
    parts = np.mean(parts, axis=0)
    level = float(np.mean(levels))
    face_area = (hi[0] - lo[0] - 2 * EDGE * h) * LOADS_TANK[2]
    return {
        "L_over_h": n,
        "spacing": h,
        "warm_start": start,
        "wall_gradient": wall_gradient,
        **({"settled_from": settled_from, "switch": switch, "iterations_before_after": phases} if settled_from else {}),
        "particles": sim.n_particles,
        "steps": sim.step_count,
        "iterations_per_step": float(np.mean(iterations)),  # every step from the start, settling included
        "ratio": float(np.mean(probe)) / buoyancy,
        "parts": {k: float(v) / buoyancy for k, v in zip(PARTS, parts)},
        "parts_sum": float(parts.sum()) / buoyancy,
        "level": level,
        "top_face_pressure": float(-parts[0] / face_area),
        "bottom_face_pressure": float(parts[1] / face_area),
        "top_face_hydrostatic": RHO0 * G * (level - hi[1]),
        "bottom_face_hydrostatic": RHO0 * G * (level - lo[1]),
        "beside_slope": float(np.mean(slopes)),
        "samples": len(probe),
        "under_bar": series["under"][-1],
        "series": series,
        "wall_seconds": time.perf_counter() - t0,
    }


def chart(record: dict, path) -> None:
    plt = pyplot()
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(15, 4))
    for start, mark in zip(STARTS, "os"):
        rows = [r for r in record["results"] if r["warm_start"] == start]
        n = [r["L_over_h"] for r in rows]
        a.plot(n, [r["ratio"] for r in rows], mark + "-", label=f"warm start {start}")
        b.plot(n, [r["beside_slope"] for r in rows], mark + "-", label=f"warm start {start}")
    for first, then in CROSSINGS:
        rows = [r for r in record.get("crossed", []) if r["settled_from"] == first and r["warm_start"] == then]
        if rows:
            a.plot(
                [r["L_over_h"] for r in rows], [r["ratio"] for r in rows], "x--", label=f"settled {first}, then {then}"
            )
    rows = record.get("completed", [])
    if rows:
        n, label = [r["L_over_h"] for r in rows], "hydrostatic, completed walls"
        a.plot(n, [r["ratio"] for r in rows], "D-", label=label)
        b.plot(n, [r["beside_slope"] for r in rows], "D-", label=label)
    a.axhspan(0.98, 1.02, color="0.9", label="issue 29's 2 %")
    a.axhline(1.0, color="k", lw=0.8)
    a.set(xlabel="spacings across the bar", ylabel="force / rho0 g V", title="held bar's buoyancy")
    b.axhline(1.0, color="k", lw=0.8)
    b.set(xlabel="spacings across the bar", ylabel="dp/dy / rho0 g", title="resting pressure's slope beside the bar")
    # the history at the finest spacing the crossed runs have (else the plain runs')
    runs = record.get("crossed") or record["results"]
    finest = max(r["L_over_h"] for r in runs)
    shown = [r for r in record["results"] + record.get("crossed", []) if r["L_over_h"] == finest and "series" in r]
    for r in shown:
        label = f"{r['settled_from']}, then {r['warm_start']}" if "settled_from" in r else r["warm_start"]
        c.plot(r["series"]["time"][1:], r["series"]["ratio"][1:], label=label, lw=1)
    c.axhspan(0.98, 1.02, color="0.9")
    c.set(
        xlabel="t (s)",
        ylabel="force / rho0 g V (50 ms means)",
        ylim=(0.9, 1.1),
        title=f"its history at {finest} spacings (switch at {record.get('switch', SWITCH):g} s)",
    )
    for ax in (a, b, c):
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def report(r: dict) -> None:
    parts = ", ".join(f"{k} {v:+.4f}" for k, v in r["parts"].items())
    how = f"settled {r['settled_from']}, then {r['warm_start']}" if "settled_from" in r else f"{r['warm_start']} start"
    how += ", completed walls" if r.get("wall_gradient") == "completed" else ""
    print(
        f"{r['L_over_h']:3d} spacings, {how}: force / rho0 g V {r['ratio']:.4f} ({parts}); slope beside "
        f"{r['beside_slope']:.4f} rho0 g; faces {r['top_face_pressure']:.0f} / "
        f"{r['bottom_face_pressure']:.0f} Pa "
        f"(hydrostatic {r['top_face_hydrostatic']:.0f} / {r['bottom_face_hydrostatic']:.0f}); "
        f"{r['iterations_per_step']:.1f} iterations a step; {r['under_bar']} particles under the bar; "
        f"{r['wall_seconds']:.0f} s",
        flush=True,
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spacings", default="8,12,16", help="spacings across the bar")
    ap.add_argument("--crossed", default="12,16", help="spacings of the crossed runs")
    ap.add_argument(
        "--parts", default="plain,crossed,completed", help="plain, crossed, completed (a part not run is kept)"
    )
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    parts = set(args.parts.split(","))
    if not parts <= {"plain", "crossed", "completed"}:
        raise SystemExit(f"--parts {args.parts!r}: among plain, crossed, completed")
    spacings = [8] if args.quick else [int(s) for s in args.spacings.split(",")]
    crossed = [8] if args.quick else [int(s) for s in args.crossed.split(",")]
    duration, window, switch = (0.6, 0.2, 0.3) if args.quick else (3.0, 0.5, SWITCH)
    record = header("held_bar", duration=duration, window=window, switch=switch)
    kept = {"plain": ("results",), "crossed": ("crossed",), "completed": ("completed",)}
    keep_parts(record, args.out, "held_bar", kept, parts, args.quick)
    record.setdefault("results", [])
    record.setdefault("crossed", [])
    record.setdefault("completed", [])
    if "plain" in parts:
        record["results"] = []
        for n in spacings:
            for start in STARTS:
                record["results"].append(measure(n, start, duration, window))
                report(record["results"][-1])
    if "crossed" in parts:
        record["crossed"] = []
        for n in crossed:
            for first, then in CROSSINGS:
                record["crossed"].append(measure(n, then, duration, window, settled_from=first, switch=switch))
                report(record["crossed"][-1])
    if "completed" in parts:
        record["completed"] = []
        for n in spacings:
            record["completed"].append(measure(n, "hydrostatic", duration, window, wall_gradient="completed"))
            report(record["completed"][-1])
    chart(record, save(record, args.out, "held_bar", args.quick))


if __name__ == "__main__":
    main()
