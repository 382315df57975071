"""``probes.csv``: a run's probe samples, one row per sample, the time first and then one column per
probe (a force probe has twelve), each headed ``name [unit]``. Rows are appended as the samples
come and flushed at every frame; a resumed run keeps the rows up to its checkpoint's time (as
``stats.jsonl`` keeps the steps up to it) and appends to them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .formats import FileFormatError

# a kept row's time may exceed the checkpoint's by this much (s): what the 12 digits written round
KEEP_SLACK = 1.0e-9


def header(names: list[str], units: list[str]) -> str:
    return ",".join(["t [s]"] + [f"{n} [{u}]" for n, u in zip(names, units)])


def _row(values) -> str:
    return ",".join(f"{float(v):.12g}" for v in values)


class ProbeWriter:
    """Appends sample rows (time first) to ``probes.csv``; with ``keep_until`` (a resumed run's
    time) the rows an older run wrote up to that time are kept (the file replaced atomically),
    the rest dropped."""

    def __init__(self, path, names: list[str], units: list[str], keep_until: float | None = None):
        self.path = Path(path)
        head = header(names, units)
        kept = []
        if keep_until is not None and self.path.is_file():
            lines = self.path.read_text().splitlines()
            if lines and lines[0] == head:
                for line in lines[1:]:
                    try:
                        t = float(line.split(",", 1)[0])
                    except ValueError:  # cut off mid-write
                        break
                    if line.count(",") != head.count(",") or t > keep_until + KEEP_SLACK:
                        break
                    kept.append(line)
        text = "\n".join([head, *kept]) + "\n"
        atomic_write(self.path, lambda tmp: Path(tmp).write_text(text))
        self._f = open(self.path, "a")

    def write(self, rows: np.ndarray) -> None:
        self._f.write("".join(_row(r) + "\n" for r in rows))

    def flush(self) -> None:
        self._f.flush()

    def close(self) -> None:
        self._f.close()


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
    path = Path(path)
    lines = path.read_text().splitlines()
    if not lines or not lines[0].startswith("t [s]"):
        raise FileFormatError(f"{path}: not a probes.csv (its first line must start with 't [s]')")
    names, units = [], []
    for cell in lines[0].split(",")[1:]:
        name, _, unit = cell.rpartition(" [")
        names.append(name)
        units.append(unit.rstrip("]"))
    width = len(names) + 1
    rows = []
    for k, line in enumerate(lines[1:], 2):
        cells = line.split(",")
        try:
            if len(cells) != width:
                raise ValueError
            rows.append([float(c) for c in cells])
        except ValueError:
            if k == len(lines):
                break
            raise FileFormatError(f"{path}, line {k}: not a row of {width} numbers") from None
    return names, units, np.asarray(rows, dtype=np.float64).reshape(-1, width)
