"""Particles pinned in films between a body and a wall, and the floor under the Jacobi step's
diagonal (docs/pressure_solve.md, "What changed").

IISPH's relaxed Jacobi step divides a particle's density residual by its diagonal ``a_diag``, the
density change per unit of its own pressure. A particle in a film between two walls (a crate
closing on the tank's side wall, a block sliding on the floor) has walls on both sides whose
pushes cancel, so its diagonal is small and the step's pressure large; the package divides by at
least ``DIAGONAL_FLOOR`` (a quarter) of a particle's inside resting liquid. Two parts:

- ``diagonals``: every step's compressed particles (advected density above rho0), frame by frame,
  their ``a_diag`` as a fraction of the bulk's ``dt^2 (m / rho0)^2 sum_j |grad W_ij|^2`` (a full
  lattice): the dam break (1.5 s), the flood (1 s) and SPHERIC Test 2 at 5 cm (1 s), at the
  defaults; and each run once more without the floor, its particles' positions at the end compared
  bit for bit (the floored step also meets uncompressed particles that carry a pressure, so the
  compressed particles' diagonals alone do not settle whether a run is touched).
- ``flood``: the bundled ``flood`` (free crates and a block) to its end, with the package's floor
  and without one (``DIAGONAL_FLOOR`` set to 0 for the run: a study's device, not an option), in
  one call and frame by frame at 25, 30 (``warp-iisph run``) and 60 fps, as each landing schedule
  makes the films' particles meet the walls at other steps: the fastest particle, the steps with a
  particle faster than 5 m/s (the wave's front is 2 sqrt(g H) = 3.7 m/s), the steps, the pressure
  iterations and the containment's put-backs.
- ``dfsph``: the same for DFSPH (``physics.method = "dfsph"``), whose constant-density solve
  divides by at least ``DENOMINATOR_FLOOR`` (a quarter) of a bulk particle's denominator of
  ``alpha_i / rho_i``, ``m^2 sum_j |grad W_ij|^2``: the flood frame by frame at 30 fps with the
  floor and without (a run that diverges is recorded with the time it reached), and the dam break
  (1.5 s) and SPHERIC Test 2 at 5 cm (1 s) at 30 fps once more without the floor, compared bit for
  bit; with the denominators of the particles the density solve pushed (a stiffness above zero
  after the step) as a fraction of the bulk's.

Writes benchmarks/results/pinned_films.json (a part not run this time kept from the file there,
with the day it was measured: ``part_dates``) and pinned_films.png.

    python benchmarks/pinned_films.py [--parts diagonals,flood,dfsph] [--quick] [--replot]

--quick (the test suite's): the flood at 4 cm for 0.3 s, in one call and at 30 fps, and the
diagonals of the dam break at 4 cm for 0.2 s; DFSPH's flood at 4 cm for 0.3 s at 30 fps and its
dam break at 4 cm for 0.2 s.
"""

import argparse
import time

import numpy as np
import warp as wp
from common import RESULTS, header, keep_parts, pyplot, save, saved

import warp_iisph.sph.solvers.dfsph as dfsph
import warp_iisph.sph.solvers.iisph as iisph
from warp_iisph import DivergenceError, Simulation
from warp_iisph.scene import load_scene

# each part and the record's keys it writes (a part not run keeps its saved measurement)
PARTS = {"diagonals": ("diagonals",), "flood": ("flood",), "dfsph": ("dfsph_denominators", "dfsph_flood")}
FAST = 5.0  # m/s: faster than the flood's wave front (3.7 m/s)
THRESHOLDS = (0.05, 0.1, 0.25, 0.37)  # fractions of the bulk's diagonal counted below


def advance(sim: Simulation, duration: float, fps: float, callback) -> None:
    """``duration`` seconds in one call (``fps`` 0) or frame by frame at ``fps``."""
    if fps == 0:
        sim.advance(duration, callback=callback)
        return
    k = 0
    while sim.time < duration - 1e-9:
        k += 1
        sim.advance(min(k / fps, duration) - sim.time, callback=callback)


def simulation(name: str, overrides: list, floor: float, method: str = "iisph") -> Simulation:
    """The bundled scene ``name`` built with ``method``'s floor set to ``floor`` (IISPH's
    ``DIAGONAL_FLOOR``, DFSPH's ``DENOMINATOR_FLOOR``)."""
    module, constant = (dfsph, "DENOMINATOR_FLOOR") if method == "dfsph" else (iisph, "DIAGONAL_FLOOR")
    package = getattr(module, constant)
    setattr(module, constant, floor)  # read when the solver is built
    try:
        return Simulation(load_scene(name, [*overrides, f"physics.method={method}"]), "cpu", history=1)
    finally:
        setattr(module, constant, package)


def against_bulk(name: str, duration: float, overrides: list, method: str, sample, samples_key: str) -> dict:
    """A run of ``name`` with ``method``'s floor: ``sample(sim, record)`` gives each step's ratios of
    a particle's diagonal (or denominator) to the bulk's, summarised here; and whether the run
    without the floor ends with the same positions (see the module)."""
    floor = dfsph.DENOMINATOR_FLOOR if method == "dfsph" else iisph.DIAGONAL_FLOOR
    sim = simulation(name, overrides, floor, method)
    ratios = []
    advance(sim, duration, sim.scene.output.fps, lambda record: ratios.append(sample(sim, record)))
    without = simulation(name, overrides, 0.0, method)
    advance(without, duration, sim.scene.output.fps, None)
    r = np.concatenate(ratios)
    return {
        "scene": name,
        "overrides": overrides,
        "duration": duration,
        "steps": len(ratios),
        samples_key: int(len(r)),
        "least": float(r.min()),
        "percentiles": {str(q): float(np.percentile(r, q)) for q in (0.01, 0.1, 1, 50)},
        "below": {str(t): int((r < t).sum()) for t in THRESHOLDS},
        "identical_without_floor": bool(np.array_equal(sim.positions, without.positions)),
    }


def compressed_diagonals(sim: Simulation, record: dict) -> np.ndarray:
    """IISPH: the step's compressed particles' diagonals over the bulk's (``a_bulk``: |a_ii| / dt^2
    inside resting liquid, the solver's own)."""
    n, terms = sim.state.n, sim.solver.terms
    compressed = terms.rho_adv.numpy()[:n] > sim.scene.physics.rho0
    return terms.a_diag.numpy()[:n][compressed] / (-(record["dt"] ** 2) * sim.solver.a_bulk)


def pushed_denominators(sim: Simulation, record: dict) -> np.ndarray:
    """DFSPH: the denominators of ``alpha_i / rho_i`` of the particles its constant-density solve
    pushed (a stiffness above zero after the step) over the bulk's."""
    n = sim.state.n
    factor = sim.solver.factor.numpy()[:n][sim.solver.kappa.numpy()[:n] > 0.0]
    return 1.0 / factor[factor > 0.0] / sim.solver.denominator_bulk


def diagonals(name: str, duration: float, overrides: list) -> dict:
    """IISPH's compressed particles' diagonals against the bulk's over a run (see the module)."""
    return against_bulk(name, duration, overrides, "iisph", compressed_diagonals, "compressed_samples")


def dfsph_denominators(name: str, duration: float, overrides: list) -> dict:
    """DFSPH's pushed particles' denominators against the bulk's over a run (see the module)."""
    return against_bulk(name, duration, overrides, "dfsph", pushed_denominators, "pushed_samples")


def flood(floor: float, fps: float, duration: float, overrides: list, method: str = "iisph") -> dict:
    """The flood with ``method``'s floor ``floor`` advanced as ``fps`` says (see the module); a run
    that diverges ends there, its reason recorded."""
    sim = simulation("flood", overrides, floor, method)
    duration = duration or sim.scene.output.duration
    rows, diverged = [], None
    t0 = time.perf_counter()
    try:
        advance(
            sim,
            duration,
            fps,
            lambda r: rows.append((r["t"], r["max_velocity"], r["iterations"], r["obstacle_corrections"])),
        )
    except DivergenceError as e:
        diverged = e.reason
    r = np.array(rows)
    return {
        "method": method,
        "floor": floor,
        "fps": fps,
        "diverged": diverged,
        "simulated_seconds": sim.time,
        "steps": len(r),
        "fastest": float(r[:, 1].max()),
        "fastest_at": float(r[int(np.argmax(r[:, 1])), 0]),
        "fast_steps": int((r[:, 1] > FAST).sum()),
        "mean_iterations": float(r[:, 2].mean()),
        "put_back": int(r[:, 3].sum()),
        "wall_seconds": time.perf_counter() - t0,
        "t": r[:, 0].tolist(),
        "max_velocity": r[:, 1].tolist(),
    }


def chart(record: dict, path) -> None:
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    runs = record.get("flood", [])
    for run in [*runs, *record.get("dfsph_flood", [])]:
        if run["fps"] == record["frame_rate"]:
            label = f"floor {run['floor']:g}" if run["floor"] else "no floor"
            label = f"{run.get('method', 'iisph').upper()}, {label}: {run['steps']} steps"
            if run.get("diverged"):
                label += f", diverged at {run['simulated_seconds']:.2f} s"
            a.plot(run["t"], run["max_velocity"], lw=0.8, label=label)
    a.axhline(FAST, color="k", lw=0.6, ls="--")
    a.set(
        xlabel="t (s)",
        ylabel="fastest particle (m/s)",
        title=f"flood, frame by frame at {record['frame_rate']:g} fps",
    )
    schedules = sorted({run["fps"] for run in runs})
    for k, floor in enumerate(sorted({run["floor"] for run in runs})):
        ys = [next((r["fastest"] for r in runs if r["fps"] == f and r["floor"] == floor), np.nan) for f in schedules]
        b.bar(np.arange(len(schedules)) + 0.4 * k, ys, 0.4, label=f"floor {floor:g}" if floor else "no floor")
    b.set_xticks(np.arange(len(schedules)) + 0.2, ["one call" if f == 0 else f"{f:g} fps" for f in schedules])
    b.set(ylabel="fastest particle over the run (m/s)", title="IISPH's flood, by how the run is advanced")
    for ax in (a, b):
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def study_row(d: dict, samples_key: str) -> dict:
    """Print one scene's diagonals (or denominators) against the bulk's, and return them."""
    print(
        f"{d['scene']} {' '.join(d['overrides'])}: {d[samples_key]} particle-steps ({samples_key}), least "
        f"{d['least']:.3f} of the bulk's, below 0.25: {d['below']['0.25']}, the same without the floor: "
        f"{d['identical_without_floor']}",
        flush=True,
    )
    return d


def flood_row(r: dict) -> dict:
    """Print one flood run, and return it."""
    how = "one call" if r["fps"] == 0 else f"{r['fps']:g} fps"
    print(
        f"{r['method']} flood, {how}, floor {r['floor']:g}: reached {r['simulated_seconds']:.3f} s"
        + (f" (diverged: {r['diverged']})" if r["diverged"] else "")
        + f", fastest {r['fastest']:.2f} m/s at {r['fastest_at']:.3f} s, {r['fast_steps']} steps over "
        f"{FAST:g} m/s, {r['steps']} steps, {r['mean_iterations']:.2f} iterations a step, "
        f"{r['put_back']} put back, {r['wall_seconds']:.0f} s",
        flush=True,
    )
    return r


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", default=",".join(PARTS))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(RESULTS))
    ap.add_argument("--replot", action="store_true", help="redraw the chart from the JSON already in --out")
    args = ap.parse_args()
    if args.replot:
        chart(*saved(args.out, "pinned_films", args.quick))
        return
    wp.config.log_level = wp.LOG_WARNING
    parts = args.parts.split(",")
    record = header(
        "pinned_films",
        floor=iisph.DIAGONAL_FLOOR,
        denominator_floor=dfsph.DENOMINATOR_FLOOR,
        fast=FAST,
        frame_rate=30.0,
    )
    if set(parts) - set(PARTS):
        ap.error(f"--parts: among {', '.join(PARTS)}")
    keep_parts(record, args.out, "pinned_films", PARTS, set(parts), args.quick)
    if args.quick:
        cases, flood_overrides, duration, schedules = (
            [("dam_break", 0.2, ["spacing=0.04"])],
            ["spacing=0.04"],
            0.3,
            (0, 30),
        )
        dfsph_cases = cases
    else:
        cases = [("dam_break", 1.5, []), ("flood", 1.0, []), ("spheric_test2", 1.0, ["spacing=0.05"])]
        flood_overrides, duration, schedules = [], None, (0, 25, 30, 60)
        dfsph_cases = [("dam_break", 1.5, []), ("spheric_test2", 1.0, ["spacing=0.05"])]
    if "diagonals" in parts:
        record["diagonals"] = [study_row(diagonals(*case), "compressed_samples") for case in cases]
    if "flood" in parts:
        record["flood"] = [
            flood_row(flood(floor, fps, duration, flood_overrides))
            for fps in schedules
            for floor in (0.0, iisph.DIAGONAL_FLOOR)
        ]
    if "dfsph" in parts:
        record["dfsph_denominators"] = [study_row(dfsph_denominators(*case), "pushed_samples") for case in dfsph_cases]
        record["dfsph_flood"] = [
            flood_row(flood(floor, record["frame_rate"], duration, flood_overrides, "dfsph"))
            for floor in (0.0, dfsph.DENOMINATOR_FLOOR)
        ]
    chart(record, save(record, args.out, "pinned_films", args.quick))


if __name__ == "__main__":
    main()
