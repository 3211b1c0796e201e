"""``sharedlink export``: a capture as CSV, JSON Lines, GeoJSON, KML or MCAP."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedlink.capture.pcapio import is_stdout, refuse_overwrite
from sharedlink.commands import (
    EXIT_OK,
    EXIT_USAGE,
    Progress,
    add_decode_options,
    add_force_option,
    add_json_option,
    add_location_options,
    add_outage_after_option,
    add_output_option,
    add_quiet_option,
    add_select_option,
    capture_input,
    decode_options,
    deprecated,
    format_from_suffix,
    given_names,
    honours_force,
    name_list,
    note,
    plural,
    warn_empty,
)
from sharedlink.defaults import EXPORT_BINARY_FORMATS as BINARY_FORMATS
from sharedlink.defaults import EXPORT_FORMATS as FORMATS
from sharedlink.errors import UsageError
from sharedlink.extras import require

_SUFFIXES = {".csv": "csv", ".jsonl": "jsonl", ".ndjson": "jsonl", ".geojson": "geojson", ".kml": "kml", ".mcap": "mcap"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="export frames or value changes as csv, jsonl, geojson, kml or mcap",
        description="One row per SharedLink frame (every variable's value after it, timestamps, kind, checksum), "
        "or one per variable change with --changes. GeoJSON and KML hold the GPS track(s) for map tools; "
        "MCAP holds LocationFix, values and frames channels per direction (and P2OS poses, commands and "
        "blackboard messages) for Foxglove and PlotJuggler. "
        "Streams: any size of capture.",
    )
    p.add_argument("capture", type=Path, help="pcap or pcapng file (-: standard input)")
    p.add_argument("--format", dest="fmt", choices=FORMATS, default=None,
                   help="output format (default: from the -o file name, else csv)")
    add_output_option(p, "file to write (default, or -: standard output)")
    add_force_option(p)
    p.add_argument("--changes", action="store_true", help="one row per variable change instead of one per frame")
    add_select_option(p, "variables to export (default: all)")
    add_location_options(p, "geojson/kml (and mcap)")
    add_decode_options(p)
    p.add_argument("--outages", action="store_true",
                   help="jsonl, csv: each outage of a link as a row of its own (kind: outage) before the frame that ends it "
                   "(csv: a duration_s column after checksum)")
    add_outage_after_option(p)
    add_json_option(p)
    add_quiet_option(p)
    p.set_defaults(func=run)


@honours_force
def run(args: argparse.Namespace) -> int:
    from sharedlink.analysis.export import (  # (when the command runs: quick start-up)
        ExportOptions,
        export,
        export_file,
    )

    variables, sync = decode_options(args)
    args.capture = capture_input(args.capture)
    given = given_names(args)
    fmt = args.fmt
    if fmt is None:
        fmt = format_from_suffix(args.output, _SUFFIXES, "csv", None)
    columns = name_list(args.select)
    _check_options(args, fmt, columns)
    refuse_overwrite(args.output, args.capture)
    opts = ExportOptions(fmt=fmt, changes=args.changes, variables=variables, columns=columns, sync_interval=sync,
                         lat=args.lat, lon=args.lon, heading=args.heading, velocity=args.velocity,
                         require=_required(fmt, columns, given), outages=args.outages,
                         outage_after=args.outage_after)
    to_stdout = args.output is None or is_stdout(args.output)
    try:
        with Progress(args.capture, quiet=args.json or to_stdout, what="exporting") as progress:
            opts.progress = progress
            if to_stdout:
                result = export(args.capture, sys.stdout, opts)
            else:
                result = export_file(args.capture, args.output, opts)
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise UsageError(f"{args.output}: {exc.strerror or exc}") from None
    summary = {"capture": str(args.capture), "output": str(args.output or "-"), "format": fmt,
               "frames": result.frames, "rows": result.rows, "points": result.points, "error": result.error}
    if args.json:
        to_stdout = args.output is None or is_stdout(args.output)
        if to_stdout:  # the export itself is on standard output
            deprecated("export --json with the export on standard output (the summary on standard error)",
                       "-o FILE with --json (the summary on standard output)")
        print(json.dumps(summary), file=sys.stderr if to_stdout else sys.stdout)
    elif args.output is not None and not is_stdout(args.output):
        what = "point" if fmt in ("geojson", "kml") else "message" if fmt == "mcap" else "row"
        n = result.points if what == "point" else result.rows
        source = plural(result.frames, 'frame')
        if result.packets:
            source += f", {plural(result.packets, 'P2OS/blackboard packet')}"
        note(f"wrote {args.output}: {plural(n, what)} from {source} ({fmt})")
    if result.robot_rows_left_out:  # a mixed capture's CSV keeps SharedLink's columns
        print(f"sharedlink: warning: {args.capture}: {plural(result.robot_rows_left_out, 'P2OS/blackboard packet')} "
              "left out of the CSV (it has SharedLink's columns, the capture SharedLink frames too): --format jsonl "
              "writes both, in capture order", file=sys.stderr)
    if fmt != "mcap" and not result.error:  # MCAP holds P2OS and blackboard channels too
        warn_empty(args.capture, result.frames + result.packets)  # (robot packets: no warning)
    if result.error:
        print(f"sharedlink: error: {result.error} (the {result.frames} frames before it were exported)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK


def _check_options(args: argparse.Namespace, fmt: str, columns: list[str] | None) -> None:
    """UsageError for options the format cannot take (or an output that is a directory); the
    foxglove extra required for mcap."""
    if args.output is not None and args.output.is_dir():
        raise UsageError(f"{args.output}: is a directory")
    if fmt in BINARY_FORMATS:
        if args.output is None or is_stdout(args.output):
            raise UsageError(f"--format {fmt} is binary: give the file with -o")
        if args.changes or columns is not None:
            raise UsageError(f"--format {fmt} writes every frame and variable: no --changes or --select")
    if args.outages and (fmt not in ("jsonl", "csv") or (fmt == "csv" and args.changes)):
        raise UsageError(f"--outages: outage rows are written in --format jsonl or csv (csv: not with --changes), not {fmt}"
                         + (" --changes" if args.changes else ""))
    if fmt == "mcap":
        require("foxglove", "sharedlink export --format mcap")


def _required(fmt: str, columns: list[str] | None, given: dict[str, list[str]]) -> list[str]:
    """The names the capture must carry: the ``--select``ed ones, and the location options given
    for a track (geojson, kml: --lat, --lon; mcap's LocationFix: --heading and --velocity too)."""
    names = list(columns or [])
    if fmt in ("geojson", "kml"):
        names += [n for opt in ("--lat", "--lon") for n in given.get(opt, [])]
    elif fmt == "mcap":
        names += [n for opt in ("--lat", "--lon", "--heading", "--velocity") for n in given.get(opt, [])]
    return names
