"""Ctrl-C and SIGTERM as exceptions in the main thread, from the command line's first instruction
on, and kept through what could lose them.

- :func:`install`: SIGINT raises ``KeyboardInterrupt``, SIGTERM :class:`Terminated`, and both are
  remembered (:func:`received`), so that a signal whose exception a library swallowed still
  ends the command with its status; installed ``armed=False`` (a program's first instruction,
  before its ``main`` can catch anything) they are only remembered until :func:`arm`.
- :func:`held`: a block both wait for (two renames that must not be parted); they are raised
  when it ends.
- :func:`deferred`: a third-party library loading (Mitsuba, usd-core): it may install handlers of
  its own or swallow the exception, so signals wait until it has loaded, the handlers it found are
  put back, and a signal that came meanwhile is raised then.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Terminated(KeyboardInterrupt):
    """The process was asked to stop (SIGTERM); raised in the main thread like Ctrl-C."""


_received: list[int] = []
_armed = [True]
_holding = [0]  # held() blocks entered and not left
_pending: list[int] = []  # signals that came while held


def _raise(signum):
    if signum == signal.SIGTERM:
        raise Terminated()
    raise KeyboardInterrupt()


def _handler(signum, frame):
    _received.append(signum)
    if not _armed[0]:
        return
    if _holding[0]:
        _pending.append(signum)
        return
    _raise(signum)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def install(armed: bool = True) -> None:
    """Our handlers, where Python's defaults are in place (a host that set its own keeps it);
    ``armed=False``: signals are remembered, not raised, until :func:`arm`."""
    if not _main_thread():
        return
    _armed[0] = armed
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _handler)
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _handler)


def arm() -> None:
    """From now on our handlers raise (a program's ``main`` is ready to catch)."""
    _armed[0] = True


def received() -> int | None:
    """The last signal our handlers saw (``None``: none)."""
    return _received[-1] if _received else None


def count() -> int:
    """How many signals our handlers have seen."""
    return len(_received)


def ignore() -> None:
    """Ignore Ctrl-C and SIGTERM from now on (a program that has done its work and exits)."""
    if _main_thread():
        for s in SIGNALS:
            signal.signal(s, signal.SIG_IGN)


@contextmanager
def held():
    """Ctrl-C and SIGTERM wait until the block has run, then are raised as usual: our handlers
    keep them (another thread may be the one the signal reaches), and the main thread blocks
    them (for a library's handlers, while it loads)."""
    if not _main_thread():
        yield
        return
    _holding[0] += 1
    before = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS) if hasattr(signal, "pthread_sigmask") else None
    try:
        yield
    finally:
        if before is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, before)
        _holding[0] -= 1
        if not _holding[0] and _pending:
            signum = _pending[-1]
            _pending.clear()
            _raise(signum)


@contextmanager
def deferred():
    """A library loads with signals held; the handlers in place before are put back after it."""
    if not _main_thread():
        yield
        return
    handlers = {s: signal.getsignal(s) for s in SIGNALS}
    with held():
        try:
            yield
        finally:
            for s, h in handlers.items():
                if h is not None:
                    signal.signal(s, h)
