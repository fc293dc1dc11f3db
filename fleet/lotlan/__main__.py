"""Entry point of ``python -m fleet.lotlan`` (see fleet.lotlan.cli)."""

import sys

from fleet.lotlan.cli import main

sys.exit(main())
