"""``sharedlink export``: a capture as CSV, JSON Lines, GeoJSON, KML or MCAP."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedlink.analysis.export import (
    BINARY_FORMATS,
    FORMATS,
    HEADING,
    LAT,
    LON,
    VELOCITY,
    ExportOptions,
    export,
    export_file,
)
from sharedlink.capture.pcapio import is_stdout, refuse_overwrite
from sharedlink.commands import (
    EXIT_OK,
    EXIT_USAGE,
    Progress,
    add_decode_options,
    check_capture,
    decode_options,
    name_list,
)
from sharedlink.errors import UsageError

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
    p.add_argument("capture", type=Path, help="pcap or pcapng file")
    p.add_argument("--format", dest="fmt", choices=FORMATS, default=None,
                   help="output format (default: from the -o file name, else csv)")
    p.add_argument("-o", "--output", type=Path, default=None, help="file to write (default, or -: standard output)")
    p.add_argument("--changes", action="store_true", help="one row per variable change instead of one per frame")
    p.add_argument("--vars", default=None, metavar="NAME,...", help="variables to export (default: all)")
    p.add_argument("--lat", default=LAT, help=f"latitude variable for geojson/kml/mcap (default {LAT})")
    p.add_argument("--lon", default=LON, help=f"longitude variable for geojson/kml/mcap (default {LON})")
    p.add_argument("--heading", default=HEADING, help=f"heading variable (degrees) for mcap (default {HEADING})")
    p.add_argument("--velocity", default=VELOCITY, help=f"speed variable for mcap (default {VELOCITY})")
    add_decode_options(p)
    p.add_argument("--json", action="store_true", help="print a summary as JSON on standard error")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    variables, sync = decode_options(args)
    check_capture(args.capture)
    fmt = args.fmt
    if fmt is None:
        fmt = _SUFFIXES.get(args.output.suffix.lower(), "csv") if args.output is not None else "csv"
    columns = name_list(args.vars)
    if args.output is not None and args.output.is_dir():
        raise UsageError(f"{args.output}: is a directory")
    if fmt in BINARY_FORMATS:
        if args.output is None or is_stdout(args.output):
            raise UsageError(f"--format {fmt} is binary: give the file with -o")
        if args.changes or columns is not None:
            raise UsageError(f"--format {fmt} writes every frame and variable: no --changes or --vars")
    refuse_overwrite(args.output, args.capture)
    opts = ExportOptions(fmt=fmt, changes=args.changes, variables=variables, columns=columns,
                         sync_interval=sync, lat=args.lat, lon=args.lon, heading=args.heading, velocity=args.velocity)
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
        print(json.dumps(summary), file=sys.stderr)
    elif args.output is not None and not is_stdout(args.output):
        what = "points" if fmt in ("geojson", "kml") else "messages" if fmt == "mcap" else "rows"
        n = result.points if what == "points" else result.rows
        print(f"wrote {args.output}: {n} {what} from {result.frames} frames ({fmt})", file=sys.stderr)
    if result.error:
        print(f"sharedlink: error: {result.error} (the {result.frames} frames before it were exported)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK
