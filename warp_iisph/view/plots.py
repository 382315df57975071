"""Charts of a run's probes (``warp-iisph plot RUN_DIR``): every probe over time, from
``probes.csv``, one panel per quantity (pressure, level, force, moment), in a PNG."""

from __future__ import annotations

from pathlib import Path

from ..run.atomic import atomic_write
from ..run.folder import PROBES_CHART, RunError, RunFolder
from ..run.lock import writing_into
from ..run.probe_file import read_probes
from .out_file import view_file

# the panels, by unit: what each holds
PANELS = {"Pa": "pressure (kPa)", "m": "water level (m)", "N": "force (N)", "N m": "moment (N m)"}


def plot_probes(run_dir, out=None, dpi: int = 110) -> Path:
    """Draw every probe of the run in ``run_dir`` over time into ``out`` (default
    ``RUN_DIR/probes.png``); returns the path. Pressures in kPa; a force probe's components
    ``x``, ``y``, ``z``, pressure parts solid and viscous parts dashed."""
    run = RunFolder.existing(run_dir)
    out = view_file(run, out, PROBES_CHART, (".png",), "chart")
    if not run.probes.is_file():
        if not run.record_path.is_file():
            raise RunError(
                f"{run.path}: not a run folder (it holds no {run.record_path.name}); give the folder a run wrote"
            )
        scene = run.record().get("scene", {})
        if isinstance(scene, dict) and scene.get("probes"):  # the run had probes: their file is gone
            raise RunError(f"{run.probes}: missing (or not a file), though the run's scene has probes")
        raise RunError(f"{run.probes}: no probe samples (the scene has no [[probes]], or no step was taken)")
    names, units, rows = read_probes(run.probes)
    if len(rows) == 0:
        raise RunError(f"{run.probes}: holds no sample yet")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [u for u in PANELS if u in units]
    if not panels:
        raise RunError(f"{run.probes}: no column in a probe's unit ({', '.join(PANELS)}); not a probes.csv a run wrote")
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 2.8 * len(panels)), sharex=True, squeeze=False)
    t = rows[:, 0]
    for ax, unit in zip(axes[:, 0], panels):
        for k, (name, u) in enumerate(zip(names, units)):
            if u != unit:
                continue
            y = rows[:, 1 + k] / (1e3 if unit == "Pa" else 1.0)
            # a force probe's viscous parts, by the column's unit and its last part (NAME.Fv_x): a
            # probe's own name may hold anything
            viscous = unit in ("N", "N m") and name.rpartition(".")[2][:3] in ("Fv_", "Mv_")
            if viscous and not y.any():
                continue  # free-slip walls: no viscous load to draw
            ax.plot(t, y, "--" if viscous else "-", lw=0.9, label=name)
        ax.set_ylabel(PANELS[unit])
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1, 0].set_xlabel("t (s)")
    rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else 0.0
    axes[0, 0].set_title(f"{run.path.name}: {len(t)} samples, {rate:.0f} per second")
    fig.tight_layout()
    try:
        with writing_into(run.path, out):  # one writer in the run folder (a chart put elsewhere reads it as it is)
            atomic_write(out, lambda tmp: fig.savefig(tmp, dpi=dpi, format="png"))
    except OSError as e:
        # a failure at run time (exit 1), not bad input
        raise OSError(e.errno, f"--out {out}: cannot write: {e.strerror or e}") from None
    finally:
        plt.close(fig)
    return out
