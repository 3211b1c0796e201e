"""Exceptions shared by the CLI and the library."""


class UsageError(Exception):
    """Bad input or usage: the CLI prints ``sharedlink: error: ...`` and exits with 2."""
