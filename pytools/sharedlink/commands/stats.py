"""``sharedlink stats``: frames per kind and node pair, rates, bytes, compression, checksum
failures, sync gaps and per-variable min/max/last of a capture."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedlink.analysis.stats import capture_stats, render_text, tables
from sharedlink.commands import (
    EXIT_OK,
    EXIT_USAGE,
    Progress,
    add_decode_options,
    check_capture,
    decode_options,
)


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
    with Progress(args.capture, quiet=args.json) as progress:
        st = capture_stats(args.capture, variables, sync, progress)
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
