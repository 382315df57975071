"""``python -m warp_iisph``: the command line, as ``warp-iisph`` and ``python -m warp_iisph.cli``."""

from .cli import exit_module, main

exit_module(main())
