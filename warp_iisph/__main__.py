"""``python -m warp_iisph``: the command line, as ``warp-iisph`` and ``python -m warp_iisph.cli``."""

import sys

from .cli import main

sys.exit(main())
