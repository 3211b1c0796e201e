"""Sub-commands of the ``sharedlink`` CLI, one module each, and the options they share.

A command module holds ``register(sub)`` and ``run(args) -> int``; what several commands use
lives here, so that no command imports another.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sharedlink.analysis.decode import parse_variables
from sharedlink.errors import UsageError
from sharedlink.protocols.state import BEACON_VARIABLES

# -- exit codes, for every command ------------------------------------------------------------

EXIT_OK, EXIT_FAIL, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


def add_decode_options(p: argparse.ArgumentParser) -> None:
    """Options every capture-reading command of this family shares."""
    p.add_argument(
        "--variables",
        metavar="NAME[:TYPE],...",
        help="a-priori list naming positional values until the capture declares its own "
        "(default: the beacon's AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2)",
    )
    p.add_argument(
        "--sync-interval", type=float, default=1.0, metavar="S",
        help="a full set is expected every S seconds (default 1; late = more than S + 0.5 s)",
    )


def decode_options(args: argparse.Namespace) -> tuple[list[tuple[str, int | None]], float]:
    """(variables, sync interval) from :func:`add_decode_options` options; UsageError if bad."""
    variables: list[tuple[str, int | None]] = list(BEACON_VARIABLES)
    if args.variables:
        try:
            variables = parse_variables(args.variables)
        except ValueError as exc:
            raise UsageError(f"--variables: {exc}") from None
    if not args.sync_interval > 0:
        raise UsageError("--sync-interval must be positive")
    return variables, args.sync_interval


def check_capture(path: Path) -> None:
    if not path.exists():
        raise UsageError(f"{path}: no such file")
    if path.is_dir():
        raise UsageError(f"{path}: is a directory")
