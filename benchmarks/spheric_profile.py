"""Where SPHERIC Test 2's face pressure gets its slope: the bundled scene's box face sensors
(P1-P4) read high low on the face and low high on it (docs/physics.md 6.5). This runs the scene
with extra pressure probes at the sensors' heights 0.05, 0.1, 0.2 and 0.4 m upstream of the face,
a level gauge above each (and one 1 cm in front of the face), and samples the horizontal velocity
of the stream 0.2 m upstream on the centre line; every reading is averaged over the experiment's
plateau window (0.6-1.2 s). Beside each pressure: the hydrostatic pressure under the local level,
rho0 g (eta - y), and the experiment's plateau and levels.

Writes benchmarks/results/spheric_profile.json and spheric_profile.png.

    python benchmarks/spheric_profile.py [--spacings 0.05,0.025] [--quick]
"""

import argparse

import numpy as np
from common import RESULTS, header, pyplot, save

from warp_iisph import Simulation
from warp_iisph.analysis.spheric import PLATEAU, load_marin
from warp_iisph.scene import load_scene
from warp_iisph.scene.probes import Probe

FACE, CENTRE = 0.8245, 0.5  # the box's face towards the water (x), the tank's centre line (z)
HEIGHTS = (0.021, 0.061, 0.101, 0.141)  # P1-P4
OFFSETS = (0.0, 0.05, 0.10, 0.20, 0.40)  # upstream of the face (m); 0: the scene's own P1-P4
STREAM = 0.2  # where the stream's velocity profile is sampled, upstream of the face (m)
RHO, G = 1000.0, 9.81


def _tag(d: float) -> str:
    return f"{round(d * 100):02d}"


def profile(spacing: float, window: tuple) -> dict:
    scene = load_scene("spheric_test2", [f"spacing={spacing!r}", "output.probe_interval=0.005"])
    for d in OFFSETS:
        if d > 0:
            for k, y in enumerate(HEIGHTS):
                scene.add_probe(Probe(name=f"p{k + 1}_{_tag(d)}", kind="pressure", position=(FACE + d, y, CENTRE),
                                      normal=(1.0, 0.0, 0.0)))  # fmt: skip
        # a gauge needs liquid under it: the one at the face stands 1 cm in front of it
        scene.add_probe(Probe(name=f"eta_{_tag(d)}", kind="level", position=(FACE + max(d, 0.01), CENTRE)))
    sim = Simulation(scene, device="cpu")
    sim.advance(window[0])
    heights, speeds = [], []
    while sim.time < window[1] - 1e-9:
        sim.advance(min(0.02, window[1] - sim.time))
        x, v = sim.positions, sim.velocities
        sel = (np.abs(x[:, 0] - (FACE + STREAM)) < spacing) & (np.abs(x[:, 2] - CENTRE) < 0.1)
        heights.append(x[sel, 1])
        speeds.append(v[sel, 0])
    t = sim.probes.time
    w = (t >= window[0]) & (t <= window[1])
    rows = []
    for d in OFFSETS:
        names = [f"P{k + 1}" for k in range(4)] if d == 0 else [f"p{k + 1}_{_tag(d)}" for k in range(4)]
        eta = float(sim.probes[f"eta_{_tag(d)}"][w].mean())
        rows.append(
            {
                "upstream": d,
                "level": eta,
                "pressure": [float(sim.probes[n][w].mean()) for n in names],
                "hydrostatic": [RHO * G * max(eta - y, 0.0) for y in HEIGHTS],
            }
        )
    y, u = np.concatenate(heights), np.concatenate(speeds)
    bins = np.arange(0.0, 0.4, spacing)
    stream = [
        {"y": float(b + 0.5 * spacing), "u": float(u[(y >= b) & (y < b + spacing)].mean())}
        for b in bins
        if np.any((y >= b) & (y < b + spacing))
    ]
    return {"spacing": spacing, "particles": sim.n_particles, "rows": rows, "stream": stream}


def experiment(window: tuple) -> dict:
    ref = load_marin()
    w = (ref["t"] >= window[0]) & (ref["t"] <= window[1])
    return {
        "pressure": [float(ref[f"P{k + 1}"][w].mean()) for k in range(4)],
        "level_x0.992": float(ref["H_x0.992"][w].mean()),  # 0.1675 m upstream of the face
        "level_x1.488": float(ref["H_x1.488"][w].mean()),  # 0.6635 m upstream
    }


def chart(record: dict, path) -> None:
    plt = pyplot()
    runs = record["runs"]
    fig, axes = plt.subplots(1, len(runs), figsize=(5.5 * len(runs), 4.6), squeeze=False, sharey=True)
    for ax, run in zip(axes[0], runs):
        for row, colour in zip(run["rows"], plt.cm.viridis(np.linspace(0.0, 0.85, len(run["rows"])))):
            label = "at the face (P1-P4)" if row["upstream"] == 0 else f"{row['upstream']:.2f} m upstream"
            ax.plot(
                np.array(row["pressure"]) / 1e3,
                HEIGHTS,
                "o-",
                color=colour,
                label=f"{label}, level {row['level']:.3f} m",
            )
            ax.plot(np.array(row["hydrostatic"]) / 1e3, HEIGHTS, ":", color=colour)
        ax.plot(np.array(record["experiment"]["pressure"]) / 1e3, HEIGHTS, "ks--", label="experiment, at the face")
        ax.set_title(f"h = {run['spacing']:g} m ({run['particles']:,} particles)")
        ax.set_xlabel("mean pressure over 0.6-1.2 s (kPa); dotted: rho0 g (level - y)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0, 0].set_ylabel("height on the face's plane (m)")
    fig.suptitle("SPHERIC Test 2: the face pressure's profile and the stream's, approaching the box")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spacings", default="0.05,0.025")
    ap.add_argument("--quick", action="store_true", help="5 cm over 0.6-0.7 s")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args()
    spacings = [0.05] if args.quick else [float(s) for s in args.spacings.split(",")]
    window = (PLATEAU[0], PLATEAU[0] + 0.1) if args.quick else PLATEAU
    record = header("spheric_profile", window=list(window), heights=list(HEIGHTS), experiment=experiment(window))
    record["runs"] = []
    for h in spacings:
        run = profile(h, window)
        record["runs"].append(run)
        print(f"h = {h:g} m ({run['particles']} particles), means over {window[0]}-{window[1]} s:")
        for row in run["rows"]:
            p = " ".join(f"{v / 1e3:5.2f}" for v in row["pressure"])
            hyd = " ".join(f"{v / 1e3:5.2f}" for v in row["hydrostatic"])
            print(
                f"  {row['upstream']:.2f} m upstream: level {row['level']:.3f} m, p {p} kPa | rho0 g (level - y) {hyd}"
            )
        print(
            "  stream 0.2 m upstream, u_x by height: " + " ".join(f"{s['y']:.3f}:{s['u']:+.2f}" for s in run["stream"])
        )
    e = record["experiment"]
    print(
        "experiment: P1-P4 " + " ".join(f"{v / 1e3:.2f}" for v in e["pressure"])
        + f" kPa; level {e['level_x0.992']:.3f} m at 0.1675 m upstream, {e['level_x1.488']:.3f} m at 0.6635 m"
    )  # fmt: skip
    path = save(record, args.out, "spheric_profile", args.quick)
    chart(record, path)
    print(f"-> {path}")


if __name__ == "__main__":
    main()
