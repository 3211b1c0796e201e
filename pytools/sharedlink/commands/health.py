"""``sharedlink health``: is the link healthy? Per link its learnt rate and outages, and the
link quality of every second (frames while up, seconds of outage while down)."""

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
    add_force_option,
    add_json_option,
    add_outage_after_option,
    add_quiet_option,
    capture_input,
    decode_options,
    honours_force,
    note,
    plural,
    warn_empty,
)
from sharedlink.errors import UsageError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "health",
        help="link health: outages and the link quality per second",
        description="Per link (one direction of one conversation): its learnt rate, its outages, and the link "
        "quality of every second: the frames received while up, the seconds since the outage began while down "
        "(docs/fields-sharedlink.md, 'Link health'). A table on a terminal, CSV or JSONL with -o, a PNG strip with --plot.",
    )
    p.add_argument("capture", type=Path, help="pcap or pcapng file (-: standard input)")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="FILE",
                   help="write the per-second rows to FILE (.csv or .jsonl; -: JSONL on standard output)")
    p.add_argument("--plot", type=Path, default=None, metavar="PNG", help="draw the quality strip per link to PNG (.png, .svg, .pdf)")
    add_force_option(p)
    add_outage_after_option(p)
    add_decode_options(p)
    add_json_option(p, "the links and outages")
    add_quiet_option(p)
    p.set_defaults(func=run)


def _format(path: Path | None) -> str | None:
    if path is None:
        return None
    if str(path) == "-" or path.suffix.lower() == ".jsonl":
        return "jsonl"
    if path.suffix.lower() == ".csv":
        return "csv"
    raise UsageError(f"{path}: give a .csv or .jsonl file name (-: JSONL on standard output)")


@honours_force
def run(args: argparse.Namespace) -> int:
    from sharedlink.analysis.health import health_dict
    from sharedlink.analysis.timeline import capture_health
    from sharedlink.capture.pcapio import open_output, refuse_overwrite

    variables, sync = decode_options(args)
    fmt = _format(args.output)
    if args.plot is not None and args.plot.suffix.lower() not in (".png", ".svg", ".pdf"):
        raise UsageError(f"{args.plot}: give a .png, .svg or .pdf file name")
    args.capture = capture_input(args.capture)
    refuse_overwrite(args.output, args.capture)
    refuse_overwrite(args.plot, args.capture)
    with Progress(args.capture, quiet=args.json or str(args.output) == "-") as progress:
        ch = capture_health(args.capture, variables, sync, progress, args.outage_after)
    if not ch.error:
        warn_empty(args.capture, ch.frames)
    written = None
    if fmt is not None:
        from sharedlink.analysis.timeline import write_rows

        with open_output(args.output, "w", encoding="utf-8", newline="") as fh:
            written = write_rows(ch, fh, fmt)
    if args.plot is not None:
        from sharedlink.analysis.timeline import plot_strip

        with open_output(args.plot) as fh:
            plot_strip(ch, fh, args.plot.suffix.lower()[1:])
    if args.json:
        json.dump({"capture": str(args.capture), **health_dict(ch.health), "error": ch.error}, sys.stdout, indent=2)
        print()
    elif str(args.output) != "-":
        if written is not None or args.plot is not None:
            _report(args, ch, written)
        else:
            _table(ch)
    if ch.error:
        print(f"sharedlink: error: {ch.error} (the {ch.frames} frames before it are counted)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK


def _report(args: argparse.Namespace, ch, written: int | None) -> None:
    outages = ch.health.outages()
    what = [f"{args.output}: {plural(written, 'row')}"] if written is not None else []
    if args.plot is not None:
        what.append(f"{args.plot}: the quality strip")
    note(f"wrote {', '.join(what)} ({plural(len(ch.health.links), 'link')}, {plural(len(outages), 'outage')})")


def _table(ch) -> None:
    """The per-second quality, a column per link, then the link table (stats'): fitted on a
    terminal, plain on a pipe (sharedlink.present)."""
    from sharedlink.analysis.health import health_table
    from sharedlink.analysis.timeline import grid
    from sharedlink.present import show, text_table

    headers, rows = grid(ch)
    show([text_table(f"Link quality per second: {ch.path}", headers, rows), *health_table(ch.health)])
