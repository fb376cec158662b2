"""``python -m warp_stokes.cli``: the ``warp-stokes`` command."""

import sys

from . import main

sys.exit(main())
