"""What ``sharedlink compress`` and ``expand`` share: arguments and the run."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from sharedlink.analysis.transform import transform_capture
from sharedlink.capture.stream import parse_variable_list
from sharedlink.commands import EXIT_OK, EXIT_USAGE
from sharedlink.errors import UsageError
from sharedlink.protocols.state import BEACON_VARIABLES


def variables_arg(text: str | None) -> list[tuple[str, int | None]]:
    """The ``--variables`` option of diff, compress and expand."""
    if text is None:
        return list(BEACON_VARIABLES)
    try:
        return parse_variable_list(text)
    except ValueError as exc:
        raise UsageError(f"--variables: {exc}") from None


VARIABLES_HELP = ("the a-priori outbound list positional frames are named by, NAME[:TYPE],... (TYPE 0 long, "
                  "2 double, 4 string; default the beacon's AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2); "
                  "declaration frames in the capture override it")


def add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", type=Path, help="pcap or pcapng capture to read")
    p.add_argument("output", type=Path, help="capture to write (same format as the input)")
    p.add_argument("--variables", metavar="LIST", default=None, help=VARIABLES_HELP)
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


def run_transform(args: argparse.Namespace, mode: str) -> int:
    if not (args.sync_interval > 0 and math.isfinite(args.sync_interval)):
        raise UsageError("--sync-interval must be a positive number of seconds")
    variables = variables_arg(args.variables)
    st = transform_capture(args.input, args.output, mode, args.sync_interval, variables)
    if args.json:
        json.dump({"input": str(args.input), "output": str(args.output), "mode": mode, **st.to_dict()}, sys.stdout)
        print()
    else:
        saving = ""
        if st.saving is not None:
            saving = f" ({st.saving:.1%} smaller)" if st.saving >= 0 else f" ({-st.saving:.1%} larger)"
        print(
            f"wrote {args.output}: {st.records} records, {st.value_frames} value frames "
            f"({st.full} full, {st.delta} delta, {st.copied} copied unchanged), "
            f"SharedLink bytes {st.bytes_in} -> {st.bytes_out}{saving}",
            file=sys.stderr,
        )
    if st.error:
        print(f"sharedlink: error: {st.error} (the records before it were written)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK
