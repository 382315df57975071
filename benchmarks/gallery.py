"""The README's scene gallery: every bundled scene run at its default resolution, and a still of one
of its frames made by `warp-iisph preview`, into docs/gallery/NAME.png. Writes
docs/gallery/gallery.json with each run's particles, steps, wall time and how it ended (a scene
not run keeps its saved row; each row has the date of its run).

    python benchmarks/gallery.py [--scenes dam_break,wake] [--device cpu] [--graph] [--quick]

(on a GPU: --device cuda --graph --out somewhere else, to check every scene's run there)
"""

import argparse
import json
import tempfile
from pathlib import Path

import warp as wp
from common import header

from warp_iisph.cli import main as cli
from warp_iisph.scene import bundled_scenes, load_scene

GALLERY = Path(__file__).resolve().parents[1] / "docs" / "gallery"
# the moment each still shows, as a fraction of the scene's duration
MOMENT = {
    "dam_break": 0.35,
    "drop_splash": 0.3,
    "fluid_flow": 0.6,
    "martin_moyce": 0.4,
    "dam_break_cube": 0.5,
    "wake": 0.6,
}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default=",".join(bundled_scenes()), help="comma-separated bundled scene names")
    ap.add_argument(
        "--quick", action="store_true", help="a tenth of each scene's duration, coarser, into a temporary folder"
    )
    ap.add_argument("--out", default=str(GALLERY))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--graph", action="store_true", help="replay graph-captured steps")
    args = ap.parse_args()
    wp.config.log_level = wp.LOG_WARNING
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, today = [], header("gallery")["date"]
    for name in args.scenes.split(","):
        scene = load_scene(name)
        duration = scene.output.duration * (0.1 if args.quick else 1.0)
        with tempfile.TemporaryDirectory() as tmp:
            run = Path(tmp) / name
            extra = ["--set", f"spacing={2 * scene.spacing}"] if args.quick else []
            extra += ["--device", args.device] + (["--graph"] if args.graph else [])
            code = cli(["run", name, "--out", str(run), "--duration", f"{duration:g}", "--no-progress", *extra])
            record = json.loads((run / "run.json").read_text())
            frame = max(0, min(record["totals"]["frames"] - 1, round(MOMENT.get(name, 0.5) * duration * record["fps"])))
            still = out / f"{name}.png"
            cli(
                [
                    "preview",
                    str(run),
                    "--frames",
                    f"{frame}:{frame + 1}",
                    "--out",
                    str(still),
                    "--resolution",
                    "480x270",
                    "--no-progress",
                ]
            )
        t = record["totals"]
        rows.append(
            {
                "scene": name,
                "exit": code,
                "ended": record["ended"],
                "particles": t["particles"],  # at the end (emitters add)
                "simulated_seconds": t["simulated_time"],
                "steps": t["steps"],
                "wall_seconds": t["wall_seconds"],
                "mean_compression": t["mean_compression"],
                "wall_corrections": t.get("wall_corrections"),
                "obstacle_corrections": t.get("obstacle_corrections"),
                "still": still.name,
                "frame": frame,
                "device": args.device,
                "graph": args.graph,
                "date": today,
            }
        )
        print(
            f"{name:16s} {rows[-1]['particles']:>6} particles, "
            f"{t['simulated_time']:.2f} s simulated in {t['wall_seconds']:.0f} s "
            f"({record['ended']}) -> {still}"
        )
    saved = out / "gallery.json"
    if saved.exists() and not args.quick:  # the scenes not run this time keep their saved rows
        ran = {r["scene"] for r in rows}
        old = json.loads(saved.read_text())
        rows = [{"date": old["date"], **r} for r in old["runs"] if r["scene"] not in ran] + rows
        rows.sort(key=lambda r: r["scene"])
    saved.write_text(json.dumps(header("gallery", runs=rows, quick=args.quick), indent=2) + "\n")


if __name__ == "__main__":
    main()
