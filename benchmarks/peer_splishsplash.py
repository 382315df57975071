"""SPlisHSPlasH (pysplishsplash, the `bench` extra) on the benchmark dam break, for a side-by-side
in the same run as ours: a 0.96 m cube of water (32^3 particles at 3 cm) in a 4 x 3 x 1.5 m tank,
IISPH or DFSPH, eta 0.1 %, CFL 0.5, dt <= 5 ms, Akinci boundary particles (its boundary handling
0: one layer sampled on the tank mesh, which sits 0.6 spacings outside the faces, where its fluid
starts at rest density), the fluid block sampled as ours (the first particle half a spacing
inside), its own viscosity 0.01 ("Standard", = our default 0.05), z-sorted. Prints one JSON record: wall
seconds per simulated second (between the first and the last step), steps, mean iterations and
the mean actual compression mean(max(rho/rho0 - 1, 0)) sampled every 20 steps.

Run it through :func:`run` (it sets the environment the wheel needs), or:

    LD_PRELOAD=/lib/x86_64-linux-gnu/libGLdispatch.so.0 OMP_NUM_THREADS=2 \\
        python benchmarks/peer_splishsplash.py --duration 1

``--scene martin_moyce --nx N`` runs validation.py's Martin & Moyce set-up instead (a column a = 0.3 m
wide, 2a high and 0.5a deep against the x = 0 wall of a 6a x 3a x 0.5a tank, N particles across, the
same sampling, viscosity and CFL as above) and adds the surge front (``surge_front``, the measure
ours gets) at every step to the record as ``T``/``Z`` (T = t sqrt(2g/a), Z = front / a), and
``escaped``: the most particles found beyond the tank mesh (0.6 spacings outside the faces) at
any step.

``--scene spheric_test2 --spacing H`` runs the bundled SPHERIC Test 2 scene (the MARIN dam break
onto a box): the tank and water as ours, the box a static rigid body (its mesh 0.6 spacings inside
the box's faces, where its boundary particles hold the water at the faces, as the tank's do) and,
every 5 ms, the readings of our pressure sensors and level gauges taken from its particles
(``warp_iisph.analysis.sensors``: the same definitions, in NumPy, its pressures converted to
pascals by :func:`pressures`) as ``probes``.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from warp_iisph.analysis.dam_break import surge_front

PRELOAD = "/lib/x86_64-linux-gnu/libGLdispatch.so.0"
G = 9.81
MM_WIDTH = 0.3  # validation.py's Martin & Moyce column width a (m)
PROBE_INTERVAL = 0.005  # how often the SPHERIC Test 2 sensors are read from its particles (s)
BOX = (
    "\n".join(
        [
            "v -0.5 -0.5 -0.5",
            "v 0.5 -0.5 -0.5",
            "v 0.5 0.5 -0.5",
            "v -0.5 0.5 -0.5",
            "v -0.5 -0.5 0.5",
            "v 0.5 -0.5 0.5",
            "v 0.5 0.5 0.5",
            "v -0.5 0.5 0.5",
            "f 1 3 2",
            "f 1 4 3",
            "f 5 6 7",
            "f 5 7 8",
            "f 1 2 6",
            "f 1 6 5",
            "f 4 8 7",
            "f 4 7 3",
            "f 1 5 8",
            "f 1 8 4",
            "f 2 3 7",
            "f 2 7 6",
        ]
    )
    + "\n"
)


def available() -> bool:
    """Whether pysplishsplash is installed (the `bench` extra)."""
    try:
        import importlib.util

        return importlib.util.find_spec("pysplishsplash") is not None
    except (ImportError, ValueError):
        return False


def run(
    duration: float = 1.0,
    threads: int = 2,
    method: str = "iisph",
    spacing: float = 0.03,
    timeout: float = 3600,
    scene: str = "dam_break",
    nx: int = 20,
) -> dict | None:
    """The peer's record (see the module), in a subprocess; ``None`` when it is not installed."""
    if not available():
        return None
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    if Path(PRELOAD).exists():
        env["LD_PRELOAD"] = PRELOAD
    p = subprocess.run(
        [
            sys.executable,
            __file__,
            "--duration",
            str(duration),
            "--method",
            method,
            "--spacing",
            str(spacing),
            "--scene",
            scene,
            "--nx",
            str(nx),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )
    if p.returncode != 0:
        raise RuntimeError(f"SPlisHSPlasH failed: {p.stderr.strip()[-500:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def pressures(sim, method: str, rho: np.ndarray, dt: float) -> np.ndarray:
    """The peer's particle pressures (Pa) after a step of ``dt`` (s), from its solver's field (the
    Python binding of 2.19 gives DFSPH no ``getSimulationData``)."""
    fm = sim.getFluidModel(0)
    n, rho0 = fm.numActiveParticles(), fm.getDensity0()
    if method == "iisph":
        # SPlisHSPlasH/IISPH/TimeStepIISPH.cpp (computePressureAccels: a_i = -sum V_j (p_i/rho_i'^2 +
        # p_j/rho_j'^2) gradW, rho' = rho/rho0) solves for p = P/rho0: pascals are rho0 p
        return rho0 * np.array(fm.getFieldBuffer("pressure"), dtype=np.float64).reshape(-1)[:n]
    # SPlisHSPlasH/DFSPH/TimeStepDFSPH.cpp (computePressureAccel: a_i = -sum V_j (k_i + k_j) gradW;
    # pressureSolve ends with k *= h^2) keeps k dt^2 with k = P rho0/rho^2: pascals are k rho^2/rho0
    k = np.array(fm.getFieldBuffer("p / rho^2"), dtype=np.float64).reshape(-1)[:n] / dt**2
    return k * rho**2 / rho0


def sensor_readings(sim, sensors, h, method: str = "iisph", dt: float = 0.0, scene=None) -> list:
    """Our pressure sensors' and level gauges' readings from the peer's particles now (its
    pressures, in pascals: :func:`pressures`), in the scene's order; the gauges beside ``scene``'s
    walls as ours (their share of the kernel's support)."""
    from scipy.spatial import cKDTree

    from warp_iisph.analysis.sensors import level_readings, pressure_readings

    fm = sim.getFluidModel(0)
    n = fm.numActiveParticles()
    x = np.array([fm.getPosition(i) for i in range(n)], dtype=np.float64)
    rho = np.array([fm.getDensity(i) for i in range(n)], dtype=np.float64)
    p = pressures(sim, method, rho, dt)
    tree = cKDTree(x)
    pressure = [s for s in sensors if s.kind == "pressure"]
    levels = [s for s in sensors if s.kind == "level"]
    out = pressure_readings(
        x, p, rho, [s.position for s in pressure], [s.normal for s in pressure], h, fm.getDensity0(), (0, -G, 0), tree
    )
    top = max(x[:, 1].max(), 0.0) + 2 * h
    walls = {"tank": scene.tank, "obstacles": scene.obstacles} if scene is not None else {}
    heights = level_readings(x, [s.position for s in levels], levels[0].bottom, top, h, tree, **walls) if levels else []
    return [float(v) for v in out] + [float(v) for v in heights]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--method", choices=("iisph", "dfsph"), default="iisph")
    ap.add_argument("--spacing", type=float, default=0.03)
    ap.add_argument("--scene", choices=("dam_break", "martin_moyce", "spheric_test2"), default="dam_break")
    ap.add_argument("--nx", type=int, default=20, help="Martin & Moyce: particles across the column (sets the spacing)")
    args = ap.parse_args()
    import pysplishsplash as sph

    block_lo, obstacles, sensors, ours = np.zeros(3), [], None, None
    if args.scene == "martin_moyce":
        a = MM_WIDTH
        h = a / args.nx
        tank, block = np.array([6 * a, 3 * a, 0.5 * a]), np.array([a, 2 * a, 0.5 * a])
    elif args.scene == "spheric_test2":
        from warp_iisph.scene import load_scene

        h = args.spacing
        ours = load_scene("spheric_test2", [f"spacing={h}"])
        tank = np.asarray(ours.tank.upper, dtype=float)
        block_lo, block = np.asarray(ours.fluids[0].lower), np.asarray(ours.fluids[0].upper)
        box = ours.obstacles[0]
        b_lo, b_hi = np.asarray(box.lower) + 0.6 * h, np.asarray(box.upper) - 0.6 * h
        obstacles = [{"translation": ((b_lo + b_hi) / 2).tolist(), "scale": (b_hi - b_lo).tolist()}]
        sensors = ours.probes
    else:
        h = args.spacing
        tank, block = np.array([4.0, 3.0, 1.5]), np.full(3, 32 * 0.03)
    folder = tempfile.mkdtemp(prefix="peer_db_")
    (Path(folder) / "box.obj").write_text(BOX)
    lo, hi = np.zeros(3) - 0.6 * h, tank + 0.6 * h
    conf = {
        "particleRadius": 0.5 * h,
        "simulationMethod": {"iisph": 3, "dfsph": 4}[args.method],
        "gravitation": [0, -G, 0],
        "timeStepSize": 0.001,
        "cflMethod": 1,
        "cflFactor": 0.5,
        "cflMaxTimeStepSize": 0.005,
        "boundaryHandlingMethod": 0,
        "stopAt": args.duration,
        "enableZSort": True,
        "maxIterations": 100,
        "minIterations": 2,
        "maxError": 0.1,
        "DFSPH": {"maxError": 0.1, "maxErrorV": 0.1, "enableDivergenceSolver": True},
    }
    wall = {"geometryFile": "box.obj", "isDynamic": False, "isWall": True, "mapInvert": True}
    scene = {
        "Configuration": conf,
        "Materials": [{"id": "Fluid", "density0": 1000, "viscosityMethod": 1, "viscosity": 0.01}],
        "RigidBodies": [{**wall, "translation": ((lo + hi) / 2).tolist(), "scale": (hi - lo).tolist()}]
        + [
            {"geometryFile": "box.obj", "isDynamic": False, "isWall": False, "mapInvert": False, **o} for o in obstacles
        ],
        "FluidBlocks": [{"denseMode": 0, "start": (block_lo - 0.5 * h).tolist(), "end": (block + 0.5 * h).tolist()}],
    }
    path = Path(folder) / "scene.json"
    path.write_text(json.dumps(scene))
    state = {
        "steps": 0,
        "iterations": [],
        "compression": [],
        "t0": None,
        "t1": None,
        "n": 0,
        "T": [],
        "Z": [],
        "escaped": 0,
        "probes": [],
        "next_probe": 0.0,
    }

    def on_step():
        sim = sph.Simulation.getCurrent()
        now = time.perf_counter()
        state["t0"] = state["t0"] or now
        state["steps"] += 1
        state["iterations"].append(sim.getTimeStep().getNumIterations())
        if args.scene == "martin_moyce":  # the front at every step, measured as ours (validation.py)
            fm = sim.getFluidModel(0)
            x = np.array([fm.getPosition(i) for i in range(fm.numActiveParticles())])
            state["T"].append(sph.TimeManager.getCurrent().getTime() * np.sqrt(2 * G / MM_WIDTH))
            state["Z"].append(surge_front(x, h) / MM_WIDTH)
            # particles beyond the tank mesh its boundary particles sit on: its walls leaked
            outside = np.any((x < lo) | (x > hi), axis=1)
            state["escaped"] = max(state["escaped"], int(outside.sum()))
        t_now = sph.TimeManager.getCurrent().getTime()
        if sensors is not None and t_now >= state["next_probe"] - 1e-9:  # every 5 ms, as ours are charted
            state["next_probe"] += PROBE_INTERVAL
            dt = sph.TimeManager.getCurrent().getTimeStepSize()  # the step's (set before its solve)
            state["probes"].append([t_now, *sensor_readings(sim, sensors, h, args.method, dt, ours)])
        if state["steps"] % 20 == 0:
            fm = sim.getFluidModel(0)
            n = fm.numActiveParticles()
            rho = np.array([fm.getDensity(i) for i in range(n)])
            state["compression"].append(float(np.mean(np.maximum(rho / fm.getDensity0() - 1.0, 0.0))))
            state["n"] = n
        state["t1"] = time.perf_counter()
        state["t0"] += state["t1"] - now  # the sampling is not the peer's time

    base = sph.Exec.SimulatorBase()
    base.init(useGui=False, sceneFile=str(path), outputDir=str(Path(folder) / "out"))
    base.setTimeStepCB(on_step)
    base.setValueFloat(base.STOP_AT, float(args.duration))
    base.run()
    wall = state["t1"] - state["t0"]
    print(
        json.dumps(
            {
                "tool": f"SPlisHSPlasH {sph.__version__ if hasattr(sph, '__version__') else '2.19'}",
                "method": args.method,
                "particles": state["n"],
                "steps": state["steps"],
                "wall_seconds": wall,
                "wall_seconds_per_simulated_second": wall / args.duration,
                "mean_iterations": float(np.mean(state["iterations"])),
                "mean_compression": float(np.mean(state["compression"])) if state["compression"] else None,
                "threads": int(os.environ.get("OMP_NUM_THREADS", "0") or 0),
                "spacing": h,
                **(
                    {"nx": args.nx, "T": state["T"], "Z": state["Z"], "escaped": state["escaped"]}
                    if args.scene == "martin_moyce"
                    else {}
                ),
                **(
                    {
                        "probes": {
                            "names": [p.name for p in sensors if p.kind != "force"],
                            "rows": state["probes"],
                            "interval": PROBE_INTERVAL,
                        }
                    }
                    if sensors is not None
                    else {}
                ),
            }
        )
    )


if __name__ == "__main__":
    main()
