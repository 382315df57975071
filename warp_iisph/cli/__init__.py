"""Command line: ``warp-iisph run | sweep | scenes | mesh | preview | plot | render | usd | blender-script``
(the grammar in :mod:`.parser`, what each command does in :mod:`.commands`).

Every error is one line on stderr: exit status 2 for bad input (a file, key or argument and its
allowed range), 1 for a failure at run time, 130 for Ctrl-C and 143 for SIGTERM; ``--debug``
shows the traceback instead.
"""

from __future__ import annotations

import os
import sys

from ..engine import signals

# As a program (the warp-iisph script, or python -m warp_iisph.cli), Ctrl-C and SIGTERM are
# remembered from here on, within milliseconds of the start (the package's __init__ imports
# nothing), and raised once main can catch them; imported by other code, main installs them.
# (python -m warp_iisph.cli imports this package with sys.argv[0] set to "-m")
if sys.argv[:1] == ["-m"] or os.path.basename(sys.argv[0] if sys.argv else "") in ("warp-iisph", "warp-iisph.exe"):
    signals.install(armed=False)

EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_TERMINATED = 2, 1, 130, 143


def main(argv=None) -> int:
    """The command line (``argv``: its arguments; ``None``: this process's, as a program)."""
    program = argv is None
    seen = 0 if program else signals.count()  # as a program, a signal before this line counts too
    try:
        signals.install()
        signals.arm()
        _standard_streams()
        argv = list(sys.argv[1:] if argv is None else argv)
        debug = "--debug" in argv
        argv = [a for a in argv if a != "--debug"]  # anywhere on the line, before or after the command
        code = _command(argv, debug) if signals.count() == seen else _stopped(signals.received())
        if signals.count() != seen and code == 0:  # a library swallowed the signal's exception
            code = _stopped(signals.received())
        if program:  # what is left is the interpreter's shutdown: a signal now would only cost a traceback
            signals.ignore()
    except KeyboardInterrupt as e:  # a signal while an error was being reported, or the work was done
        code = _stopped(signal_of(e))
        if program:
            signals.ignore()
    if program:
        _flush_stdout()
    return code


def exit_module(code: int):
    """Exit a ``python -m`` run (of this package or of :mod:`warp_iisph.cli`) with status ``code``.

    CPython (3.8 on) ends a ``-m`` run by SIGINT, whatever status it exits with, once a
    KeyboardInterrupt has left a string ``exec``, even one caught afterwards (dataclasses and
    namedtuple build their methods so, and a Ctrl-C at start-up lands there); a string exec that
    completes clears that mark."""
    exec("pass")
    sys.exit(code)


def signal_of(e: KeyboardInterrupt):
    import signal

    return signal.SIGTERM if isinstance(e, signals.Terminated) else signal.SIGINT


def _stopped(signum) -> int:
    import signal

    terminated = signum == signal.SIGTERM
    _say(f"warp-iisph: {'terminated' if terminated else 'interrupted'}")
    return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED


# The commands that load trimesh (scenes, meshes, viewers): it loads with signals held.
MESH_COMMANDS = ("run", "sweep", "mesh", "render", "preview", "usd", "blender-script")


def _command(argv: list, debug: bool) -> int:
    from .commands import COMMANDS

    try:
        parser = _parser()
        args = parser.parse_args(argv)
        repeatable = _repeatable(parser)
        for key, value in vars(args).items():  # argparse gives [] for --opt=-- (it drops the "--")
            if isinstance(value, list) and key not in repeatable:
                parser.error(f"argument --{key.replace('_', '-')}: expected one value")
        if args.command in MESH_COMMANDS:
            with signals.deferred():  # trimesh's optional imports catch BaseException: a Ctrl-C among them was lost
                import trimesh  # noqa: F401
        return COMMANDS[args.command](args)
    except KeyboardInterrupt as e:
        return _stopped(signal_of(e))
    except Exception as e:
        if isinstance(e, BrokenPipeError) and _stdout_gone():  # the reader went away (| head): done
            return 0
        if debug:
            raise
        code, text = _one_line(e)
        _say(f"warp-iisph: error: {text}")
        return code


def _stdout_gone() -> bool:
    """Whether standard output is a pipe whose reader has gone (polled: an error on it)."""
    import select

    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poll.poll(0))
    except (OSError, ValueError, AttributeError):  # no poll here, or no stdout to ask
        return False


def _repeatable(parser) -> set:
    """The destinations of options that may be given more than once (``--set``, ``--vary``)."""
    import argparse

    found = set()
    for action in parser._actions:
        if isinstance(action, argparse._AppendAction):
            found.add(action.dest)
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found |= _repeatable(sub)
    return found


def _say(line: str) -> None:
    """One line on stderr, if anything is there to take it."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError, AttributeError):
        pass


def _standard_streams() -> None:
    """Standard streams the shell closed (``2>&-``) opened on /dev/null: else the next file this
    process opens would take the descriptor, and receive what is written to the stream."""
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    if sys.stdout is None:
        sys.stdout = open(1, "w", closefd=False)  # lives as long as the process
    if sys.stderr is None:
        sys.stderr = open(2, "w", closefd=False)


def _flush_stdout() -> None:
    """Flush stdout now: a reader that went away (``| head``) costs nothing at the shutdown."""
    try:
        sys.stdout.flush()
    except (OSError, ValueError):
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.close(null)
        except OSError:
            pass


def use_graph(asked: bool | None, device: str) -> bool:
    """``--graph`` / ``--no-graph`` as given, else graphs on CUDA (they remove the per-step launch
    cost: 1.75 against 3.8 ms per step at 97k particles on an H200) and not on the CPU (where
    a replay runs on one thread and split launches are faster)."""
    return bool(asked) if asked is not None else device.startswith("cuda")


def _one_line(e: Exception) -> tuple[int, str]:
    """Exit status and message of an error: bad input (ValueError: a file, key or argument out of
    range) is 2, anything else 1."""
    text = " ".join(str(e).split()) or type(e).__name__
    if isinstance(e, ValueError):
        return EXIT_BAD_INPUT, text
    if isinstance(e, MemoryError):
        return EXIT_FAILED, text if str(e) else "out of memory"
    if isinstance(e, OSError):
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        return EXIT_FAILED, f"{where}{e.strerror or text}"
    return EXIT_FAILED, f"{type(e).__name__}: {text} (an internal error: run with --debug for the traceback)"


def _parser():
    """The command line's parser (:mod:`.parser`)."""
    from .parser import _parser as build

    return build()


def __getattr__(name: str):
    """``COMMANDS`` (the command names to what runs them), loaded with :mod:`.commands` on first use."""
    if name == "COMMANDS":
        from .commands import COMMANDS

        return COMMANDS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
