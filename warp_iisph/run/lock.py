"""One writer per folder: an OS file lock (``fcntl.flock``) held while a command writes there.

``FOLDER/.warp-iisph.lock`` says who holds it (PID and command line), so that a refusal names the
holder. run, resume, mesh, preview, render, plot, usd and blender-script take it before they write into
a run folder and keep it until they end (the OS drops it with the process, however it ends). The
holder removes the file while it still holds the lock, and a taker checks that the file it locked
is still the one at that path, so two processes never both hold a folder.
"""

from __future__ import annotations

import errno
import os
import sys
from contextlib import ExitStack, nullcontext
from pathlib import Path

from .folder import RunError, enclosing_run

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no lock
    fcntl = None

LOCK_NAME = ".warp-iisph.lock"
UNLOCKABLE = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}


class FolderBusy(RunError):
    """Another process holds the folder's lock; the message names it."""


def _describe(text: str) -> str:
    return " ".join(text.split())[:300] or "another process (starting)"


class FolderLock:
    """The lock of one folder: ``acquire`` (``FolderBusy`` naming the holder when another
    process has it), ``release``; a context manager that takes and releases it."""

    def __init__(self, folder, what: str = "run folder", hint: str = ""):
        self.folder = Path(folder)
        self.what = what
        self.hint = hint  # what else the refused command may do, said after the refusal
        self._fd: int | None = None

    @property
    def path(self) -> Path:
        return self.folder / LOCK_NAME

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> "FolderLock":
        if self._fd is not None or fcntl is None:
            return self
        from .atomic import FILE_MODE

        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, FILE_MODE)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                if e.errno in UNLOCKABLE:  # a file system without locks (some network mounts): none taken
                    os.close(fd)
                    return self
                if not isinstance(e, BlockingIOError):
                    os.close(fd)
                    raise
                holder = _describe(os.pread(fd, 4096, 0).decode(errors="replace"))
                os.close(fd)
                raise FolderBusy(
                    f"{self.folder}: in use by {holder}; wait until it ends (one writer per {self.what})"
                    + (f", {self.hint}" if self.hint else "")
                ) from None
            except BaseException:
                os.close(fd)
                raise
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:  # its holder removed it as it let go: take the new one
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"PID {os.getpid()} ({' '.join(sys.argv) or sys.executable})\n".encode(), 0)
        self._fd = fd
        return self

    def moved(self, folder) -> None:
        """The folder was renamed to ``folder`` (its lock file went with it, still held)."""
        self.folder = Path(folder)

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            if os.stat(self.path).st_ino == os.fstat(fd).st_ino:
                os.unlink(self.path)  # while still held: a waiting taker then finds it gone and retries
        except OSError:
            pass
        finally:
            os.close(fd)

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def holder(folder) -> str | None:
    """Who holds ``folder``'s lock now, or ``None`` when nobody does (the disk is not changed)."""
    if fcntl is None:
        return None
    try:
        fd = os.open(Path(folder) / LOCK_NAME, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return _describe(os.pread(fd, 4096, 0).decode(errors="replace"))
    finally:
        os.close(fd)
    return None


def check_free(folder, what: str = "run folder") -> None:
    """``FolderBusy`` when another process holds ``folder``'s lock (nothing is written)."""
    who = holder(folder)
    if who is not None:
        raise FolderBusy(f"{folder}: in use by {who}; wait until it ends (one writer per {what})")


def writing_into(folder, *outputs):
    """The locks a command that reads run ``folder`` and writes ``outputs`` takes, as a context
    manager: the lock of every run folder that an output lies in (``folder`` itself, or another
    run's: :func:`~.folder.enclosing_run`); none when all go elsewhere (a view of a run that is
    still being written, put beside it, reads it without taking its lock)."""
    root = Path(os.path.realpath(folder))
    runs = []
    for out in outputs:
        target = Path(os.path.realpath(out))
        inside = root if (target == root or root in target.parents) else enclosing_run(target)
        if inside is not None and inside not in runs:
            runs.append(inside)
    if not runs:
        return nullcontext()
    stack = ExitStack()
    try:
        for run in runs:
            stack.enter_context(FolderLock(run, hint="or write to a file outside it with --out"))
    except BaseException:
        stack.close()
        raise
    return stack
