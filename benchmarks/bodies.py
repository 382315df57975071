"""Free bodies: what they cost, whether the liquid stays out of them, how deep they float, how they heave.

(a) The bundled ``flood`` scene at its defaults (three crates and a concrete block swept along a
channel) with its free bodies, against the same scene with the bodies fixed where they start (the
same boxes as still obstacles, sampled in layers inside their faces as a body is; at that scene's
defaults), and against the same boxes moved along the path the free bodies took (keyframes every
10 ms from a free run of its own, untimed: the same flow round them, with nothing pushed back),
which sets the coupling's own cost apart from the different flow that bodies held still make; the
three once more from the half warm start (the free bodies' default until 2026-12-06): wall
seconds per simulated second, the median over repeats, each repeat's six runs taking turns frame by
frame in one process (free, fixed, ..., then backwards: since 2026-12-06, when runs one after the
other put 1.36 where the turns put 1.19, the machine's speed drifting between runs). Each
run also reports the containment's last-line corrections (``obstacle_corrections``: particles it
put back out of an obstacle or a body; ``wall_corrections``: out of the tank), the fluid
particles found inside a body at every frame (checked outside the timing, in each body's frame:
centres inside its surface, and past its wall, the last line's, which is a free body's surface and
a still faces-sampled box's inner boundary layer h/2 inside its faces), and whether any body left
the tank (a corner of its box beyond a face by more than a spacing). The timed runs advance frame
by frame at the scene's 30 fps; the free bodies and their replay are then advanced
once each at 25 and 60 fps, taking turns, and in one call each (``schedule_runs``; the replay on the 30 fps path):
the spray the films shoot out is chaotic, a particle faster than 5 m/s cuts the CFL step for as
long as it flies, and each landing schedule brings the films' particles to the walls at other
steps, so the steps one schedule takes are one sample (``summary.schedules``: steps and cost per
schedule, and their medians).

(b) Archimedes: the draft of a box of density 500 and one of 250 (0.16 x 0.08 x 0.16 m, in a
0.4 m square pool 0.2 m deep, as tests/test_bodies.py's ``pool``) at spacings 0.02 and 0.01 m,
the mean over t = 1.0 .. 1.6 s, as % error against half and a quarter of the box's height, below
two levels of the liquid: by its rest volume (particles times h^3 filling the pool from its floor,
less the box's submerged volume), and as six level gauges read it (``kind = "level"``, where the
smoothed occupancy falls through 1/2; at the pool's corners and the middles of two sides, 0.06 m
from the walls and the box), which sees where the liquid's surface stands whatever gap the walls
keep the particles at. Part ``dfsph_drafts``: the same with DFSPH
(``physics.method = "dfsph"``; its walls are Akinci's); part ``dfsph_heave``: DFSPH in the
bundled ``heave`` scene as it is, against the linear theory of (c).

(c) Heave: the density 500 box of (b) placed 2 cm below its draft and held there for 0.5 s
(``release_time``) while the liquid settles around it, then released from rest; its centre's
height every 5 ms over 1.5 s from the release, fitted with a damped cosine (period, damping ratio,
equilibrium), at the spacings of (b). The undamped period it implies, ``T_d sqrt(1 - zeta^2)``, is
set against ``2 pi sqrt((M + M_a) / k)``: the hydrostatic stiffness ``k = rho g A_b / (1 - A_b /
A_pool)`` (in a closed pool the level rises as the box sinks) and the added mass of a square flat
plate of the box's side at a free surface, half of its value in unbounded fluid (DNV-RP-H103,
Appendix A, Table A-2: C_A = 0.579 on V_R = pi/4 a^2 b; the high-frequency limit, without the
draft and the pool's walls, both of which add to it): an estimate, not a measurement. Then the
same box in a 1.2 m pool (the bundled ``heave`` scene: its walls 0.52 m from the box; the waves
the heave radiates at 11 rad/s, group speed about 0.45 m/s, are back after about 2.3 s, long waves,
sqrt(g h) = 1.4 m/s, after about 0.75 s), as the scene has it (viscosity 0.01), at the default
viscosity and without viscosity (the liquid linear theory assumes), against linear potential flow for the box's own
shape in open water (heave_reference.py: Capytaine's radiation solve and Cummins' equation,
released from rest as far from rest as the box, and fitted the same way; skipped without
Capytaine); the period of the first swing (twice the time between the first two crossings of
rest) beside the fit.

(d) What sets the flood's step (part ``step_setters``, untimed): the free bodies, their replay and
the still boxes over the first second, where the free bodies' extra steps build up; at every step
whose fastest particle is over 4 m/s (the wave's front runs at 3.7), whether it is a lone droplet
(no fluid particle within the kernel's support; summed over those steps, 1 - the fastest other
particle's speed / the droplet's: about the steps the droplets added where the CFL rule set the
step, whose length goes as 1 / the fastest speed), and where each such flight began: the two solids
nearest the particle then (a droplet squeezed out between two crates closing on each other is
nearest both).

Writes benchmarks/results/bodies.json (a part not run this time kept from the file there, with the
day it was measured: ``part_dates``) and .png.

    python benchmarks/bodies.py [--repeats 3] [--spacings 0.02,0.01]
        [--parts flood,drafts,heave,dfsph_drafts,dfsph_heave,step_setters] [--quick] [--replot]
"""

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np
from common import RESULTS, header, keep_parts, pyplot, save, saved, warm_up

from warp_iisph import Box, Physics, Scene, Simulation
from warp_iisph.engine.launch import get_threads
from warp_iisph.scene import load_scene
from warp_iisph.scene.bodies import quaternion_matrix
from warp_iisph.scene.motion import MAX_KEYS, Motion
from warp_iisph.scene.probes import Probe

FLOOD_VARIANTS = ("free", "fixed", "replayed", "free_half", "fixed_half", "replayed_half")
# the half-start variants; the others take the scene's own
VARIANT_WARM_STARTS = {"free_half": "half", "fixed_half": "half", "replayed_half": "half"}
# each replay follows the path the free bodies take from its own start
REPLAYS = {"replayed": "free", "replayed_half": "free_half"}
# Other landing schedules the free bodies and their replay are advanced with once each:
# the films' spray is chaotic, and each schedule brings their particles to the walls at other steps
SCHEDULES = (25.0, 60.0, 0.0)  # frames per second; 0: in one call
FAST = 5.0  # m/s: a step with a particle faster than this (the wave's front runs at 3.7) is counted
REPLAY_KEY_INTERVAL = 0.01  # s between the keys a replay takes from the free run's steps
_paths: dict = {}  # the free variants' paths, recorded once in runs of their own (every run is the same)


def flood(variant: str, overrides: list, path: dict | None = None) -> Scene:
    """The flood scene; ``free``: as it is (the hydrostatic warm start, beside a body at least half
    the last pressure); ``fixed``: its bodies replaced by still box obstacles of the same shapes, at
    that scene's defaults; ``replayed``: the same box obstacles moved along the ``path`` the free
    bodies took (keyframes, :func:`replay_motions`), so the liquid flows round the bodies as they
    moved, but pushes nothing: the same flow without the coupling. ``free_half``, ``fixed_half``,
    ``replayed_half``: the same from the half warm start (the free bodies' default until
    2026-12-06), the replay along ``free_half``'s path. Every box-obstacle variant but ``fixed``
    takes the free bodies' walls, ``physics.wall_gradient = "completed"``, so that it differs from
    the free run in the coupling only."""
    scene = load_scene("flood", overrides)
    if variant in VARIANT_WARM_STARTS:
        scene.physics.warm_start = VARIANT_WARM_STARTS[variant]
    if variant in ("fixed_half", "replayed", "replayed_half"):
        scene.physics.wall_gradient = "completed"
    scene.physics.validate()
    if variant in ("fixed", "fixed_half", "replayed", "replayed_half"):
        motions = replay_motions(scene, path) if variant.startswith("replayed") else [None] * len(scene.bodies)
        for body, motion in zip(scene.bodies, motions):  # in layers inside its faces where thick enough
            thick = min(np.subtract(body.shape.upper, body.shape.lower)) >= 3 * scene.spacing
            box = Box(body.shape.lower, body.shape.upper, sampling="faces" if thick else "cells", motion=motion)
            scene.add_obstacle(box)
        scene.bodies = []
    return scene


def replay_motions(scene: Scene, path: dict) -> list:
    """Keyframes that move each body's box as the free run moved the body: at every key (the free
    run's steps, one every REPLAY_KEY_INTERVAL, at most MAX_KEYS) its centre of mass's translation
    and its rotation as angles about x, then y, then z (kept continuous), about its centre of mass
    at the start; smooth interpolation between keys."""
    from scipy.spatial.transform import Rotation

    keep = np.unique(np.linspace(0, len(path["times"]) - 1, min(len(path["times"]), MAX_KEYS)).round().astype(int))
    path = {key: np.asarray(v)[keep] for key, v in path.items()}
    out = []
    for k in range(len(scene.bodies)):
        centres = path["position"][:, k]
        start = centres[0]
        angles = continuous_angles(Rotation.from_quat(path["orientation"][:, k]).as_euler("xyz"))
        out.append(
            Motion(
                times=path["times"].tolist(),
                translate=(centres - start).tolist(),
                rotate=angles.tolist(),
                pivot=tuple(start),
                interpolation="smooth",
            ).validate(f"bodies[{k}].replay")
        )
    return out


def continuous_angles(angles: np.ndarray) -> np.ndarray:
    """Angles about x, then y, then z (radians, one row per key) made continuous from key to key,
    in degrees: of the two triples that give each rotation, ``(a, b, c)`` and ``(a + pi, pi - b,
    c + pi)``, the one nearer the last key's (a body tumbling past 90 degrees about y), each angle
    then within half a turn of the last key's."""
    out = np.array(angles, dtype=float)
    for i in range(1, len(out)):
        a, b, c = out[i]
        best = None
        for triple in ((a, b, c), (a + np.pi, np.pi - b, c + np.pi)):
            t = np.asarray(triple)
            t = out[i - 1] + (t - out[i - 1] + np.pi) % (2.0 * np.pi) - np.pi  # the nearest turn
            if best is None or np.abs(t - out[i - 1]).sum() < np.abs(best - out[i - 1]).sum():
                best = t
        out[i] = best
    return np.degrees(out)


def replay_poses(scene: Scene, t: float) -> dict:
    """The replayed boxes' poses at ``t`` as Simulation.bodies gives a free body's (centre, x y z w)."""
    from scipy.spatial.transform import Rotation

    position, orientation = [], []
    for o in scene.obstacles:
        if o.motion is None:
            continue
        translate, angles = o.motion.at(t)
        position.append(np.asarray(o.motion.pivot) + translate)
        orientation.append(Rotation.from_euler("xyz", np.radians(angles)).as_quat())
    return {"position": np.array(position), "orientation": np.array(orientation)}


def box_frame(x: np.ndarray, boxes: list, poses: dict, k: int) -> np.ndarray:
    """``x`` in box k's frame, from its centre (``poses``: Simulation.bodies; none for boxes that do
    not move, which stand where ``boxes`` puts them)."""
    lo, hi = boxes[k]
    if poses:
        centre, rot = poses["position"][k], quaternion_matrix(poses["orientation"][k])
    else:
        centre, rot = 0.5 * (np.asarray(hi) + np.asarray(lo)), np.eye(3)
    return (x - centre) @ rot


def inside_count(x: np.ndarray, boxes: list, poses: dict, inset: float = 0.0) -> int:
    """Fluid particles strictly inside any of the boxes at their poses (``poses``: Simulation.bodies;
    none for boxes that do not move), each box shrunk by ``inset`` on every side."""
    n = 0
    for k, (lo, hi) in enumerate(boxes):
        half = 0.5 * (np.asarray(hi) - np.asarray(lo)) - inset
        local = box_frame(x, boxes, poses, k)
        n += int(np.count_nonzero(np.all(np.abs(local) < half, axis=1)))
    return n


def outside_tank(boxes: list, poses: dict, lower, upper, margin: float) -> bool:
    """Whether a corner of a body's box lies beyond a face of the tank by more than ``margin``."""
    for k, (lo, hi) in enumerate(boxes):
        half = 0.5 * (np.asarray(hi) - np.asarray(lo))
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        corners = poses["position"][k] + (signs * half) @ quaternion_matrix(poses["orientation"][k]).T
        if np.any(corners < np.asarray(lower) - margin) or np.any(corners > np.asarray(upper) + margin):
            return True
    return False


def free_path(variant: str, overrides: list, duration) -> dict:
    """The path the free bodies of ``variant`` take (a run of its own, untimed, advanced frame by
    frame as the timed runs are): their centres and orientations at the first step every
    REPLAY_KEY_INTERVAL."""
    scene = flood(variant, overrides)
    duration = duration or scene.output.duration
    sim = Simulation(scene, "cpu", history=1)
    start = sim.bodies
    path = {"times": [0.0], "position": [start["position"]], "orientation": [start["orientation"]]}

    def on_step(r):
        if r["t"] - path["times"][-1] >= REPLAY_KEY_INTERVAL - 1e-9:
            pose = sim.bodies
            path["times"].append(r["t"])
            path["position"].append(pose["position"])
            path["orientation"].append(pose["orientation"])

    while sim.time < duration - 1e-9:
        sim.advance(min(1.0 / scene.output.fps, duration - sim.time), callback=on_step)
    return {key: np.array(v) for key, v in path.items()}


# what a timed flood run counts over its steps
COUNTED = ("steps", "obstacle_corrections", "wall_corrections", "corrected_steps", "iterations")


class FloodRun:
    """One timed run of ``variant``, advanced frame by frame at ``fps`` (None: the scene's; 0: in
    one call, its steps landing on no frame) by :meth:`frame`, one frame a call, so that several
    runs can take turns in one process (:func:`run_floods`)."""

    def __init__(self, variant: str, overrides: list, duration, fps: float | None = None):
        load = load_scene("flood", overrides)
        self.names = [b.name for b in load.bodies]
        self.boxes = [(b.shape.lower, b.shape.upper) for b in load.bodies]
        self.variant = variant
        self.replay = variant in REPLAYS
        if self.replay and REPLAYS[variant] not in _paths:
            _paths[REPLAYS[variant]] = free_path(REPLAYS[variant], overrides, duration)
        self.scene = scene = flood(variant, overrides, _paths[REPLAYS[variant]] if self.replay else None)
        self.duration = duration or scene.output.duration
        self.sim = Simulation(scene, "cpu", history=1)
        self.fps = scene.output.fps if fps is None else fps
        self.interval = 1.0 / self.fps if self.fps else self.duration
        self.counts = dict.fromkeys(COUNTED, 0)
        self.speeds = []
        # the boxes' walls for the last line: a free body's surface, a still box's inner boundary
        # layer h/2 inside its faces (sampled by faces; sph/containment.py)
        self.inset = 0.5 * scene.spacing if variant not in ("free", "free_half") else 0.0
        self.wall, self.inside, self.inside_frames, self.past_walls, self.left = 0.0, 0, 0, 0, False

    def _on_step(self, r) -> None:
        c = self.counts
        c["steps"] += 1
        c["obstacle_corrections"] += r["obstacle_corrections"]
        c["wall_corrections"] += r["wall_corrections"]
        c["corrected_steps"] += bool(r["obstacle_corrections"] or r["wall_corrections"])
        c["iterations"] += r["iterations"]
        self.speeds.append(r["max_velocity"])

    @property
    def done(self) -> bool:
        return self.sim.time >= self.duration - 1e-9

    def poses(self):
        return replay_poses(self.scene, self.sim.time) if self.replay else self.sim.bodies

    def frame(self) -> None:
        """The next frame, timed; the checks after it, untimed."""
        sim, scene = self.sim, self.scene
        t0 = time.perf_counter()
        sim.advance(min(self.interval, self.duration - sim.time), callback=self._on_step)
        self.wall += time.perf_counter() - t0
        poses = self.poses()
        k = inside_count(sim.positions, self.boxes, poses)
        self.inside += k
        self.inside_frames += bool(k)
        self.past_walls += inside_count(sim.positions, self.boxes, poses, self.inset) if self.inset else k
        if poses:
            self.left |= outside_tank(self.boxes, poses, scene.tank.lower, scene.tank.upper, scene.spacing)

    def result(self) -> dict:
        sim, counts, speeds, poses = self.sim, self.counts, self.speeds, self.poses()
        return {
            "variant": self.variant,
            "fps": self.fps,
            "particles": sim.n_particles,
            "boundary_particles": sim.model.n_boundary,
            "spacing": self.scene.spacing,
            "simulated_seconds": sim.time,
            "wall_seconds": self.wall,
            "wall_seconds_per_simulated_second": self.wall / sim.time,
            **counts,
            "mean_iterations": counts["iterations"] / counts["steps"],
            "median_fastest_speed": float(np.median(speeds)),  # the fastest particle's, over the steps (m/s)
            "fastest_speed": float(np.max(speeds)),
            "fast_steps": int(np.sum(np.asarray(speeds) > FAST)),
            "inside_bodies_at_frames": self.inside,  # centres inside the boxes' surfaces, summed over frames
            "past_walls_at_frames": self.past_walls,  # centres past their walls (module docstring), summed over frames
            "frames_with_particles_inside": self.inside_frames,
            "body_left_tank": self.left,
            "final_positions": poses["position"].tolist() if poses else None,
        }


def run_floods(variants, overrides: list, duration, fps: float | None = None) -> list:
    """Timed runs of ``variants`` taking turns frame by frame in one process, in the given order
    and then backwards (ABBA): a drift of the machine's speed over minutes (up to 30 % here) falls
    on every variant alike. Their results in the order of ``variants``."""
    runs = [FloodRun(v, overrides, duration, fps) for v in variants]
    turn = 0
    while not all(r.done for r in runs):
        for r in runs if turn % 2 == 0 else runs[::-1]:
            if not r.done:
                r.frame()
        turn += 1
    return [r.result() for r in runs]


# m/s: above the wave's front (3.7 m/s), a step whose fastest particle is this fast is counted
SETTER_SPEED = 4.0
SETTER_VARIANTS = ("free", "replayed", "fixed")


def box_distance(p: np.ndarray, half: np.ndarray) -> float:
    """Signed distance from ``p`` (in the box's frame, from its centre) to a box of ``half`` sides."""
    q = np.abs(p) - half
    return float(np.linalg.norm(np.maximum(q, 0.0)) + min(q.max(), 0.0))


class StepSetters:
    """What sets the step in a flood run (untimed, the scene's 30 fps frames): at every step whose
    fastest particle is over ``speed``, whether it is a lone droplet (no fluid particle within the
    kernel's support: then how much shorter its step was than the fastest other particle's would
    be, by the CFL rule's ``cfl h / (max(v, v_floor) + c)``, from the speeds at the step's end, a
    step late, and leaving out the steps fitted to land on a frame) and,
    where its flight began (an episode: a fastest particle not where the last one was heading),
    the two solids nearest it: the boxes (bodies or their still or moved
    stand-ins, in their frames), the post, the floor and the side and end walls."""

    def __init__(self, variant: str, overrides: list, duration: float, speed: float = SETTER_SPEED):
        self.run = run = FloodRun(variant, overrides, duration)
        self.speed = speed
        self.half = [0.5 * np.subtract(hi, lo) for lo, hi in run.boxes]
        post = run.scene.obstacles[0]  # the scene's own; a fixed or replayed variant's boxes come after it
        self.post = (0.5 * np.add(post.lower, post.upper), 0.5 * np.subtract(post.upper, post.lower))
        self.tank = np.asarray(run.scene.tank.upper)
        self.radius = run.sim.model.support_radius
        self.steps, self.fast, self.lone, self.lone_share, self.episodes = 0, 0, 0, 0.0, []
        self.series = {"t": [], "fastest": [], "dt": []}  # every step's end, fastest speed, length
        self._heading = None

    def solids(self, p: np.ndarray) -> list:
        """(name, distance) of every solid to ``p``, nearest first."""
        run, poses = self.run, self.run.poses()
        out = [(n, box_distance(box_frame(p, run.boxes, poses, k), self.half[k])) for k, n in enumerate(run.names)]
        out.append(("post", box_distance(p - self.post[0], self.post[1])))
        out += [("floor", float(p[1])), ("end walls", float(min(p[0], self.tank[0] - p[0])))]
        out.append(("side walls", float(min(p[2], self.tank[2] - p[2]))))
        return sorted(out, key=lambda s: s[1])

    def on_step(self, r) -> None:
        self.steps += 1
        sim = self.run.sim
        v = sim.velocities
        speed = np.linalg.norm(v, axis=1)
        i = int(np.argmax(speed))
        self.series["t"].append(r["t"])
        self.series["fastest"].append(float(speed[i]))
        self.series["dt"].append(r["dt"])
        if speed[i] <= self.speed:
            self._heading = None
            return
        x = sim.positions
        p = x[i]
        self.fast += 1
        from scipy.spatial import cKDTree

        near = cKDTree(x).query_ball_point(x, self.radius, return_length=True)  # each counts itself
        lone = bool(near[i] == 1)
        self.lone += lone
        if lone and np.any(near > 1):  # the share of its step the droplet took (docstring)
            floor, c = sim.loop.velocity_scale, sim.solver.signal_speed
            others = max(float(speed[near > 1].max()), floor) + c
            self.lone_share += 1.0 - others / (max(float(speed[i]), floor) + c)
        h = self.run.scene.spacing
        if self._heading is None or np.linalg.norm(p - self._heading) > h:
            (a, da), (b, db) = self.solids(p)[:2]
            nearest = [a, da, b, db]
            self.episodes.append({"t": r["t"], "speed": float(speed[i]), "lone": lone, "nearest": nearest, "steps": 0})
        self.episodes[-1]["steps"] += 1
        self._heading = p + v[i] * r["dt"]  # where it is headed at the next step

    def result(self) -> dict:
        run = self.run
        while not run.done:
            run.sim.advance(min(run.interval, run.duration - run.sim.time), callback=self.on_step)
        between = [e for e in self.episodes if e["nearest"][0] in run.names and e["nearest"][2] in run.names]
        return {
            "variant": run.variant,
            "duration": run.duration,
            "steps": self.steps,
            "fast_steps": self.fast,  # the fastest particle over the speed
            "lone_fast_steps": self.lone,  # ... and no fluid particle within the support
            # sum over those of 1 - (fastest speed with a neighbour) / (the droplet's): about the steps
            # the droplets added where the CFL rule set the step
            "steps_lone_droplets_added": self.lone_share,
            "episodes": self.episodes,
            "steps_of_flights_from_between_two_boxes": sum(e["steps"] for e in between),
            **self.series,
        }


def measure_step_setters(record: dict, overrides: list, duration: float, speed: float = SETTER_SPEED) -> None:
    """Part ``step_setters``: :class:`StepSetters` for SETTER_VARIANTS over ``duration``."""
    out = {}
    for variant in SETTER_VARIANTS:
        r = StepSetters(variant, overrides, duration, speed).result()
        out[variant] = r
        print(
            f"step setters, {variant:8s}: {r['steps']} steps to {duration:g} s, {r['fast_steps']} with a particle "
            f"over {speed:g} m/s ({r['lone_fast_steps']} a lone droplet), "
            f"{r['steps_of_flights_from_between_two_boxes']} from flights that began between two boxes; "
            f"the droplets added about {r['steps_lone_droplets_added']:.0f} steps",
            flush=True,
        )
    record["step_setters"] = {"speed": speed, "runs": out}


def pool(spacing: float, density: float, width: float = 0.4) -> Scene:
    """tests/test_bodies.py's pool: a 0.16 x 0.08 x 0.16 m box placed at its draft in the middle of
    a square pool ``width`` wide (0.4 m there) and 0.2 m deep."""
    scene = Scene(spacing=spacing, tank=Box((0, 0, 0), (width, 0.4, width)), name="pool")
    scene.add_fluid_box((0, 0, 0), (width, 0.2, width))
    draft = density / 1000.0 * 0.08
    bottom = 0.2 - draft + draft * 0.16**2 / width**2
    lo = 0.5 * width - 0.08
    scene.add_body(Box((lo, bottom, lo), (lo + 0.16, bottom + 0.08, lo + 0.16)), density=density)
    return scene


# where the drafts' level gauges stand, as fractions of the pool's width: its corners and the
# middles of two sides, 0.06 m from the walls and from the box in the 0.4 m pool
GAUGES = ((0.15, 0.15), (0.85, 0.15), (0.15, 0.85), (0.85, 0.85), (0.5, 0.15), (0.15, 0.5))


def run_draft(spacing: float, density: float, settle: float, end: float, method: str = "iisph") -> dict:
    """tests/test_bodies.py's settled_draft at ``spacing``: the mean draft over settle .. end,
    below the liquid's level by its rest volume and below the level the gauges read."""
    scene = pool(spacing, density)
    scene.physics.method = method
    for k, (u, w) in enumerate(GAUGES):
        scene.add_probe(Probe(f"gauge{k}", "level", position=(0.4 * u, 0.4 * w)))
    sim = Simulation(scene, "cpu", history=1)
    area, a_box, drafts, bottoms = 0.4 * 0.4, 0.16 * 0.16, [], []
    t0 = time.perf_counter()
    while sim.time < end - 1e-9:
        sim.advance(0.05)
        if sim.time > settle:
            bottom = sim.bodies["position"][0][1] - 0.04
            level = (sim.n_particles * spacing**3 - a_box * bottom) / (area - a_box)
            drafts.append(level - bottom)
            bottoms.append(bottom)
    wall = time.perf_counter() - t0
    target = density / 1000.0 * 0.08
    draft = float(np.mean(drafts))
    late = sim.probes.time > settle
    gauges = [float(np.mean(sim.probes[f"gauge{k}"][late])) for k in range(len(GAUGES))]
    draft_gauges = float(np.mean(gauges) - np.mean(bottoms))
    b = sim.bodies
    return {
        "method": method,
        "spacing": spacing,
        "density": density,
        **scene.physics.resolved(free_bodies=True),  # its walls' gradient and warm start, as the run took them
        "particles": sim.n_particles,
        "draft": draft,
        "target": target,
        "error_percent": 100.0 * (draft / target - 1.0),
        "gauge_levels": gauges,
        "draft_gauges": draft_gauges,
        "error_percent_gauges": 100.0 * (draft_gauges / target - 1.0),
        "heave_ptp": float(np.ptp(bottoms)),
        "tilt": float(np.abs(b["orientation"][0, :3]).max()),
        "drift": float(np.abs(b["position"][0][[0, 2]] - 0.2).max()),
        "wall_seconds": wall,
    }


# each part and the record's keys it writes (a part not run keeps its saved measurement)
PARTS = {
    "flood": ("flood",),
    "drafts": ("drafts", "settle"),
    "heave": ("heave",),
    "dfsph_drafts": ("dfsph_drafts", "settle"),
    "dfsph_heave": ("dfsph_heave",),
    "step_setters": ("step_setters",),
}
HEAVE_DROP = 0.02  # m below the placed draft
HEAVE_HOLD = 0.5  # s the box is held there while the liquid settles around it, then released
PLATE_CA = 0.579  # DNV-RP-H103 Table A-2, a square flat plate (b / a = 1), on V_R = pi / 4 a^2 b


def heave_estimate(width: float = 0.4, rho: float = 1000.0, g: float = 9.81) -> dict:
    """The density 500 box's undamped heave period in the pool ``width`` wide from its hydrostatic
    stiffness and the added mass of a square plate at a free surface (see the module)."""
    side, height, pool_area = 0.16, 0.08, width * width
    mass = 500.0 * side * side * height
    area = side * side
    stiffness = rho * g * area / (1.0 - area / pool_area)
    added = 0.5 * rho * PLATE_CA * np.pi / 4.0 * side**3
    return {
        "mass": mass,
        "stiffness": stiffness,
        "added_mass": added,
        "period": 2.0 * np.pi * np.sqrt((mass + added) / stiffness),
        "period_without_added_mass": 2.0 * np.pi * np.sqrt(mass / stiffness),
    }


def lowered_pool(spacing: float, width: float = 0.4, hold: float = HEAVE_HOLD) -> Scene:
    """``pool``'s density 500 box placed HEAVE_DROP below its draft, held there until ``hold``."""
    scene = pool(spacing, 500.0, width)
    b = scene.bodies[0].shape
    scene.bodies[0].shape = Box(np.add(b.lower, (0, -HEAVE_DROP, 0)), np.add(b.upper, (0, -HEAVE_DROP, 0)))
    scene.bodies[0].release_time = hold
    return scene


def run_heave(scene: Scene, duration: float, **physics) -> dict:
    """``scene``'s first body, held until its ``release_time`` while the liquid settles around it,
    then free: its centre's height every 5 ms for ``duration`` seconds from the release (times
    from it), the liquid's speeds at the release, and a damped cosine fitted to it. ``physics``:
    settings changed from the scene's."""
    for key, value in physics.items():
        setattr(scene.physics, key, value)
    scene.validate()
    hold = scene.bodies[0].release_time
    sim = Simulation(scene, "cpu", history=1)
    t0 = time.perf_counter()
    sim.advance(hold)
    speed = np.linalg.norm(sim.velocities, axis=1)
    t, y = [0.0], [sim.bodies["position"][0][1]]
    while sim.time < hold + duration - 1e-9:
        sim.advance(0.005)
        t.append(sim.time - hold)
        y.append(sim.bodies["position"][0][1])
    wall = time.perf_counter() - t0
    fit = fit_damped(t, y)
    fit["crossing_period"] = crossing_period(fit["t"], fit["y"], fit["equilibrium"])
    lo, hi = scene.tank.bounds
    return {
        "spacing": scene.spacing,
        "width": float(hi[0] - lo[0]),
        "hold": hold,
        "viscosity": scene.physics.viscosity,
        "warm_start": scene.physics.resolved(free_bodies=True)["warm_start"],
        "particles": sim.n_particles,
        "liquid_speed_at_release": {"mean": float(speed.mean()), "max": float(speed.max())},
        **fit,
        "wall_seconds": wall,
    }


def fit_damped(t, y) -> dict:
    """A damped cosine fitted to a heave record: its damped period, damping ratio, undamped period
    ``T_d sqrt(1 - zeta^2)``, equilibrium and the fit's rms residual, and the record itself."""
    from scipy.optimize import curve_fit

    t, y = np.asarray(t, float), np.asarray(y, float)

    def damped(t, amplitude, zeta, omega, phase, rest):
        return rest + amplitude * np.exp(-zeta * omega * t) * np.cos(omega * np.sqrt(1.0 - zeta**2) * t + phase)

    guess = [y[0] - y[-1], 0.2, 2.0 * np.pi / 0.5, 0.0, float(y[-len(y) // 3 :].mean())]
    bounds = ([-1.0, 0.0, 1.0, -2 * np.pi, -1.0], [1.0, 0.95, 100.0, 2 * np.pi, 1.0])
    (amplitude, zeta, omega, phase, rest), _ = curve_fit(damped, t, y, p0=guess, bounds=bounds)
    fit = damped(t, amplitude, zeta, omega, phase, rest)
    return {
        "t": t.tolist(),
        "y": y.tolist(),
        "damped_period": float(2.0 * np.pi / (omega * np.sqrt(1.0 - zeta**2))),
        "damping_ratio": float(zeta),
        "natural_period": float(2.0 * np.pi / omega),
        "equilibrium": float(rest),
        "fit_rms": float(np.sqrt(np.mean((fit - y) ** 2))),
    }


def summarize(runs: list) -> dict:
    """The medians of each variant's runs and their ratios: per simulated second (what a user
    waits) and per step (the free bodies' own cost; their motion also changes the steps the CFL
    rule takes)."""

    def median(value, v):
        return statistics.median(value(r) for r in runs if r["variant"] == v)

    variants = [v for v in FLOOD_VARIANTS if any(r["variant"] == v for r in runs)]
    per_s = {v: median(lambda r: r["wall_seconds_per_simulated_second"], v) for v in variants}
    per_step = {v: median(lambda r: r["wall_seconds"] / r["steps"], v) for v in variants}
    out = {
        "particles": runs[0]["particles"],
        "median_wall_seconds_per_simulated_second": per_s,
        "cost_ratio": per_s["free"] / per_s["fixed"],
        "median_ms_per_step": {v: 1e3 * t for v, t in per_step.items()},
        "cost_ratio_per_step": per_step["free"] / per_step["fixed"],
        **{
            key: {v: [r[key] for r in runs if r["variant"] == v] for v in variants}
            for key in ("steps", "obstacle_corrections", "mean_iterations")
        },
    }
    if "free_half" in per_s and "fixed_half" in per_s:  # both from the half start
        out["cost_ratio_half_start"] = per_s["free_half"] / per_s["fixed_half"]
        out["cost_ratio_per_step_half_start"] = per_step["free_half"] / per_step["fixed_half"]
    if "free_half" in per_s:  # the free bodies' default until 2026-12-06 against the fixed scene's
        out["cost_ratio_free_half_to_fixed"] = per_s["free_half"] / per_s["fixed"]
    # the coupling alone: the free bodies against boxes moved along their path, from the same start
    for free, replayed in (("free", "replayed"), ("free_half", "replayed_half")):
        if free in per_s and replayed in per_s:
            out[f"cost_ratio_{free}_to_{replayed}"] = per_s[free] / per_s[replayed]
            out[f"cost_ratio_per_step_{free}_to_{replayed}"] = per_step[free] / per_step[replayed]
    return out


def step_setters_chart(ax, setters: dict) -> None:
    """Each variant's fastest particle over its steps (part ``step_setters``), the flights that
    began between two boxes marked where they began."""
    labels = {"free": "free bodies", "replayed": "moved along the free path", "fixed": "held still"}
    for (variant, r), color in zip(setters["runs"].items(), ("C0", "C2", "C1")):
        ax.plot(
            r["t"],
            r["fastest"],
            color=color,
            lw=1.0,
            label=f"{labels.get(variant, variant)}: {r['steps']} steps, droplets ~{r['steps_lone_droplets_added']:.0f}",
        )
        for e in r["episodes"]:
            if e["steps"] >= 10:
                ax.annotate(f"{e['nearest'][0]} / {e['nearest'][2]}", (e["t"], e["speed"]), fontsize=7, color=color)
    ax.axhline(setters["speed"], color="grey", lw=0.8, ls=":")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("fastest particle (m/s)")
    ax.set_title(
        f"What sets the step: the fastest particle (over {setters['speed']:g} m/s dotted);\n"
        "flights of 10 steps or more labelled with the two solids they began between",
        fontsize=9,
    )
    ax.legend(fontsize=8)


def chart(record: dict, path) -> None:
    plt = pyplot()
    setters = record.get("step_setters")
    panels = 4 if setters else 3
    fig, axes = plt.subplots(
        1, panels, figsize=(20 + 5 * (panels - 3), 4.8), gridspec_kw={"width_ratios": [1.6, 1, 1, 1][:panels]}
    )
    a, b, c = axes[:3]
    if setters:
        step_setters_chart(axes[3], setters)
    runs = record["flood"]["runs"]
    names = {
        "free": "free bodies",
        "fixed": "bodies fixed\n(still obstacles)",
        "replayed": "moved along\nthe free path",
        "free_half": "free,\nhalf warm start",
        "fixed_half": "fixed,\nhalf start",
        "replayed_half": "moved along its path,\nhalf start",
    }
    shown = [v for v in FLOOD_VARIANTS if any(r["variant"] == v for r in runs)]
    for i, variant in enumerate(shown):
        ys = [r["wall_seconds_per_simulated_second"] for r in runs if r["variant"] == variant]
        a.scatter([i] * len(ys), ys, color=f"C{i}", alpha=0.6)
        a.bar(i, statistics.median(ys), width=0.5, color=f"C{i}", alpha=0.5)
    s = record["flood"]["summary"]
    a.set_xticks(range(len(shown)), [names[v] for v in shown], fontsize=8)
    a.set_ylabel("wall s per simulated s (median, repeats as dots)")
    a.set_title(
        f"flood, {s['particles']} particles: free / fixed = {s['cost_ratio']:.2f} per simulated s, "
        f"{s['cost_ratio_per_step']:.2f} per step"
        + (
            f"\nfree / moved along its path: {s['cost_ratio_free_to_replayed']:.2f}"
            if "cost_ratio_free_to_replayed" in s
            else ""
        )
        + (
            f"; from the half start: free / fixed {s['cost_ratio_half_start']:.2f}, "
            f"free / moved {s['cost_ratio_free_half_to_replayed_half']:.2f}"
            if "cost_ratio_half_start" in s and "cost_ratio_free_half_to_replayed_half" in s
            else ""
        ),
        fontsize=9,
    )
    for key, name, color in (("drafts", "IISPH", "C0"), ("dfsph_drafts", "DFSPH", "C3")):
        for density, marker in ((500.0, "o"), (250.0, "s")):
            rows = [r for r in record.get(key, []) if r["density"] == density]
            h = [r["spacing"] for r in rows]
            if rows and "error_percent_gauges" in rows[0]:
                gauged = [r["error_percent_gauges"] for r in rows]
                b.plot(h, gauged, marker=marker, color=color, label=f"{name}, density {density:g}")
            if rows:
                b.plot(h, [r["error_percent"] for r in rows], marker=marker, color=color, ls=":", fillstyle="none")
    b.axhline(0.0, color="k", lw=0.8)
    for y in (-2.0, 2.0):
        b.axhline(y, color="grey", lw=0.8)
    b.set_xscale("log")
    b.set_xlabel("spacing h (m)")
    b.set_ylabel("draft error (%) vs half / quarter of the box height")
    b.set_title(
        "Archimedes: drafts below the gauges' level (solid)\n"
        "and the rest volume's (dotted, open); grey: the issue's 2 %",
        fontsize=9,
    )
    b.legend(fontsize=8)
    heave = record.get("heave")
    if heave:
        est = heave["estimate"]["period"]
        for r in heave["runs"]:
            line = c.plot(r["t"], 1e3 * (np.array(r["y"]) - r["equilibrium"]), lw=1.2)[0]
            c.plot(
                [],
                [],
                color=line.get_color(),
                label=(
                    f"h {r['spacing']:g}: T {r['damped_period']:.3f} s, zeta {r['damping_ratio']:.2f}, "
                    f"undamped {r['natural_period_error_percent']:+.1f} %"
                ),
            )
        ref = heave.get("reference")
        colors = ("tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink")
        for (name, run), color in zip(heave.get("open", {}).items(), colors):
            c.plot(
                run["t"],
                1e3 * (np.array(run["y"]) - run["equilibrium"]),
                color=color,
                lw=1.2,
                label=(
                    f"h {run['spacing']:g}, {heave['open_pool']:g} m pool, {name}: "
                    f"T {run['damped_period']:.3f} s, zeta {run['damping_ratio']:.2f}"
                ),
            )
        dh = record.get("dfsph_heave")
        if dh:
            c.plot(
                dh["t"],
                1e3 * (np.array(dh["y"]) - dh["equilibrium"]),
                color="tab:olive",
                lw=1.2,
                label=(
                    f"DFSPH, h {dh['spacing']:g}, {dh['width']:g} m pool, heave scene: "
                    f"T {dh['damped_period']:.3f} s, zeta {dh['damping_ratio']:.2f}"
                ),
            )
        if ref:
            c.plot(
                ref["t"],
                1e3 * (np.array(ref["y"]) - ref["equilibrium"]),
                color="k",
                ls="--",
                lw=1.0,
                label=f"linear theory (Capytaine): T {ref['damped_period']:.3f} s, zeta {ref['damping_ratio']:.2f}",
            )
        c.axhline(0.0, color="k", lw=0.8)
        c.set_xlabel(f"t from the release (s; held {heave.get('hold', 0.0):g} s before)")
        c.set_ylabel("box centre above its fitted rest (mm)")
        c.set_title(f"Heave from {1e3 * heave['drop']:.0f} mm low (estimate: undamped {est:.3f} s)", fontsize=10)
        c.legend(fontsize=8)
    else:
        c.set_axis_off()
    fig.suptitle(
        f"{record['device_name']}, {record['threads']} threads, "
        + ", ".join(f"{part} {day}" for part, day in record.get("part_dates", {"run": record["date"]}).items())
        + (" (shared machine: timings noisy)" if record.get("shared_machine") else ""),
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="interleaved runs of each flood variant")
    ap.add_argument("--spacings", default="0.02,0.01", help="the drafts' spacings (m)")
    ap.add_argument("--quick", action="store_true", help="a coarse, short flood once each and drafts at 0.04 m")
    ap.add_argument("--replot", action="store_true", help="redraw the chart from the saved JSON")
    ap.add_argument(
        "--parts",
        default=",".join(PARTS),
        help="which parts to measure; a part left out keeps what the saved bodies.json holds (not with --quick)",
    )
    ap.add_argument("--shared-machine", action="store_true", help="record that other jobs shared the machine")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    if args.replot:  # the summary recomputed from the saved runs, the chart redrawn
        record = json.loads((RESULTS / "bodies.json").read_text())
        flood = record["flood"]
        flood["summary"] = summarize(flood["runs"])
        if "schedule_runs" in flood:
            flood["summary"]["schedules"] = schedule_summary(flood["runs"], flood["schedule_runs"])
        chart(record, save(record, args.out, "bodies", False))
        return
    if args.quick:
        overrides, duration, repeats, spacings, settle, end = ["spacing=0.04"], 0.3, 1, [0.04], 0.3, 0.5
    else:
        overrides, duration, repeats, spacings, settle, end = (
            [],
            None,
            args.repeats,
            [float(s) for s in args.spacings.split(",")],
            1.0,
            1.6,
        )
    parts = set(args.parts.split(","))
    if parts - set(PARTS):
        ap.error(f"--parts: must be among {', '.join(PARTS)}")
    warm_up()
    record = header("bodies", threads=get_threads(), quick=args.quick, shared_machine=args.shared_machine)
    keep_parts(record, args.out, "bodies", PARTS, parts, args.quick)
    if "flood" in parts:
        measure_flood(record, overrides, duration, repeats, (0.0,) if args.quick else SCHEDULES)
    if "step_setters" in parts:
        # quick: a coarse, short run whose front is slower, a lower speed to count
        measure_step_setters(record, overrides, duration or 1.0, 1.0 if args.quick else SETTER_SPEED)

    def checkpoint():
        save(record, args.out, "bodies", args.quick)

    previous = {} if args.quick or not (Path(args.out) / "bodies.json").is_file() else saved(args.out, "bodies")[0]
    if "drafts" in parts:
        measure_drafts(record, spacings, settle, end, checkpoint=checkpoint, kept=previous.get("drafts", []))
    if "dfsph_drafts" in parts:
        measure_drafts(record, spacings, settle, end, "dfsph", checkpoint)
    if "dfsph_heave" in parts:
        measure_dfsph_heave(record, spacings[0], 0.6 if args.quick else 1.5, args.quick)
    if "heave" in parts:
        measure_heave(record, spacings, 0.6 if args.quick else 1.5, args.quick)
    chart(record, save(record, args.out, "bodies", args.quick))


def measure_flood(record: dict, overrides: list, duration, repeats: int, schedules: tuple = SCHEDULES) -> None:
    runs = []
    for i in range(repeats):
        for r in run_floods(FLOOD_VARIANTS, overrides, duration):
            runs.append(r)
            print(
                f"flood {r['variant']:10s} #{i}: {r['particles']} particles, {r['steps']} steps, "
                f"{r['wall_seconds_per_simulated_second']:.1f} wall s per s, corrections {r['obstacle_corrections']} "
                f"(walls {r['wall_corrections']}), inside at frames {r['inside_bodies_at_frames']} "
                f"(past the walls {r['past_walls_at_frames']}), "
                f"left the tank {r['body_left_tank']}",
                flush=True,
            )
    scheduled = []
    for fps in schedules:
        for r in run_floods(("free", "replayed"), overrides, duration, fps):
            scheduled.append(r)
            print(
                f"flood {r['variant']:10s} at {fps:g} fps: {r['steps']} steps, "
                f"{r['wall_seconds_per_simulated_second']:.1f} wall s per s, fastest {r['fastest_speed']:.2f} m/s, "
                f"{r['fast_steps']} steps over {FAST:g} m/s",
                flush=True,
            )
    summary = summarize(runs)
    summary["schedules"] = schedule_summary(runs, scheduled)
    med = summary["median_wall_seconds_per_simulated_second"]
    print(
        f"flood: free / fixed = {summary['cost_ratio']:.3f} "
        f"(medians {med['free']:.1f} and {med['fixed']:.1f} wall s per s), "
        f"{summary['cost_ratio_per_step']:.3f} per step; free / replayed along its path "
        f"{summary.get('cost_ratio_free_to_replayed', float('nan')):.3f}; from the half start: free / fixed "
        f"{summary.get('cost_ratio_half_start', float('nan')):.3f}, free / replayed "
        f"{summary.get('cost_ratio_free_half_to_replayed_half', float('nan')):.3f}; free from the half start / "
        f"fixed {summary.get('cost_ratio_free_half_to_fixed', float('nan')):.3f}"
    )
    record["flood"] = {
        "overrides": overrides,
        "repeats": repeats,
        "runs": runs,
        "schedule_runs": scheduled,
        "summary": summary,
    }


def median_per_s(runs: list) -> float:
    return statistics.median(r["wall_seconds_per_simulated_second"] for r in runs)


def schedule_summary(runs: list, schedules: list) -> dict:
    """Per landing schedule (the timed runs' own first), the free bodies' steps and wall time per
    simulated second over their replay's, and the medians over the schedules."""
    out = {}
    fps_all = sorted({r["fps"] for r in runs + schedules}, key=lambda f: (f == 0, f))
    for fps in fps_all:
        pick = {v: [r for r in runs + schedules if r["variant"] == v and r["fps"] == fps] for v in ("free", "replayed")}
        if not (pick["free"] and pick["replayed"]):
            continue
        free, replay = pick["free"][0], pick["replayed"][0]  # the steps are the same in every repeat
        out[f"{fps:g}"] = {
            "steps": [free["steps"], replay["steps"]],
            "fastest_speed": [free["fastest_speed"], replay["fastest_speed"]],
            "fast_steps": [free["fast_steps"], replay["fast_steps"]],
            "step_ratio": free["steps"] / replay["steps"],
            "cost_ratio": median_per_s(pick["free"]) / median_per_s(pick["replayed"]),
        }
    rows = list(out.values())
    if rows:
        out["median_step_ratio"] = statistics.median(r["step_ratio"] for r in rows)
        out["median_cost_ratio"] = statistics.median(r["cost_ratio"] for r in rows)
    return out


def measure_drafts(
    record: dict, spacings: list, settle: float, end: float, method: str = "iisph", checkpoint=None, kept=()
) -> None:
    """Each spacing's drafts of the density 500 and 250 boxes; ``checkpoint()`` after each, with
    the record holding the drafts measured so far (a long run stopped keeps what it measured) and
    ``kept``, the saved runs at other spacings (each run says which walls' gradient it had; runs
    saved before 2026-12-06 had Akinci's)."""
    kept = [{**r, "wall_gradient": r.get("wall_gradient", "akinci")} for r in kept if r["spacing"] not in spacings]
    drafts = []
    for h in spacings:
        for density in (500.0, 250.0):
            d = run_draft(h, density, settle, end, method)
            drafts.append(d)
            print(
                f"{method} draft h {h:g} density {density:g}: {d['draft']:.5f} m against {d['target']:.5f} "
                f"({d['error_percent']:+.1f} %) below the level by the rest volume, {d['draft_gauges']:.5f} m "
                f"({d['error_percent_gauges']:+.1f} %) below the gauges' level, {d['particles']} particles, "
                f"{d['wall_seconds']:.0f} s",
                flush=True,
            )
            record["drafts" if method == "iisph" else f"{method}_drafts"] = sorted(
                drafts + kept, key=lambda r: (-r["spacing"], -r["density"])
            )
            record["settle"] = [settle, end]
            if checkpoint is not None:
                checkpoint()


def crossing_period(t, y, rest: float) -> float | None:
    """Twice the time between the record's first two crossings of ``rest`` (linearly interpolated):
    the period of its first swing, which needs no model of the decay (a damped cosine crosses every
    half period) and, unlike the later crossings of a strongly damped record, stands well above the
    pool's own slosh; None with fewer than two crossings."""
    t, z = np.asarray(t, float), np.asarray(y, float) - rest
    k = np.nonzero(np.sign(z[1:]) != np.sign(z[:-1]))[0][:2]
    if len(k) < 2:
        return None
    crossings = t[k] - z[k] * (t[k + 1] - t[k]) / (z[k + 1] - z[k])
    return float(2.0 * (crossings[1] - crossings[0]))


def heave_reference(run: dict) -> dict | None:
    """Linear potential flow's free decay of the box in open water (heave_reference.py; None
    without Capytaine), released from rest as far from rest as ``run``'s box, fitted as the run is."""
    try:
        import capytaine  # noqa: F401
    except ImportError:
        print("heave reference: Capytaine (pip install 'warp_iisph[bench]') is not installed, skipped")
        return None
    import heave_reference as linear

    # the simulated pool's mass and stiffness (its level rises as the box sinks: 1.8 % above open water's)
    box = heave_estimate(run["width"])
    mass, stiffness = box["mass"], box["stiffness"]
    rad = linear.radiation(0.16, 0.04, 0.2)
    t = np.asarray(run["t"], float)
    t_ref, z = linear.free_decay(mass, stiffness, rad, float(run["y"][0] - run["equilibrium"]), float(t[-1]))
    fit = fit_damped(t, np.interp(t, t_ref, z))  # sampled as the run is
    fit["crossing_period"] = crossing_period(fit["t"], fit["y"], fit["equilibrium"])
    w = linear.natural_frequency(mass, stiffness, rad)
    return {
        "radiation": rad,
        "mass": mass,
        "stiffness": stiffness,
        "resonance_period": 2.0 * np.pi / w,  # where w^2 (M + A(w)) = k
        "added_mass_at_resonance": float(np.interp(w, rad["omega"], rad["added_mass"])),
        "damping_at_resonance": float(np.interp(w, rad["omega"], rad["damping"])),
        **fit,
    }


# the open pool's runs: the bundled heave scene as it is (viscosity 0.01), at the default viscosity,
# and in the liquid linear theory assumes (no viscosity)
OPEN_RUNS = {"heave scene": {}, "defaults": {"viscosity": Physics().viscosity}, "inviscid": {"viscosity": 0.0}}


def measure_heave(record: dict, spacings: list, duration: float, quick: bool) -> None:
    estimate = heave_estimate()
    hold = 0.2 if quick else HEAVE_HOLD
    runs = []
    for h in spacings:
        r = run_heave(lowered_pool(h, hold=hold), duration)
        r["natural_period_error_percent"] = 100.0 * (r["natural_period"] / estimate["period"] - 1.0)
        runs.append(r)
        print(
            f"heave h {h:g}: damped period {r['damped_period']:.3f} s, damping ratio {r['damping_ratio']:.3f}, "
            f"undamped {r['natural_period']:.3f} s against the estimate {estimate['period']:.3f} s "
            f"({r['natural_period_error_percent']:+.1f} %), fit rms {1e3 * r['fit_rms']:.2f} mm, "
            f"{r['particles']} particles, {r['wall_seconds']:.0f} s",
            flush=True,
        )
    record["heave"] = {"drop": HEAVE_DROP, "hold": hold, "estimate": estimate, "runs": runs}

    # the bundled heave scene (the open pool) against linear theory, as it is, at the default
    # viscosity and without viscosity; quick: coarser, held shorter
    overrides = heave_scene_overrides(spacings[0], hold, quick)
    open_runs = {name: run_heave(load_scene("heave", overrides), duration, **ph) for name, ph in OPEN_RUNS.items()}
    reference = None if quick else heave_reference(open_runs["heave scene"])
    for name, run in open_runs.items():
        score(run, reference)
        print(
            f"heave h {run['spacing']:g} in a {run['width']:g} m pool, {name}, from its release: damped period "
            f"{run['damped_period']:.3f} s (first swing {seconds(run['crossing_period'])}), damping ratio "
            f"{run['damping_ratio']:.3f}, liquid at release: mean {1e3 * run['liquid_speed_at_release']['mean']:.1f}"
            f" mm/s, max {1e3 * run['liquid_speed_at_release']['max']:.0f} mm/s"
            + (
                f"; linear theory (Capytaine, Cummins): {reference['damped_period']:.3f} s (first swing "
                f"{seconds(reference['crossing_period'])}), {reference['damping_ratio']:.3f}"
                if reference
                else ""
            )
            + f", {run['particles']} particles, {run['wall_seconds']:.0f} s",
            flush=True,
        )
    record["heave"].update(open_pool=open_runs["heave scene"]["width"], open=open_runs, reference=reference)


def heave_scene_overrides(spacing: float, hold: float, quick: bool) -> list:
    """The bundled heave scene as it is; quick: coarser, held shorter."""
    return [f"spacing={spacing}", f"bodies.0.release_time={hold}"] if quick else []


def score(run: dict, reference) -> None:
    """A heave run's periods as per cent off linear theory's (``reference``; none: nothing)."""
    for key in ("damped_period", "natural_period", "crossing_period"):
        if reference and run[key] is not None and reference[key] is not None:
            run[f"{key}_error_percent"] = 100.0 * (run[key] / reference[key] - 1.0)


def measure_dfsph_heave(record: dict, spacing: float, duration: float, quick: bool) -> None:
    """The bundled heave scene as it is, with DFSPH, against the linear theory the heave part
    computed (kept from the saved file where that part is not run; none in quick mode)."""
    overrides = heave_scene_overrides(spacing, 0.2 if quick else HEAVE_HOLD, quick)
    run = run_heave(load_scene("heave", [*overrides, "physics.method=dfsph"]), duration)
    reference = (record.get("heave") or {}).get("reference")
    score(run, reference)
    print(
        f"DFSPH heave h {run['spacing']:g} in a {run['width']:g} m pool, the heave scene: damped period "
        f"{run['damped_period']:.3f} s (first swing {seconds(run['crossing_period'])}), damping ratio "
        f"{run['damping_ratio']:.3f}"
        + (f"; linear theory {reference['damped_period']:.3f} s, {reference['damping_ratio']:.3f}" if reference else "")
        + f", {run['particles']} particles, {run['wall_seconds']:.0f} s",
        flush=True,
    )
    record["dfsph_heave"] = run


def seconds(value) -> str:
    return "none" if value is None else f"{value:.3f} s"


if __name__ == "__main__":
    main()
