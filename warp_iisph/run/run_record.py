"""``run.json``: a run's record (scene, device, versions, the frame plan, how it ended) and its
totals over the step records, rewritten at every frame and however the run ends."""

from __future__ import annotations

import math
import platform
import sys
import time
from types import SimpleNamespace

import numpy as np

from .. import __version__
from ..engine.timing import StageTimes
from ..scene import scene_to_dict
from ..setup.fill import lattice_shortfalls, nozzle_flows
from ..stepping.flows import BLOCKED
from .folder import new_run_id
from .frame_queue import FrameQueue

# the frame files a run writes as its ``output`` says (``output.particles``, ``output.mesh``)
FRAME_KINDS = ("particles", "mesh")
# what every step record holds that the totals sum
STEP_SUMS = ("iterations", "density_error", "compression")
# A run whose mean compression ends above this many times eta gets a warning: a converged solve
# holds it near eta or below (the bundled dam break at its defaults: 0.46 eta; at CFL 2: 0.9).
COMPRESSION_WARNING = 2.0


def versions() -> dict:
    import warp as wp

    return {
        "warp_iisph": __version__,
        "warp": wp.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def _recorded_scene(scene, plan) -> dict:
    """The scene as a table, its ``output`` saying the frames this run writes (``--duration`` and
    ``--fps`` override the scene file's)."""
    table = scene_to_dict(scene)
    table["output"].update(duration=plan.requested, fps=plan.fps)
    return table


class RunRecord:
    """The record of a run of ``scene`` by ``sim`` into ``run`` (a resumed run's record ``before``
    goes on: its id, its list of resumptions): :attr:`data` is what ``run.json`` holds,
    :attr:`totals` the sums over the step records, :attr:`times` the main thread's seconds per
    stage; :meth:`write` brings them up to date on disk."""

    def __init__(self, scene, sim, run, plan, graph: bool, background: bool, before: dict | None, first: int):
        self.sim, self.run = sim, run
        self.started = time.perf_counter()
        self.totals = StepTotals(sim.physics)
        # seconds per stage on the main thread; ``export`` is what output cost it: the host copies
        # plus the waits for the writer thread (whose own work overlaps the simulation)
        self.times = StageTimes()
        self.data = {
            "run_id": before["run_id"] if before is not None else new_run_id(),
            "ended": "running",
            "message": "",
            "scene": _recorded_scene(scene, plan),
            # what the scene's unset choices came to (its table keeps them unset)
            "resolved": sim.physics.resolved(bool(scene.bodies)),
            "device": str(sim.device),
            "graph": graph,
            "versions": versions(),
            "command": " ".join(sys.argv),
            "particles": {"fluid": sim.n_particles, "boundary": sim.model.n_boundary, "capacity": sim.model.capacity},
            "duration": plan.duration,
            "requested_duration": plan.requested,
            "fps": plan.fps,
            "output": {
                "particles": scene.output.particles,
                "format": scene.output.format,
                "mesh": scene.output.mesh,
                "background": background,
            },
        }
        if before is not None:
            resumption = {"frame": first - 1, "t": sim.time, "step": sim.step_count}
            # the frame files the run wrote up to here (since its start or its last resumption),
            # which a later resume checks are still there (:mod:`.kept`)
            wrote = before.get("output") or {}
            resumption["output_before"] = {k: bool(wrote[k]) for k in FRAME_KINDS if k in wrote}
            self.data["resumed"] = before.get("resumed", []) + [resumption]
            self.data.update({k: before[k] for k in ("obstacles", "bodies") if k in before})

    @property
    def run_id(self) -> str:
        return self.data["run_id"]

    def add_step(self, step: dict) -> None:
        """One step's record (a line of ``stats.jsonl``) into the totals and the stage times."""
        self.totals.add(step)
        self.times.merge({k: v / 1e3 for k, v in step.get("ms", {}).items()})

    def end(self, ended: str, message: str) -> None:
        self.data.update(ended=ended, message=message)

    def refresh(self, frames: int, mesher=None, queue: FrameQueue | None = None) -> dict:
        """The totals and stage seconds as they are now (``frames``: frames whose files are on disk)."""
        self.data["totals"] = self.totals.record(self.sim, frames, time.perf_counter() - self.started)
        if queue is not None:
            self.data["stage_seconds"] = _stage_seconds(self.times, mesher, queue)
            self.data["output"].update(writer_seconds=queue.busy, waited_seconds=queue.blocked)
        return self.data

    def write(self, frames: int, mesher, queue: FrameQueue) -> None:
        """``run.json`` brought up to date (atomically, :meth:`.folder.RunFolder.write_record`)."""
        self.run.write_record(self.refresh(frames, mesher, queue))


def blank_record(scene, plan, device: str = "cpu") -> dict:
    """The ``run.json`` that a run of ``scene`` over ``plan`` on ``device`` writes, every count 0
    and its clock at the plan's end, made before anything is built or run: the same names and
    parts as a real run's, from the code that writes them (what a sweep checks ``--measure``
    against before its first variant runs)."""
    from ..stepping.flows import has_flows

    # a simulation before its first step: exactly what a record reads of one, each count 0 (a field
    # read from anything else fails here, in the sweep's check, rather than reading 0)
    flows = SimpleNamespace(emitted=0, removed=0, refused=0, blocked=0) if has_flows(scene) else None
    model = SimpleNamespace(capacity=0, n_boundary=0)
    sim = SimpleNamespace(
        physics=scene.physics, device=device, time=plan.duration, n_particles=0, step_count=0, model=model, flows=flows
    )
    return RunRecord(scene, sim, None, plan, False, False, None, 0).refresh(0)


class StepTotals:
    """Sums over a run's step records, kept as they come (the records themselves go to disk)."""

    def __init__(self, physics):
        self.physics = physics
        self.steps = 0
        self.sums = dict.fromkeys(STEP_SUMS, 0.0)
        self.corrections = {"wall_corrections": 0, "obstacle_corrections": 0}
        self.corrected_steps = 0
        self.substeps = 0  # steps that were pieces of a fixed dt cut into substeps
        self.most_substeps = 1
        self.unconverged = 0
        self.worst_unconverged = 0.0

    def add(self, rec: dict) -> None:
        ph = self.physics
        self.steps += 1
        for k in self.sums:
            self.sums[k] += rec[k]
        for k in self.corrections:
            self.corrections[k] += rec.get(k, 0)
        self.corrected_steps += int(any(rec.get(k, 0) for k in self.corrections))
        pieces = rec.get("substeps", 1)
        self.substeps += int(pieces > 1)
        self.most_substeps = max(self.most_substeps, pieces)
        if ph.method in ("iisph", "dfsph") and rec["iterations"] >= ph.max_iterations and rec["density_error"] > ph.eta:
            self.unconverged += 1
            self.worst_unconverged = max(self.worst_unconverged, rec["density_error"])

    def record(self, sim, frames: int, wall: float) -> dict:
        n = max(self.steps, 1)
        return {
            "steps": sim.step_count,
            "simulated_time": sim.time,
            "frames": frames,
            "particles": sim.n_particles,
            **(
                {
                    "emitted": sim.flows.emitted,
                    "removed": sim.flows.removed,
                    "not_emitted": sim.flows.refused,
                    "blocked": sim.flows.blocked,
                }
                if sim.flows
                else {}
            ),
            "wall_seconds": wall,
            "wall_seconds_per_simulated_second": wall / sim.time if sim.time > 0 else None,
            "mean_iterations": self.sums["iterations"] / n,
            "mean_density_error": self.sums["density_error"] / n,
            "mean_compression": self.sums["compression"] / n,
            **self.corrections,
            "corrected_steps": self.corrected_steps,
            "substeps": self.substeps,
            "most_substeps": self.most_substeps,
            "unconverged_steps": self.unconverged,
            "worst_unconverged_error": self.worst_unconverged,
        }


# physics.viscosity is the coefficient of the report's form; the kinematic viscosity it gives
KINEMATIC = 0.2
# below this sqrt(g H) H / nu a dam break's front runs a quarter or more slower than without viscosity
# (benchmarks/viscosity_scale.py: Martin & Moyce's front speed 37 points slower at 12, its own 11.4 cm
# column; 17 at 37, 9 at 79, 6 at 146; a 4 cm column, 2.5, flows like honey)
VISCOUS_REYNOLDS = 20.0


def liquid_reynolds(scene: dict) -> float | None:
    """``sqrt(g H) H / nu`` of a scene table's tallest block of liquid (``H`` its height along
    gravity, ``nu`` the kinematic viscosity); ``None`` without liquid blocks, gravity or viscosity."""
    ph = scene["physics"]
    g = math.sqrt(sum(c * c for c in ph["gravity"]))
    nu = KINEMATIC * ph["viscosity"]
    heights = []
    for f in scene.get("fluids") or ():
        if "radius" in f:
            heights.append(2.0 * f["radius"])
        elif "lower" in f and "upper" in f and g > 0.0:
            heights.append(sum(abs(c) / g * (b - a) for c, a, b in zip(ph["gravity"], f["lower"], f["upper"])))
    if not heights or g <= 0.0 or nu <= 0.0:
        return None
    height = max(heights)
    return math.sqrt(g * height) * height / nu


def run_warnings(record: dict) -> list[str]:
    """What a finished run's record (``run.json``: its totals and its scene's physics) says its
    user should know, one sentence each: particles the emitters could not add, layers liquid at a
    nozzle blocked, steps that stopped at ``max_iterations``, a density held looser than asked (a
    step too long for the pressure solve, which the solve's own criterion, met on the linearised
    prediction, does not see), pressure probes read beside Akinci's walls (whose wall layer
    carries up to twice the pressure), boxes of liquid their lattice fills to less than 90 %, and
    spheres of liquid and nozzles it holds to less than 90 % or more than 110 %
    (:mod:`warp_iisph.setup.fill`)."""
    t, ph = record["totals"], record["scene"]["physics"]
    warnings = []
    if t.get("not_emitted"):
        warnings.append(
            f"the emitters could not add {t['not_emitted']} particles: the liquid reached its capacity of "
            f"{record['particles']['capacity']} (raise max_particles)"
        )
    if t.get("blocked"):
        due = t["emitted"] + t["blocked"] + t.get("not_emitted", 0)
        warnings.append(
            f"the emitters poured {100 * t['emitted'] / due:.0f} % of the particles due: {t['blocked']} were "
            f"blocked, their layers due while liquid sat at the nozzle (within {BLOCKED:g} spacings of a new "
            "particle); a nozzle under the liquid's surface with no wall behind it pours nothing, one its own "
            "stream falls back onto part of its layers (docs/scenes.md, Emitters)"
        )
    if t["unconverged_steps"]:
        warnings.append(
            f"{t['unconverged_steps']} of {t['steps']} steps stopped at max_iterations = {ph['max_iterations']} "
            f"above eta = {100 * ph['eta']:g} % (worst {100 * t['worst_unconverged_error']:.3f} %)"
        )
    compression, eta, dt = t["mean_compression"], ph["eta"], ph.get("dt")
    if ph["method"] in ("iisph", "dfsph") and t["steps"] and compression > COMPRESSION_WARNING * eta:
        if dt is None:
            cure = f"lower physics.cfl (now {ph['cfl']:g}) or physics.dt_max (now {ph['dt_max']:g} s)"
        elif ph["substeps"]:
            cure = f"shorten physics.dt (now {dt:g} s)"
        else:
            cure = f"shorten physics.dt (now {dt:g} s) or set physics.substeps = true"
        if t["unconverged_steps"]:
            cure = f"raise physics.max_iterations, or {cure}"
        warnings.append(
            f"mean compression {100 * compression:.3f} %, {compression / eta:.1f} times eta = {100 * eta:g} %: "
            f"the steps are too long for the pressure solve to hold the density; {cure}"
        )
    reynolds = liquid_reynolds(record["scene"])
    if reynolds is not None and reynolds < VISCOUS_REYNOLDS:
        warnings.append(
            f"the viscosity slows a liquid this small: physics.viscosity = {ph['viscosity']:g} (a kinematic "
            f"{KINEMATIC * ph['viscosity']:g} m^2/s) against its height gives sqrt(g H) H / nu = {reynolds:.1f}, "
            f"below {VISCOUS_REYNOLDS:g}, where a dam break's front runs a quarter or more slower than without "
            "viscosity (below 5 it flows like honey): lower physics.viscosity for a liquid this small "
            "(docs/physics.md 6.6)"
        )
    sensors = sum(1 for pr in record["scene"].get("probes") or () if pr.get("kind") == "pressure")
    akinci = ph["method"] == "dfsph" or (ph["method"] == "iisph" and ph.get("wall_pressure") == "fluid")
    if sensors and akinci:
        walls = "DFSPH's walls" if ph["method"] == "dfsph" else 'physics.wall_pressure = "fluid"'
        warnings.append(
            f"{sensors} pressure probe{'s' if sensors > 1 else ''} read the liquid's layer at the wall, which with "
            f"Akinci's wall pressure ({walls}) carries up to twice the hydrostatic pressure: at rest such a "
            "sensor reads about a third high; IISPH's default (extrapolated) walls read within a few per cent"
        )
    return warnings + lattice_shortfalls(record["scene"]) + nozzle_flows(record["scene"])


def _stage_seconds(times: StageTimes, mesher, queue: FrameQueue) -> dict:
    """The main thread's seconds per stage: the steps', the meshing's and the waits for output."""
    total = StageTimes()
    total.merge(times.seconds)
    if mesher is not None:
        total.merge({k: v for k, v in mesher.times.seconds.items() if k != "export"})
    total.add("export", queue.blocked)
    return total.seconds
