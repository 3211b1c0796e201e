"""``sharedlink ingest``: captures (files or directories) into a fleet Parquet dataset."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sharedlink.commands import (
    EXIT_OK,
    EXIT_USAGE,
    SECONDS,
    OldFlag,
    Progress,
    add_decode_options,
    add_json_option,
    add_old_spelling,
    add_output_option,
    add_quiet_option,
    decode_options,
)
from sharedlink.commands import report as print_summary
from sharedlink.errors import UsageError
from sharedlink.extras import require
from sharedlink.fleet import BATCH_ROWS, SCHEDULER_TIMEOUT_S

if TYPE_CHECKING:
    from sharedlink.fleet.ingest import Outcome


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ingest",
        help="decode captures into a Parquet dataset (frames, values, packets, links and outages tables)",
        description="Decode every capture into the Parquet dataset DATASET (Hive-partitioned by day and node pair; "
        "tables frames and values; see docs/fleet.md). Incremental: a capture already in the dataset with the same "
        "content is skipped, a changed one has its rows replaced. A damaged capture keeps the rows before the damage "
        "and is reported (exit 2 once everything else is ingested).",
    )
    p.add_argument("inputs", nargs="+", type=Path, metavar="CAPTURE_OR_DIR",
                   help="capture files, or directories searched for *.pcap, *.pcapng and *.cap")
    add_output_option(p, "the dataset directory (made if missing)", dest="dataset", metavar="DATASET")
    add_old_spelling(p, "--to", "-o/--output", "dataset", type=Path, metavar="DATASET")
    p.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the tasks on this Dask distributed scheduler (e.g. tcp://host:8786) instead; "
                   "its workers must see the captures and DATASET at the same paths")
    p.add_argument("--scheduler-timeout", type=SECONDS, default=SCHEDULER_TIMEOUT_S, metavar="SECONDS",
                   help=f"how long to try to reach the --scheduler before giving up (exit 2; default {SCHEDULER_TIMEOUT_S:g})")
    p.add_argument("--vehicle", metavar="NAME",
                   help="the vehicle of every capture given (default: the name of the directory a capture is in)")
    p.add_argument("--reingest", action="store_true", help="decode captures again even when the dataset holds them unchanged")
    p.add_argument("--force", dest="reingest", action=OldFlag, new="--reingest (--force means replace a symbolic-link output elsewhere)")
    p.add_argument("--batch-rows", type=int, default=BATCH_ROWS, metavar="N",
                   help=f"rows held per table before a row group is written (bounds memory; default {BATCH_ROWS})")
    add_quiet_option(p)
    add_decode_options(p)
    add_json_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    require("fleet", "sharedlink ingest")
    if args.scheduler:
        require("dask", "sharedlink ingest --scheduler")
    from sharedlink.fleet.ingest import ingest  # pyarrow loads only for this command

    variables, sync = decode_options(args)
    if args.dataset is None:
        raise UsageError("no dataset: give -o DATASET")
    _check_inputs(args.inputs)

    def say(o: Outcome) -> None:
        if args.quiet and o.status in ("ingested", "unchanged"):
            return
        if o.status == "unchanged":
            line = "unchanged"
        elif o.entry is not None:
            line = f"{o.status}: {o.entry.frames} frames, {o.entry.values} values"
            if o.entry.packets:
                line += f", {o.entry.packets} P2OS/blackboard packets"
        else:
            line = o.status
        print(f"{o.path}: {line}", file=sys.stderr)
        if o.error:
            print(f"sharedlink: error: {o.error}", file=sys.stderr)

    if args.batch_rows < 1:
        raise UsageError("--batch-rows must be at least 1")
    with Progress(None, quiet=args.quiet or args.json, what="ingesting") as progress:
        progress.total = _total_size(args.inputs)  # (bytes of every capture: the bar's whole)
        report = ingest(
            args.inputs, args.dataset, workers=args.workers, scheduler=args.scheduler,
            scheduler_timeout=args.scheduler_timeout, vehicle=args.vehicle,
            variables=variables, sync_interval=sync, force=args.reingest, batch_rows=args.batch_rows, on_outcome=say,
            progress=progress,
        )
    bad = report.count("damaged") + report.count("failed")
    summary = {"dataset": str(args.dataset), "ingested": report.count("ingested"), "unchanged": report.count("unchanged"),
               "damaged_or_unreadable": bad, "frames": report.frames, "values": report.values}
    print_summary(
        summary, args.json,
        f"{args.dataset}: {report.count('ingested')} ingested ({report.frames} frames, {report.values} values), "
        f"{report.count('unchanged')} unchanged, {bad} damaged or unreadable",
    )
    return EXIT_OK if report.ok else EXIT_USAGE


def _total_size(inputs: list[Path]) -> int | None:
    from sharedlink.fleet.ingest import find_captures

    try:
        return sum(p.stat().st_size for p in find_captures(inputs))
    except OSError:
        return None


def _check_inputs(inputs: list[Path]) -> None:
    """Every input exists, and a directory holds a capture: an empty input is an error (exit 2),
    not a quiet run that ingests nothing."""
    from sharedlink.fleet.ingest import find_captures  # pyarrow loads only for this command

    for path in inputs:
        if not path.exists():
            raise UsageError(f"{path}: no such file")
        if path.is_dir() and not find_captures([path]):
            raise UsageError(f"{path}: no captures in this directory (*.pcap, *.pcapng, *.cap)")
