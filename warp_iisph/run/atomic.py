"""Files that appear whole or not at all: written beside their place, flushed to disk, renamed in."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from ..engine import signals


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# files are readable as any file the user creates (mkstemp alone would make them 0600)
FILE_MODE = 0o666 & ~_umask()


def flush_to_disk(f) -> None:
    """An appended log's lines on the disk, not only in the OS's cache: flushed and fsynced, so a
    checkpoint written after (fsynced too) never outlives them, even through a power cut."""
    f.flush()
    os.fsync(f.fileno())


def atomic_write(path: Path, write) -> None:
    """``write(tmp)`` to a temporary file beside ``path``, flushed to disk, then renamed into
    place: a file that exists is whole."""
    staged_write(path, write).commit()


class StagedFile:
    """A file written and flushed beside its place (:func:`staged_write`): ``commit`` renames it
    in, ``discard`` removes it."""

    def __init__(self, tmp: str, path: Path):
        self.tmp, self.path = tmp, path

    def commit(self) -> None:
        try:
            os.replace(self.tmp, self.path)
        except BaseException:
            self.discard()
            raise

    def discard(self) -> None:
        if os.path.exists(self.tmp):
            os.remove(self.tmp)


def staged_write(path: Path, write) -> StagedFile:
    """:func:`atomic_write` in two halves: the file written and flushed beside ``path`` now, put
    in place by the returned file's ``commit`` (so that it appears only after other files)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_beside(path, f".{path.name}.", ".tmp" + path.suffix)
    try:
        write(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return StagedFile(tmp, path)


def temporary_beside(path: Path, prefix: str, suffix: str) -> str:
    """The name of a new empty file ``prefix...suffix`` of its own in ``path``'s folder, readable as
    any file the user makes (mkstemp's are private). A Ctrl-C waits until it is made, named here
    and closed exactly once (one landing between them left the file behind, or closed it twice),
    and takes it with it."""
    name = None
    try:
        with signals.held():
            fd, name = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
            try:
                os.fchmod(fd, FILE_MODE)
            finally:
                os.close(fd)
    except BaseException:
        if name is not None and os.path.exists(name):
            os.remove(name)
        raise
    return name


def write_json(path, obj) -> None:
    path = Path(path)

    def write(tmp):
        with open(tmp, "w") as f:
            json.dump(obj, f, indent=2, default=jsonable)
            f.write("\n")

    atomic_write(path, write)


def jsonable(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
