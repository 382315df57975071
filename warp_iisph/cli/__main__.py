"""``python -m warp_iisph.cli``: the command line."""

import sys

from . import main

sys.exit(main())
