"""Ctrl-C and SIGTERM as exceptions in the main thread, from the command line's first instruction
on, and kept through what could lose them.

- :func:`install`: SIGINT raises ``KeyboardInterrupt``, SIGTERM :class:`Terminated`, and both are
  remembered (:func:`received`), so that a signal whose exception a library swallowed still
  ends the command with its status.
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


def _handler(signum, frame):
    _received.append(signum)
    if signum == signal.SIGTERM:
        raise Terminated()
    raise KeyboardInterrupt()


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def install() -> None:
    """Our handlers, where Python's defaults are in place (a host that set its own keeps it)."""
    if not _main_thread():
        return
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _handler)
    if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _handler)


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
    """Ctrl-C and SIGTERM wait until the block has run (then they are raised as usual)."""
    if not _main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


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
