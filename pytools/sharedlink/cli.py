"""The ``sharedlink`` command: a thin argparse layer over the library.

Each sub-command lives in ``sharedlink/commands/<name>.py`` with ``register(subparsers)``
adding its parser and setting ``func``; ``func(args) -> int`` returns the exit code.

Exit codes, for every command: 0 success (and, for diff, data agree), 1 the check failed
(diff: data diverge), 2 bad input or usage (missing or damaged file, bad option, output that is
the input, full disk), 130 stopped by Ctrl-C, 143 stopped by SIGTERM (cleaned up as on Ctrl-C).
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any, NoReturn

from . import __version__
from ._interrupt import quiet_interrupt

with quiet_interrupt():  # Ctrl-C while the command loads: exit 130, no traceback
    from .commands import EXIT_INTERRUPTED, EXIT_OK, EXIT_TERMINATED, EXIT_USAGE
    from .errors import Error, UsageError

#: sub-command modules, in the order ``--help`` lists them
COMMANDS = [
    "gen", "replay", "serial", "compress", "expand", "diff", "stats", "health", "export", "plot", "lists", "watch",
    "ingest", "query", "plugins",
]

__all__ = ["EXIT_INTERRUPTED", "EXIT_OK", "EXIT_USAGE", "Error", "UsageError", "main", "build_parser"]



class _Parser(argparse.ArgumentParser):
    """argparse with its errors (a bad number, a missing argument) raised as UsageError: the
    usage line, then ``sharedlink: error: ...`` once from :func:`main`, exit 2 (also when
    :func:`main` is called from Python)."""

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        self.print_usage(sys.stderr)
        raise UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="sharedlink",
        description="Generate, replay, compare and decode SharedLink beacon captures.",
        epilog="Exit codes: 0 ok, 1 check failed (e.g. diff found a divergence), 2 bad input or usage, 130 interrupted (143 by SIGTERM).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"sharedlink.commands.{name}").register(sub)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is so that it cleans up as on Ctrl-C."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated()


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; its exit code. Ctrl-C (even while the parser is being built) and
    SIGTERM end it cleanly: no traceback, no half-written file (130, 143)."""
    previous = _install_sigterm()
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        return int(args.func(args) or 0)
    except Error as exc:  # every error of the package, reported once: FILE: record N: reason
        print(f"sharedlink: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except Terminated:
        print("sharedlink: terminated", file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        print("sharedlink: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_OK
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _install_sigterm() -> Any:
    """SIGTERM raises :class:`Terminated` (main thread only); the previous handler."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _terminate)


def _quiet_stdout() -> None:
    """After a closed pipe: no second error when Python flushes stdout at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
