"""``python -m warp_iisph.cli``: the command line."""

from . import exit_module, main

exit_module(main())
