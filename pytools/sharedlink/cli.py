"""The ``sharedlink`` command: a thin argparse layer over the library.

Each sub-command lives in ``sharedlink/commands/<name>.py`` with ``register(subparsers)``
adding its parser and setting ``func``; ``func(args) -> int`` returns the exit code.

Exit codes, for every command (the table is in docs/cli.md): 0 success (and, for diff, data
agree; watch stopped by Ctrl-C, its normal end, as tcpdump), 1 the check failed (diff: data
diverge; stats --fail-on: a problem occurred), 2 bad input or usage (missing or damaged file, bad
option, output that is the input, a missing extra, full disk), 130 stopped by Ctrl-C, 143 stopped
by SIGTERM (cleaned up as on Ctrl-C, replay and watch too).
"""

from __future__ import annotations

from ._interrupt import Terminated, quiet_interrupt

# Ctrl-C while the command loads (the standard library's modules too): exit 130, no traceback
with quiet_interrupt():
    import argparse
    import importlib
    import os
    import signal
    import sys
    import threading
    from collections.abc import Sequence
    from typing import Any, NoReturn

    from . import __version__
    from .commands import EXIT_INTERRUPTED, EXIT_OK, EXIT_TERMINATED, EXIT_USAGE, set_quiet
    from .commands.examples import epilog
    from .errors import Error, UsageError

#: sub-command modules, in the order ``--help`` lists them
COMMANDS = [
    "gen", "replay", "serial", "compress", "expand", "diff", "stats", "health", "export", "plot", "lists", "watch",
    "ingest", "query", "plugins", "completion",
]

__all__ = ["EXIT_INTERRUPTED", "EXIT_OK", "EXIT_USAGE", "Error", "UsageError", "main", "build_parser"]



class _HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, except that an epilog of indented lines (the examples) is kept as
    written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        prose, mark, examples = text.partition("examples:\n")
        filled = super()._fill_text(prose, width, indent) if prose.strip() else ""
        if not mark:
            return filled
        raw = "\n".join(indent + line for line in (mark + examples).splitlines())
        return f"{filled}\n\n{raw}" if filled else raw


class _Parser(argparse.ArgumentParser):
    """argparse with its errors (a bad number, a missing argument, an unknown option) raised as
    UsageError: the usage line of the (sub)command that was given, then ``sharedlink: error:
    ...`` once from :func:`main`, exit 2 (also when :func:`main` is called from Python)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        self.print_usage(sys.stderr)
        raise UsageError(message)

    def parse_args(self, args: Sequence[str] | None = None, namespace: Any = None) -> argparse.Namespace:  # type: ignore[override]
        """As argparse's, but an unknown option is reported with the usage of the subcommand
        it was given to (``usage: sharedlink stats ...``), not the top-level one."""
        ns, extras = self.parse_known_args(args, namespace)
        parser = ns.__dict__.pop("_parser", self)
        if extras:
            parser.error(f"unrecognized arguments: {' '.join(extras)}")
        return ns


def _leaves(parser: argparse.ArgumentParser, name: str = "") -> list[tuple[str, argparse.ArgumentParser]]:
    """Every (sub)command's parser, by its name (``serial capture``)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return [(name, parser)] if name else []
    return [leaf for s in subs for sub, p in s.choices.items() for leaf in _leaves(p, f"{name} {sub}".strip())]


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command's parser; with ``command`` (the first word given, as :func:`main`
    passes it) only that command's parser under it, when it names one: a run loads and builds
    one command, not all (its parsing is the same; ``completion`` needs them all)."""
    parser = _Parser(
        prog="sharedlink",
        description="Generate, replay, compare and decode SharedLink beacon captures.",
        epilog="Exit codes: 0 ok (also watch stopped with Ctrl-C), 1 check failed (diff found a divergence, stats "
        "--fail-on a problem, replay could not send), 2 bad input or usage, 130 interrupted by Ctrl-C, 143 by "
        "SIGTERM. 'sharedlink COMMAND --help' ends with examples; docs/cli.md has the whole vocabulary.\n\n"
        "examples:\n  sharedlink gen -o drive.pcap      # a 60 s drive\n"
        "  sharedlink stats drive.pcap       # what is in it\n"
        "  sharedlink completion bash        # shell completion (bash, zsh, fish)",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in [command] if command in COMMANDS and command != "completion" else COMMANDS:
        importlib.import_module(f"sharedlink.commands.{name}").register(sub)
    if "completion" in sub.choices:
        sub.choices["completion"].set_defaults(root_parser=parser)  # what its script completes
    for name, leaf in _leaves(parser):
        leaf.set_defaults(_parser=leaf)  # (read by _Parser.parse_args: the usage of this command)
        examples = epilog(name)
        if examples:
            leaf.epilog = f"{leaf.epilog}\n\n{examples}" if leaf.epilog else examples
    return parser


def _terminate(signum: int, frame: object) -> None:
    raise Terminated()


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; its exit code. Ctrl-C (even while the parser is being built) and
    SIGTERM end it cleanly: no traceback, no half-written file (130, 143)."""
    previous = None
    try:
        previous = _install_sigterm()
        words = sys.argv[1:] if argv is None else list(argv)
        parser = build_parser(words[0] if words else None)
        args = parser.parse_args(words)
        set_quiet(args)
        if args.command is None:  # bare `sharedlink`: the commands, as --help lists them
            parser.print_help()
            return EXIT_OK
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
