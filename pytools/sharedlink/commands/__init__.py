"""Sub-commands of the ``sharedlink`` CLI, one module each, and what they share.

A command module holds ``register(sub)`` and ``run(args) -> int`` and calls the library; what
several commands use lives here (as in pypa/twine ``twine/commands/__init__.py``), so that no
command imports another. Errors are raised (``sharedlink.errors``), never printed here:
``cli.main`` reports them once.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from sharedlink.analysis.transform import transform_capture
from sharedlink.capture.pcapio import is_stdout
from sharedlink.errors import UsageError
from sharedlink.protocols.state import BEACON_VARIABLES, parse_variables

T = TypeVar("T")

# -- exit codes, for every command ------------------------------------------------------------

EXIT_OK, EXIT_FAIL, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
#: stopped by SIGTERM (128 + 15), cleaned up as on Ctrl-C
EXIT_TERMINATED = 143

# -- options: --variables (one parser, one meaning in every command) and --sync-interval -----

VARIABLES_HELP = (
    "the a-priori outbound list positional frames are named by until the capture declares its own, "
    "NAME[:TYPE],... (TYPE 0 long, 2 double, 4 string; default the beacon's "
    "AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2)"
)


def add_variables_option(p: argparse.ArgumentParser) -> None:
    """``--variables NAME[:TYPE],...``, read by :func:`variables_option`."""
    p.add_argument("--variables", metavar="NAME[:TYPE],...", default=None, help=VARIABLES_HELP)


def variables_option(text: str | None) -> list[tuple[str, int | None]]:
    """The ``--variables`` list (the beacon's when not given); UsageError if bad."""
    if text is None:
        return list(BEACON_VARIABLES)
    try:
        return parse_variables(text)
    except ValueError as exc:
        raise UsageError(f"--variables: {exc}") from None


def add_decode_options(p: argparse.ArgumentParser) -> None:
    """Options every capture-reading command of this family shares."""
    add_variables_option(p)
    p.add_argument(
        "--sync-interval", type=float, default=1.0, metavar="S",
        help="a full set is expected every S seconds (default 1; late = more than S + 0.5 s)",
    )


def decode_options(args: argparse.Namespace) -> tuple[list[tuple[str, int | None]], float]:
    """(variables, sync interval) from :func:`add_decode_options` options; UsageError if bad."""
    variables = variables_option(args.variables)
    if not args.sync_interval > 0:
        raise UsageError("--sync-interval must be positive")
    return variables, args.sync_interval


def check_capture(path: Path) -> None:
    """A capture to read must exist and be a file."""
    if not path.exists():
        raise UsageError(f"{path}: no such file")
    if path.is_dir():
        raise UsageError(f"{path}: is a directory, not a capture")


# -- commands that write a file (gen, serial) ----------------------------------------------------


def generate_to(opts: Any, generate: Callable[[Any, Path], T], out: Path) -> T:
    """``opts.validate()`` then ``generate(opts, out)``; a bad option or an unwritable file is a
    :class:`UsageError` (exit 2), never a traceback."""
    try:
        opts.validate()
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    try:
        return generate(opts, out)
    except OSError as exc:
        raise UsageError(f"{out}: {exc.strerror or exc}") from None


def report(summary: dict, as_json: bool, line: str) -> None:
    """The closing summary: JSON on stdout with ``--json``, else ``line`` on stderr."""
    if as_json:
        json.dump(summary, sys.stdout)
        print()
    else:
        print(line, file=sys.stderr)


# -- compress and expand -----------------------------------------------------------------------


def add_transform_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments ``compress`` and ``expand`` share."""
    p.add_argument("input", type=Path, help="pcap or pcapng capture to read")
    p.add_argument("output", type=Path, help="capture to write (same format as the input)")
    add_variables_option(p)
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


def run_transform(args: argparse.Namespace, mode: str) -> int:
    """``compress`` / ``expand``: rewrite the capture, then the summary."""
    if not (args.sync_interval > 0 and math.isfinite(args.sync_interval)):
        raise UsageError("--sync-interval must be a positive number of seconds")
    variables = variables_option(args.variables)
    if args.json and is_stdout(args.output):
        raise UsageError("--json needs an output file (the capture goes to standard output)")
    st = transform_capture(args.input, args.output, mode, args.sync_interval, variables)
    if args.json:
        json.dump({"input": str(args.input), "output": str(args.output), "mode": mode, **st.to_dict()}, sys.stdout)
        print()
    else:
        saving = ""
        if st.saving is not None:
            saving = f" ({st.saving:.1%} smaller)" if st.saving >= 0 else f" ({-st.saving:.1%} larger)"
        print(
            f"wrote {args.output}: {st.records} records, {st.value_frames} value frames "
            f"({st.full} full, {st.delta} delta, {st.copied} copied unchanged), "
            f"SharedLink bytes {st.bytes_in} -> {st.bytes_out}{saving}",
            file=sys.stderr,
        )
    if st.error:
        print(f"sharedlink: error: {st.error} (the records before it were written)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK
