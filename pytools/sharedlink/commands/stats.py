"""``sharedlink stats``: frames per kind and node pair, rates, bytes, compression, checksum
failures, sync gaps and per-variable min/max/last of a capture."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedlink.commands import (
    EXIT_FAIL,
    EXIT_OK,
    EXIT_USAGE,
    Progress,
    add_decode_options,
    add_json_option,
    add_outage_after_option,
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
    add_outage_after_option(p)
    p.add_argument("--fail-on", type=_fail_on, default=(), metavar="WHAT",
                   help="exit 1 when the capture has any of WHAT (comma-separated): outage (a link went silent)")
    p.set_defaults(func=run)


#: what --fail-on takes
FAIL_ON = ("outage",)


def _fail_on(text: str) -> tuple[str, ...]:
    what = tuple(w.strip() for w in text.split(",") if w.strip())
    bad = [w for w in what if w not in FAIL_ON]
    if bad or not what:
        raise argparse.ArgumentTypeError(f"{text!r}: give one or more of {', '.join(FAIL_ON)}, comma-separated")
    return what


def run(args: argparse.Namespace) -> int:
    from sharedlink.analysis.stats import (  # (when the command runs: quick start-up)
        capture_stats,
        render_text,
    )

    variables, sync = decode_options(args)
    args.capture = capture_input(args.capture)
    with Progress(args.capture, quiet=args.json) as progress:
        st = capture_stats(args.capture, variables, sync, progress, args.outage_after)
    if not st.error:
        warn_empty(args.capture, st.frames)
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
    if "outage" in args.fail_on and st.health.outages():
        print(f"sharedlink: {len(st.health.outages())} outage(s) (--fail-on outage)", file=sys.stderr)
        return EXIT_FAIL
    return EXIT_OK


#: per table (by its headers' count): columns that wrap, columns left out first, right-aligned numbers
_LAYOUT: dict[int, dict] = {
    2: dict(wrap=(0,), drop=(), right=()),  # the summary, frames per kind
    9: dict(wrap=(4,), drop=(4, 8, 7, 6, 3), right=(1, 2, 3, 5, 6, 7, 8)),  # per node pair
    7: dict(wrap=(), drop=(6, 3, 0, 2), right=(2, 3, 4, 5)),  # variables
    10: dict(wrap=(0,), drop=(9, 8, 6, 5, 3, 2, 7), right=(2, 3, 4, 5, 6, 7, 8, 9)),  # link health
    5: dict(wrap=(0,), drop=(3, 1, 2), right=(4,)),  # outages
    3: dict(wrap=(0, 2), drop=(), right=()),  # link notes
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
