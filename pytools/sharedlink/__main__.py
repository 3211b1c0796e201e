"""``python -m sharedlink``: the same as the ``sharedlink`` command."""

import sys

from .cli import main

sys.exit(main())
