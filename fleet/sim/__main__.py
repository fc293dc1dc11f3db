"""Entry point of ``python -m fleet.sim`` (see :mod:`fleet.sim.cli`)."""

import sys

from fleet.sim.cli import main

sys.exit(main())
