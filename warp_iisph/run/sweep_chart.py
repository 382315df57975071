"""A sweep's measures and its chart: a number of each variant's run.json summary, named by a dotted
path or a bare name, drawn against the varied keys (matplotlib)."""

from __future__ import annotations

import math
import re
from pathlib import Path

SUMMARY = ("device", "particles", "duration", "totals")  # the parts of a variant's run.json that sweep.json copies
DEFAULT_MEASURE = "totals.wall_seconds_per_simulated_second"
DONE = ("completed", "diverged")  # a variant that ended so is a result: --resume leaves it
CHART_EXTRA = "pip install 'warp_iisph[cluster]'  (Dask distributed, matplotlib)"


# --- measures --------------------------------------------------------------------------------------


def _bare(value: str) -> str:
    """A value's text without the quotes of a TOML string."""
    if len(value) >= 2 and value[0] == value[-1] and value[0] in "\"'":
        return value[1:-1]
    return value


def check_measure(measure: str, summaries=None) -> str:
    """``measure`` when it is a dotted name and, given ``summaries`` (the variants' summaries, or
    those they will have: :func:`~warp_iisph.run.sweep.blank_summary`), a number in one of them by
    :func:`measure_value`, the chart's own look-up; ``ValueError`` naming ``--measure``, the key
    and the names there are otherwise."""
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z0-9_]+)*", measure or ""):
        raise ValueError(
            f"--measure {measure!r}: must name a value of a run's run.json, e.g. totals.mean_compression "
            f"or mean_iterations (looked up in {', '.join(SUMMARY)})"
        )
    summaries = list(summaries or ())
    if summaries and all(measure_value(s, measure) is None for s in summaries):
        raise ValueError(
            f"--measure {measure}: no such number in a variant's run.json; give one of "
            f"{', '.join(measure_names(summaries))} (by its dotted path, or its last name alone: "
            f"mean_iterations for totals.mean_iterations)"
        )
    return measure


def measure_value(summary: dict, measure: str) -> float | None:
    """The number ``measure`` names in a variant's summary: a dotted path (``totals.mean_iterations``),
    or a bare name looked up in each part (``mean_iterations``); ``None`` where there is none."""
    node = summary
    for part in measure.split("."):
        node = node.get(part) if isinstance(node, dict) else None
    if node is None and "." not in measure:
        node = next((s[measure] for s in summary.values() if isinstance(s, dict) and measure in s), None)
    if isinstance(node, bool) or not isinstance(node, (int, float)) or not math.isfinite(node):
        return None
    return float(node)


def numbers_in(summary: dict, prefix: str = "") -> list[str]:
    """Every dotted name with a number in ``summary`` (what ``--measure`` may name)."""
    names = []
    for key, value in summary.items():
        if isinstance(value, dict):
            names += numbers_in(value, f"{prefix}{key}.")
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            names.append(f"{prefix}{key}")
    return names


def measure_names(summaries) -> list[str]:
    """The names ``--measure`` may take in any of ``summaries``, the totals first (what a study
    measures), each once."""
    names = dict.fromkeys(n for s in summaries for n in numbers_in(s))
    return sorted(names, key=lambda n: not n.startswith("totals."))


def require_chart() -> None:
    """``RuntimeError`` saying what to install when matplotlib (the chart's) is missing."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise RuntimeError(f"the chart needs matplotlib (the cluster extra): {CHART_EXTRA}") from None


def _numeric(values: list[str]) -> list[float] | None:
    try:
        return [float(_bare(v)) for v in values]
    except ValueError:
        return None


def chart(record: dict, path: Path, measure: str | None = None) -> str | None:
    """Draw ``measure`` (default: the sweep's) of every variant that ran to a result against the
    first varied key, a line per setting of the others (the mean of repeats, each repeat a dot);
    diverged variants are hollow. Returns the chart's file name, ``None`` when no variant has
    the measure (nothing is drawn)."""
    measure = measure or record["measure"]
    keys = list(record["vary"])
    points = []  # (x key value, rest, value, diverged)
    for e in record["variants"]:
        if e["ended"] not in DONE:
            continue
        value = measure_value(e.get("summary") or {}, measure)
        if value is None:
            continue
        s = e["settings"]
        x = s[keys[0]] if keys else str(e["repeat"])
        # a line per setting of the other keys (named in the legend's title when there is one)
        rest = ", ".join(_bare(s[k]) if len(keys) == 2 else f"{k}={_bare(s[k])}" for k in keys[1:])
        points.append((x, rest, value, e["ended"] == "diverged"))
    if not points:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = record["vary"][keys[0]] if keys else [str(k) for k in range(1, record["repeat"] + 1)]
    numeric = _numeric(xs)
    where = dict(zip(xs, numeric if numeric is not None else range(len(xs))))
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for rest in dict.fromkeys(p[1] for p in points):
        mine = [p for p in points if p[1] == rest]
        line_x, line_y = [], []
        for x in xs:
            at = [p[2] for p in mine if p[0] == x]
            if at:
                line_x.append(where[x])
                line_y.append(sum(at) / len(at))
        (line,) = ax.plot(line_x, line_y, "-", label=rest or None)
        for x, _, value, diverged in mine:
            ax.plot(where[x], value, "o", ms=5, color=line.get_color(), mfc="none" if diverged else line.get_color())
    if numeric is None:
        ax.set_xticks(list(where.values()), [_bare(x) for x in xs], rotation=30 if len(xs) > 6 else 0)
    elif min(numeric) > 0 and max(numeric) / min(numeric) >= 20:
        ax.set_xscale("log")
    ax.set_xlabel(keys[0] if keys else "repeat")
    ax.set_ylabel(measure)
    diverged = sum(p[3] for p in points)
    hollow = f" ({diverged} diverged: hollow)" if diverged else ""
    ax.set_title(f"{Path(record['scene']).stem}: {len(points)} variants{hollow}")
    if any(p[1] for p in points):
        ax.legend(fontsize=8, title=", ".join(keys[1:]), title_fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name
