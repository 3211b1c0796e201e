"""``sharedlink stats``: frames per kind and node pair, rates, bytes, compression, checksum
failures, late full sets and per-variable min/max/last of a capture."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedlink.commands import (
    EXIT_USAGE,
    Progress,
    add_decode_options,
    add_fail_on_option,
    add_json_option,
    add_outage_after_option,
    add_quiet_option,
    capture_input,
    decode_options,
    fail_on,
    warn_empty,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "stats",
        help="statistics of a capture",
        description="Frames per kind and per node pair, rates, bytes, compression ratio, checksum failures, "
        "late full sets and per-variable count/min/max/last. Streams: any size of capture.",
    )
    p.add_argument("capture", type=Path, help="pcap or pcapng file (-: standard input)")
    add_decode_options(p)
    add_json_option(p, "the statistics")
    add_quiet_option(p)
    add_outage_after_option(p)
    add_fail_on_option(p)
    p.set_defaults(func=run)


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
    return fail_on(args.fail_on, st)


def _rich(st) -> None:
    """The tables on a terminal, fitted to its width (sharedlink.present)."""
    from sharedlink.analysis.stats import tables
    from sharedlink.present import show

    show(tables(st), terminal=True)
