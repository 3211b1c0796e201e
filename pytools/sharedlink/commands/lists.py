"""``sharedlink lists``: the list declarations of captures (vehicle profiles, issue 29), per
node pair in order, printed in the syntax of the variables preference and ``--variables``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedlink.commands import EXIT_OK, EXIT_USAGE, check_capture


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "lists",
        help="the variable lists declared in captures (vehicle profiles)",
        description="Every list declaration (N/L then T/Q pairs) of each capture, per node pair in capture order "
        "with types, and the lists in force at the end, in the per-pair syntax the sharedlink.variables "
        "preference and --variables read (B>A: AutoGpsHead:2,...; A>B: ...). Declarations with a bad "
        "checksum are shown as comments and change no list.",
    )
    p.add_argument("captures", type=Path, nargs="+", metavar="CAPTURE", help="pcap, pcapng or serial capture")
    p.add_argument("--json", action="store_true", help="print the declarations and lists as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sharedlink.analysis.lists import (  # (when the command runs: quick start-up)
        capture_lists,
        render_text,
    )

    for path in args.captures:
        check_capture(path)
    results = [capture_lists(path) for path in args.captures]
    if args.json:
        json.dump({"captures": [r.to_dict() for r in results]}, sys.stdout, indent=2)
        print()
    else:
        sys.stdout.write(render_text(results))
    damaged = [r for r in results if r.error]
    for r in damaged:
        print(f"sharedlink: error: {r.error} (the declarations before it are listed)", file=sys.stderr)
    return EXIT_USAGE if damaged else EXIT_OK
