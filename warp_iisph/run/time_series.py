"""A run's CSV time series (``probes.csv``, ``bodies.csv``): a header ``t [s],...``, then one row of
numbers per sample, the time first, 12 significant digits. Rows are appended as they come; a
resumed run keeps the rows up to its checkpoint's time (as ``stats.jsonl`` keeps the steps up to
it) and appends to them; a row cut off mid-write (a killed run) ends the file when it is read."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import atomic_write, flush_to_disk
from .formats import FileFormatError

# a kept row's time may exceed the checkpoint's by this much (s), or by this fraction of it: what
# the 12 digits written round
KEEP_SLACK = 1.0e-9
KEEP_SLACK_RELATIVE = 1.0e-11


def row(values) -> str:
    return ",".join(f"{float(v):.12g}" for v in values)


def rows_until(path, until: float) -> tuple[str, list[str]]:
    """A time series file's header line and its rows up to time ``until`` (s), as a resumed run
    keeps them: from the first on, each of the header's width, up to the first that is cut off,
    of another width or later than ``until``. ``OSError``/``UnicodeDecodeError`` when it cannot
    be read; ``("", [])`` for an empty file."""
    lines = Path(path).read_text().splitlines()
    if not lines:
        return "", []
    head, kept = lines[0], []
    limit = until + max(KEEP_SLACK, KEEP_SLACK_RELATIVE * abs(until))
    for line in lines[1:]:
        try:
            t = float(line.split(",", 1)[0])
        except ValueError:  # cut off mid-write
            break
        if line.count(",") != head.count(",") or not t <= limit:
            break
        kept.append(line)
    return head, kept


class TimeSeriesWriter:
    """Appends rows under ``head`` to ``path``; with ``keep_until`` (a resumed run's time) the rows
    an older run wrote up to that time under the same header are kept (the file replaced
    atomically), the rest dropped. :attr:`rows` counts the rows the file holds."""

    def __init__(self, path, head: str, keep_until: float | None = None):
        self.path = Path(path)
        kept = []
        if keep_until is not None and self.path.is_file():
            old_head, rows = rows_until(self.path, keep_until)
            kept = rows if old_head == head else []
        text = "\n".join([head, *kept]) + "\n"
        atomic_write(self.path, lambda tmp: Path(tmp).write_text(text))
        self._f = open(self.path, "a")
        self.rows = len(kept)

    def write_rows(self, rows) -> None:
        self._f.write("".join(row(r) + "\n" for r in rows))
        self.rows += len(rows)

    def flush(self) -> None:
        flush_to_disk(self._f)

    def close(self) -> None:
        self._f.close()


def read_time_series(path, kind: str) -> tuple[list[str], np.ndarray]:
    """A time series file as (its header's cells after the time, rows): rows an (n, 1 + columns)
    array, time first; an incomplete last row is left out. ``kind`` names the file in errors."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError:
        raise FileFormatError(f"{path}: not a {kind} (not text)") from None
    if not lines or not lines[0].startswith("t [s]"):
        raise FileFormatError(f"{path}: not a {kind} (its first line must start with 't [s]')")
    cells = lines[0].split(",")[1:]
    width = len(cells) + 1
    rows = []
    for k, line in enumerate(lines[1:], 2):
        try:
            values = [float(v) for v in line.split(",")]
        except ValueError:
            values = []
        if len(values) != width:
            if k == len(lines):
                break
            raise FileFormatError(f"{path}, line {k}: not a row of {width} numbers")
        rows.append(values)
    return cells, np.asarray(rows, dtype=np.float64).reshape(-1, width)
