"""``sharedlink stats``: frames per kind and node pair, rates, bytes, compression, checksum
failures, sync gaps and per-variable min/max/last of a capture."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..cli import EXIT_OK, EXIT_USAGE, UsageError
from ..decode import parse_variables
from ..pcapio import CaptureError
from ..state import BEACON_VARIABLES
from ..stats import capture_stats, render_text, tables


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


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "stats",
        help="statistics of a capture",
        description="Frames per kind and per node pair, rates, bytes, compression ratio, checksum failures, "
        "sync gaps and per-variable count/min/max/last. Streams: any size of capture.",
    )
    p.add_argument("capture", type=Path, help="pcap or pcapng file")
    add_decode_options(p)
    p.add_argument("--json", action="store_true", help="print the statistics as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    variables, sync = decode_options(args)
    check_capture(args.capture)
    try:
        st = capture_stats(args.capture, variables, sync)
    except CaptureError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        json.dump(st.to_dict(), sys.stdout, indent=2)
        print()
    elif sys.stdout.isatty():
        _rich(st)
    else:
        sys.stdout.write(render_text(st))
    if st.error:
        print(f"sharedlink: error: {st.error} (the statistics cover the {st.frames} frames before it)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK


def _rich(st) -> None:  # pragma: no cover - terminals only
    from rich.console import Console
    from rich.table import Table

    console = Console()
    for title, headers, rows in tables(st):
        t = Table(title=title, show_header=any(headers), title_justify="left")
        for h in headers:
            t.add_column(h)
        for r in rows:
            t.add_row(*r)
        console.print(t)
