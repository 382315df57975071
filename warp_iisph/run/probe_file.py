"""``probes.csv``: a run's probe samples, one row per sample, the time first and then one column per
probe (a force probe has twelve), each headed ``name [unit]``. Rows are appended as the samples
come and written to the disk at every frame (before its checkpoint); a resumed run keeps the rows
up to its checkpoint's time (as ``stats.jsonl`` keeps the steps up to it) and appends to them.
"""

from __future__ import annotations

import numpy as np

from .time_series import TimeSeriesWriter, read_time_series


def header(names: list[str], units: list[str]) -> str:
    return ",".join(["t [s]"] + [f"{n} [{u}]" for n, u in zip(names, units)])


class ProbeWriter(TimeSeriesWriter):
    """Appends sample rows (time first) to ``probes.csv`` (see :class:`.time_series.TimeSeriesWriter`)."""

    def __init__(self, path, names: list[str], units: list[str], keep_until: float | None = None):
        super().__init__(path, header(names, units), keep_until)

    def write(self, rows: np.ndarray) -> None:
        self.write_rows(rows)


def open_probe_file(path, sim, keep_until: float | None = None) -> ProbeWriter | None:
    """The writer of ``sim``'s probe samples to ``path``, fed as they arrive; ``None`` for a scene
    without probes."""
    if not sim.probes:
        return None
    writer = ProbeWriter(path, sim.probes.names, sim.probes.units, keep_until)
    sim.probes.listen(writer.write)
    return writer


def read_probes(path) -> tuple[list[str], list[str], np.ndarray]:
    """``probes.csv`` as (names, units, samples): samples an (n, 1 + columns) array, time first;
    an incomplete last row (a run cut off while writing it) is left out."""
    cells, rows = read_time_series(path, "probes.csv")
    names, units = [], []
    for cell in cells:
        name, _, unit = cell.rpartition(" [")
        names.append(name)
        units.append(unit.rstrip("]"))
    return names, units, rows
