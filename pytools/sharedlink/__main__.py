"""``python -m sharedlink``: the same as the ``sharedlink`` command."""

import sys

from ._interrupt import quiet_interrupt

with quiet_interrupt():  # Ctrl-C while the command loads: exit 130, no traceback
    from .cli import main

sys.exit(main())
