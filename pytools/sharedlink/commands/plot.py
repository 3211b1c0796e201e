"""``sharedlink plot``: the GPS track and the variables over time, as an image."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedlink.capture.pcapio import open_output, refuse_overwrite
from sharedlink.commands import (
    EXIT_OK,
    EXIT_USAGE,
    Progress,
    add_decode_options,
    add_force_option,
    add_json_option,
    add_location_options,
    add_old_spelling,
    add_output_option,
    add_quiet_option,
    add_select_option,
    capture_input,
    decode_options,
    given_names,
    honours_force,
    name_list,
    number,
    plural,
    unknown_names,
    warn_empty,
)
from sharedlink.errors import UsageError
from sharedlink.extras import require


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "plot",
        help="plot the GPS track and the variables over time",
        description="Draw the vehicle's track (latitude/longitude coloured by speed, start and end, dropped frames "
        "and bad checksums marked) and each variable over time in panels below, on a clock-time axis (UTC), "
        "with dropped frames and bad checksums counted per time bin in a strip at the bottom. Long captures are "
        "thinned: every marker up to a few hundred, an even sample beyond.",
    )
    p.add_argument("capture", type=Path, help="pcap or pcapng file (-: standard input)")
    add_output_option(p, "image to write (.png, .svg or .pdf)", required=True)
    add_force_option(p)
    add_select_option(p, "variables to plot below the track (default: all numeric)")
    add_location_options(p, "the track, coloured by the speed", names=("lat", "lon", "velocity"))
    add_old_spelling(p, "--speed", "--velocity (--speed is a time factor in replay and watch)", "velocity")
    p.add_argument("--elapsed", action="store_true",
                   help="time since the first frame on the time axis (default: clock time, UTC)")
    p.add_argument("--max-points", type=number(10, 1e9, integer=True), default=5000, help="points kept per series (default 5000)")
    add_decode_options(p)
    add_json_option(p)
    add_quiet_option(p)
    p.set_defaults(func=run)


@honours_force
def run(args: argparse.Namespace) -> int:
    variables, sync = decode_options(args)
    args.capture = capture_input(args.capture)
    given = given_names(args)
    if args.output.suffix.lower() not in (".png", ".svg", ".pdf"):
        raise UsageError(f"{args.output}: give a .png, .svg or .pdf file name")
    refuse_overwrite(args.output, args.capture)
    if args.max_points < 10:
        raise UsageError("--max-points must be at least 10")
    names = name_list(args.select)
    require("plot", "sharedlink plot")
    import matplotlib

    matplotlib.use("Agg")  # headless, whatever the environment says
    from sharedlink.analysis.plot import build_figure, collect

    with Progress(args.capture, quiet=args.json, what="plotting") as progress:
        data = collect(args.capture, variables, sync, max_points=args.max_points,
                       lat=args.lat, lon=args.lon, speed=args.velocity, progress=progress)
    robots = data.frames == 0 and data.robots.packets > 0  # a P2OS or blackboard capture: its panels
    if data.error is None:
        warn_empty(args.capture, data.frames + data.robots.packets)  # (robot packets: no warning)
        if not robots:
            unknown_names({k: v for k, v in given.items() if k != "--select"}, data.variables)
    try:
        if robots:
            from sharedlink.analysis.robot_plot import build_robot_figure

            fig = build_robot_figure(data.robots, args.capture.name)
        else:
            fig = build_figure(data, names, elapsed=args.elapsed)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    with open_output(args.output) as fh:  # complete or not at all, even on a full disk
        fig.savefig(fh, format=args.output.suffix.lower()[1:])
    panels = len(names) if names is not None else len(data.variables)
    summary = {"capture": str(args.capture), "output": str(args.output), "frames": data.frames,
               "variables": names if names is not None else data.variables, "panels": 1 + panels,
               "gaps": data.gaps, "dropped_frames": data.dropped_frames, "checksum_failures": data.checksum_failures,
               "error": data.error}
    if robots:
        summary.update(panels=len(fig.axes), packets=data.robots.packets, checksum_failures=data.robots.bad, variables=[])
    if args.json:
        print(json.dumps(summary))
    elif robots:
        print(f"wrote {args.output}: P2OS/blackboard panels from {plural(data.robots.packets, 'packet')}", file=sys.stderr)
    else:
        print(f"wrote {args.output}: track and {plural(panels, 'variable panel')} from {plural(data.frames, 'frame')}",
              file=sys.stderr)
    if data.error:
        print(f"sharedlink: error: {data.error} (the {data.frames} frames before it are plotted)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK
