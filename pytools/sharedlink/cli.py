"""The ``sharedlink`` command: a thin argparse layer over the library.

Each sub-command lives in ``sharedlink/commands/<name>.py`` with ``register(subparsers)``
adding its parser and setting ``func``; ``func(args) -> int`` returns the exit code.

Exit codes, for every command: 0 success (and, for diff, data agree), 1 the check failed
(diff: data diverge), 2 bad input or usage (missing or damaged file, bad option), 130 stopped
by Ctrl-C.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from . import __version__
from .commands import EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE
from .errors import Error, UsageError

#: sub-command modules, in the order ``--help`` lists them
COMMANDS = ["gen", "replay", "serial", "compress", "expand", "diff", "stats", "export", "plot", "watch", "ingest", "query"]

__all__ = ["EXIT_INTERRUPTED", "EXIT_OK", "EXIT_USAGE", "Error", "UsageError", "main", "build_parser"]



def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sharedlink",
        description="Generate, replay, compare and decode SharedLink beacon captures.",
        epilog="Exit codes: 0 ok, 1 check failed (e.g. diff found a divergence), 2 bad input or usage, 130 interrupted.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"sharedlink.commands.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except Error as exc:  # every error of the package, reported once: FILE: record N: reason
        print(f"sharedlink: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("sharedlink: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return EXIT_OK


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
