"""``python -m flightsim``: the same as ``secuav-sim``."""

import sys

from flightsim.cli import main

sys.exit(main())
