"""``python -m engine.context_broker``: see :mod:`engine.context_broker.server`."""

import sys

from engine.context_broker.server import main

sys.exit(main())
