"""``sharedlink stats``: frames per kind and node pair, rates, bytes, compression, checksum
failures, sync gaps and per-variable min/max/last of a capture."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedlink.commands import (
    EXIT_OK,
    EXIT_USAGE,
    Progress,
    add_decode_options,
    add_json_option,
    capture_input,
    decode_options,
    fit_table,
    warn_empty,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "stats",
        help="statistics of a capture",
        description="Frames per kind and per node pair, rates, bytes, compression ratio, checksum failures, "
        "sync gaps and per-variable count/min/max/last. Streams: any size of capture.",
    )
    p.add_argument("capture", type=Path, help="pcap or pcapng file (-: standard input)")
    add_decode_options(p)
    add_json_option(p, "the statistics")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sharedlink.analysis.stats import (  # (when the command runs: quick start-up)
        capture_stats,
        render_text,
    )

    variables, sync = decode_options(args)
    args.capture = capture_input(args.capture)
    with Progress(args.capture, quiet=args.json) as progress:
        st = capture_stats(args.capture, variables, sync, progress)
    if not st.error:
        warn_empty(args.capture, st.frames + st.robots.packets)  # (robot packets: no warning)
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


#: per table (by its headers' count): columns that wrap, columns left out first, right-aligned numbers
_LAYOUT: dict[int, dict] = {
    2: dict(wrap=(0,), drop=(), right=()),  # the summary, frames per kind
    9: dict(wrap=(4,), drop=(4, 8, 7, 6, 3), right=(1, 2, 3, 5, 6, 7, 8)),  # per node pair
    7: dict(wrap=(), drop=(6, 3, 0, 2), right=(2, 3, 4, 5)),  # variables
}


def _rich(st) -> None:
    """The tables on a terminal, fitted to its width (numbers never cut); plain text when a
    table cannot fit even with columns left out."""
    from rich.console import Console

    from sharedlink.analysis.stats import tables

    console = Console()
    for title, headers, rows in tables(st):
        t = fit_table(title, headers, rows, console.width, **_LAYOUT.get(len(headers), {}))
        if t is None:
            grid = ([headers] if any(headers) else []) + rows
            widths = [max(len(r[i]) for r in grid) for i in range(len(headers))]
            console.print(title, highlight=False)
            for r in grid:
                console.print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip(), highlight=False, soft_wrap=True)
        else:
            console.print(t)
