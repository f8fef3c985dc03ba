"""``python -m lacore.cli ...``: the ``lacore`` console script."""

import sys

from . import main

sys.exit(main())
