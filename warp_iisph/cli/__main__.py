"""``python -m warp_iisph.cli``: the command line."""

import sys

from . import main

code = main()
# Under ``python -m``, CPython (3.8 on) ends the process by SIGINT, whatever status it exits with,
# once a KeyboardInterrupt has left a string ``exec`` (dataclasses and namedtuple build their
# methods so, and a Ctrl-C at start-up lands there), even one caught afterwards; a string exec
# that completes clears that mark, so the status is the one main returned.
exec("pass")
sys.exit(code)
