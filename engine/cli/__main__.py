"""``python -m engine.cli`` runs the ``plantkg`` command (used to start agents with this interpreter)."""

import sys

from engine.cli import main

sys.exit(main())
