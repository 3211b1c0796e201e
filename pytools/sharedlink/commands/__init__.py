"""Sub-commands of the ``sharedlink`` CLI, one module each."""
