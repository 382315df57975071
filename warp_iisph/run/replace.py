"""Putting a new folder where the user asked for it without losing what is there: a run folder
(``run --out``), or a run's meshes (``mesh --overwrite``).

The new folder is written beside its target as ``.NAME.new-PID`` (holding ``.warp-iisph.staging``,
which names the target) and moved into place once it is whole enough to stand (a run: its first
frame). A target that exists is replaced only if it is a run of warp-iisph (its ``run.json`` says
so) that holds none of the run's inputs, no other run and not the current directory; symbolic
links on the way are resolved. The swap is two renames, after a marker beside them,
``.NAME.swap-PID``, records them; Ctrl-C and SIGTERM wait until the swap (and the old folder's
removal) is done. A later start, or a resume, finds markers and staging folders whose process
is gone and finishes or rolls back what they record: the old folder stays unless the new one
took its place.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from ..engine import signals
from .atomic import write_json
from .folder import RECORD, RunError, RunFolder, run_around
from .lock import LOCK_NAME, FolderBusy, FolderLock, holder

STAGED = ".warp-iisph.staging"  # inside a staging folder: the name of the folder it is to become
MAX_NAME_BYTES = 200  # a target's name, with room for .NAME.swap-PID within 255 bytes


class OutputExistsError(RunError):
    """A target that may not be written or replaced; the message says why (nothing was changed)."""


def _pid_of(name: str, prefix: str) -> int | None:
    tail = name[len(prefix) :]
    return int(tail) if name.startswith(prefix) and tail.isdigit() else None


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process: alive
        return True
    return True


def _siblings(path: Path, kind: str) -> list[tuple[Path, int]]:
    """``.NAME.KIND-PID`` entries beside ``path``, with their PIDs."""
    prefix = f".{path.name}.{kind}-"
    try:
        entries = list(path.parent.iterdir())
    except OSError:
        return []
    found = [(p, _pid_of(p.name, prefix)) for p in entries]
    return [(p, pid) for p, pid in found if pid is not None]


def _staged_for(folder: Path, path: Path) -> bool:
    """Whether ``folder`` is a staging folder of ``path`` (its marker names it)."""
    try:
        return (folder / STAGED).read_text().strip() == path.name
    except (OSError, UnicodeDecodeError):
        return False


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def recover(path) -> None:
    """Finish or roll back what a process that is gone left beside ``path``: swaps it began
    (a new folder that never got in place goes and the old one stays; an old one that was
    replaced goes) and staging folders. A process alive, or a folder it still locks, is left be."""
    path = Path(path)
    if not path.parent.is_dir():
        return
    with signals.held():
        for marker, pid in _siblings(path, "swap"):
            if _alive(pid):
                continue
            try:
                info = json.loads(marker.read_text())
                old, new = path.parent / info["old"], path.parent / info["new"]
            except (OSError, ValueError, TypeError, KeyError):
                continue
            if old.parent != path.parent or new.parent != path.parent:
                continue
            if new.is_dir() and _staged_for(new, path):  # the second rename never happened
                if not path.exists() and old.is_dir():
                    os.rename(old, path)
                shutil.rmtree(new, ignore_errors=True)
            elif old.is_dir() and path.exists():  # both renames happened: the old folder goes
                shutil.rmtree(old, ignore_errors=True)
            elif old.is_dir():
                os.rename(old, path)
            (path / STAGED).unlink(missing_ok=True)
            marker.unlink(missing_ok=True)
        for staging, pid in _siblings(path, "new"):
            if not _alive(pid) and _staged_for(staging, path) and holder(staging) is None:
                shutil.rmtree(staging, ignore_errors=True)
        if not path.exists():  # an old run hidden by a swap that was never finished or undone
            hidden = [p for p, pid in _siblings(path, "old") if not _alive(pid) and RunFolder(p).is_run()]
            if len(hidden) == 1:
                os.rename(hidden[0], path)
        if (path / LOCK_NAME).is_file() and holder(path) is None:  # left by a process that was killed
            (path / LOCK_NAME).unlink(missing_ok=True)


def resolved(out, what: str = "--out") -> Path:
    """``out`` absolute, with every symbolic link on the way resolved (a link to nothing refused)."""
    out = Path(out)
    if out.is_symlink() and not out.exists():
        raise OutputExistsError(f"{what} {out}: a symbolic link to nothing ({os.readlink(out)})")
    path = Path(os.path.realpath(out))
    if path.parent == path or not path.name or path.name in (".", ".."):
        raise OutputExistsError(f"{what} {out}: is the root of the file system")
    if len(path.name.encode("utf-8", "surrogateescape")) > MAX_NAME_BYTES:
        raise OutputExistsError(f"{what} {out}: its name is longer than {MAX_NAME_BYTES} bytes")
    return path


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_replaceable(path: Path, given, inputs=(), what: str = "--out") -> None:
    """``OutputExistsError`` unless the folder ``path`` may be replaced by a new run: a run of
    warp-iisph, none of whose files is one of ``inputs`` (the scene file, its meshes), holding
    no other run and not the current directory."""
    try:
        cwd = Path(os.path.realpath(Path.cwd()))
    except OSError:
        cwd = None
    if cwd is not None and _inside(cwd, path):
        raise OutputExistsError(f"{what} {given}: holds the current directory; --overwrite will not replace it")
    if not RunFolder(path).is_run():
        raise OutputExistsError(
            f"{what} {given}: holds files but is not a run of warp-iisph (no {RECORD} of one); "
            "--overwrite replaces only a run folder: choose another folder, or empty it yourself"
        )
    for p in inputs:
        if _inside(Path(os.path.realpath(p)), path):
            raise OutputExistsError(f"{what} {given}: holds {p}, an input of this run; --overwrite would delete it")
    for folder, _, files in os.walk(path):
        if RECORD in files and Path(folder) != path and RunFolder(folder).is_run():
            raise OutputExistsError(f"{what} {given}: holds another run, {folder}; --overwrite will not delete it")


class Target:
    """Where a new folder goes (``path``, links resolved; ``given`` as the user wrote it), whether
    a folder there is to be replaced, and the lock held on that folder."""

    def __init__(self, path: Path, given, replacing: bool, lock: FolderLock | None):
        self.path, self.given, self.replacing, self.lock = path, given, replacing, lock
        self.created: list[Path] = []

    def release(self) -> None:
        if self.lock is not None:
            self.lock.release()


def _check_no_staging(path: Path, given, what: str) -> None:
    """``FolderBusy`` while another process stages a new folder for ``path`` (it holds its lock)."""
    for staging, pid in _siblings(path, "new"):
        who = holder(staging) if pid != os.getpid() else None
        if who is not None:
            raise FolderBusy(f"{what} {given}: {who} is writing a new run there; wait until it ends")


def prepare(out, overwrite: bool, inputs=(), what: str = "--out") -> Target:
    """Check where a new run goes before anything is built (``OutputExistsError``, ``FolderBusy``;
    leftovers of processes that are gone are recovered first); a folder there is locked."""
    given = out
    path = resolved(out, what)
    inside = run_around(path)
    if inside is not None:
        raise OutputExistsError(f"{what} {given}: inside the run folder {inside}; put the new run elsewhere")
    recover(path)
    if path.exists() and not path.is_dir():
        raise OutputExistsError(f"{what} {given}: is a file, not a folder")
    ancestor = path.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputExistsError(f"{what} {given}: {ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise OutputExistsError(f"{what} {given}: cannot write in {ancestor} (permission denied)")
    _check_no_staging(path, given, what)
    if not path.is_dir():
        return Target(path, given, False, None)
    lock = FolderLock(path).acquire()
    try:
        if any(p.name != LOCK_NAME for p in path.iterdir()):
            if not overwrite:
                raise OutputExistsError(
                    f"{what} {given}: folder exists and is not empty; pass --overwrite to replace it"
                )
            check_replaceable(path, given, inputs, what)
    except BaseException:
        lock.release()
        raise
    return Target(path, given, True, lock)


def stage(target: Target, what: str = "--out") -> tuple[Path, FolderLock]:
    """The staging folder beside the target, created and locked (the target checked once more:
    another process may have written there while this one was building)."""
    path = target.path
    _check_no_staging(path, target.given, what)
    if not target.replacing and path.exists():
        lock = FolderLock(path).acquire()
        if any(p.name != LOCK_NAME for p in path.iterdir()):
            lock.release()
            raise OutputExistsError(f"{what} {target.given}: another process wrote there while this run was built")
        target.replacing, target.lock = True, lock
    new = path.parent / f".{path.name}.new-{os.getpid()}"
    if new.exists() and _staged_for(new, path):  # this process's own, from a start that failed
        shutil.rmtree(new)
    made = [p for p in (path.parent, *path.parent.parents) if not p.exists()]
    path.parent.mkdir(parents=True, exist_ok=True)
    target.created = made  # folders above the target that a start which fails removes again
    new.mkdir()
    lock = FolderLock(new)
    try:
        lock.acquire()
        (new / STAGED).write_text(path.name + "\n")
    except BaseException:
        lock.release()
        shutil.rmtree(new, ignore_errors=True)
        raise
    return new, lock


def discard(new: Path, lock: FolderLock, target: Target | None = None) -> None:
    """Remove a staging folder that never got in place (and the folders above the target that
    were made for it, if they are empty)."""
    lock.release()
    shutil.rmtree(new, ignore_errors=True)
    if target is not None and not target.path.exists():
        for folder in target.created:  # nearest first
            try:
                folder.rmdir()
            except OSError:
                break


def commit(target: Target, new: Path, lock: FolderLock) -> Path:
    """Move the staging folder ``new`` into the target's place (the old folder, if any, removed):
    a marker first, then two renames and the removal, with Ctrl-C and SIGTERM held until done.
    Returns the place; the target's lock is then the new folder's."""
    path = target.path
    pid = os.getpid()
    with signals.held():
        if not target.replacing:
            try:
                os.rename(new, path)
            except OSError as e:
                raise OutputExistsError(
                    f"--out {target.given}: another process wrote there while this run started ({e.strerror})"
                ) from None
        else:
            old = path.parent / f".{path.name}.old-{pid}"
            marker = path.parent / f".{path.name}.swap-{pid}"
            write_json(marker, {"target": path.name, "old": old.name, "new": new.name, "pid": pid})
            _fsync_dir(path.parent)
            try:
                os.rename(path, old)
            except BaseException:  # the old folder went away, or cannot move: nothing was swapped
                marker.unlink(missing_ok=True)
                raise
            try:
                os.rename(new, path)
            except BaseException:
                os.rename(old, path)
                marker.unlink(missing_ok=True)
                raise
            if target.lock is not None:
                target.lock.moved(old)
        lock.moved(path)
        (path / STAGED).unlink(missing_ok=True)
        _fsync_dir(path.parent)
        if target.replacing:
            target.release()
            shutil.rmtree(old, ignore_errors=True)
            if not old.exists():  # else the marker stays, and a later start finishes the removal
                marker.unlink(missing_ok=True)
    target.lock, target.replacing = lock, False
    return path
