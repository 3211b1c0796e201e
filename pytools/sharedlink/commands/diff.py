"""``sharedlink diff``: do two captures carry the same data?"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sharedlink.commands import (
    EXIT_FAIL,
    EXIT_OK,
    EXIT_USAGE,
    MAX_SECONDS,
    SECONDS,
    STDIN,
    Progress,
    add_json_option,
    add_quiet_option,
    add_variables_option,
    capture_input,
    number,
    variables_option,
    warn_empty,
)
from sharedlink.errors import UsageError
from sharedlink.protocols.codec import TYPE_NAMES

if TYPE_CHECKING:  # (loaded when the command runs: every command's start-up pays for what is imported here)
    from sharedlink.analysis.diff import DiffReport, Divergence, Staleness
    from sharedlink.capture.stream import SideStats


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diff",
        help="compare the shared-variable data of two captures",
        description="Rebuild every variable's value over time in two captures (values carried forward, lists "
        "learnt, positional and named forms alike), align the value frames of each direction (by time within "
        "a window, or by sequence) and compare. Reports frames and bytes of each capture and the saving of B "
        "against A, per variable the samples compared, mismatches, first divergence and worst staleness, full "
        "syncs and missed sync intervals, checksum failures, undecodable data, variables on one side only and "
        "unmatched frames.",
        epilog="Exit codes: 0 the data agree, 1 they diverge, 2 bad usage or a missing/damaged capture (what "
        "comes before the damage is still compared and reported), 130 interrupted.",
    )
    p.add_argument("a", type=Path, help="first capture (pcap or pcapng), e.g. the full stream (-: standard input)")
    p.add_argument("b", type=Path, help="second capture, e.g. the compressed stream")
    p.add_argument("--by", choices=("time", "sequence"), default="time",
                   help="align frames by time within --window (default) or by their order")
    p.add_argument("--window", type=number(0, MAX_SECONDS * 1000, above=True, unit="ms"), default=None, metavar="MS",
                   help="with --by time: frames match when this close, in ms (default half the frame period)")
    p.add_argument("--tolerance", type=number(0), default=0.0, metavar="X",
                   help="doubles within X of each other are equal (default 0: equal as numbers)")
    p.add_argument("--sync-interval", type=SECONDS, default=1.0, metavar="S",
                   help="a full set is due every S seconds: a gap between full sets that rounds to n >= 2 "
                   "intervals misses n - 1 (default 1)")
    add_variables_option(p)
    p.add_argument("--single-process", action="store_true",
                   help="read both captures in this process (default: each in its own)")
    add_json_option(p, "the report")
    add_quiet_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sharedlink.analysis.diff import DiffOptions, diff_captures

    opts = DiffOptions(
        by=args.by,
        window_ms=args.window,
        tolerance=args.tolerance,
        sync_interval=args.sync_interval,
        variables=variables_option(args.variables),
        parallel=not args.single_process,
    )
    try:
        opts.validate()
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if str(args.a) == str(args.b) == "-":
        raise UsageError("-: standard input can be only one of the two captures")
    args.a, args.b = capture_input(args.a), capture_input(args.b)
    if STDIN in (args.a, args.b):
        opts.parallel = False  # a reader process has no standard input of its own
    with Progress([args.a, args.b], quiet=args.json, what="comparing", unit="frames") as progress:
        report = diff_captures(args.a, args.b, opts, progress)
    unreadable = [s.error for s in (report.a, report.b) if s.error and s.records == 0]
    if unreadable:  # not a capture at all: nothing to compare
        raise UsageError("; ".join(unreadable))
    if report.a.frames == report.b.frames == 0 and not report.errors and STDIN not in (args.a, args.b):
        robots = _robot_diff(args)  # P2OS or blackboard captures: compared on their decoded packets
        if robots is not None:
            return robots
    for side in (report.a, report.b):
        if not side.error:
            warn_empty(side.path, side.frames)
    if args.json:
        json.dump(report.to_dict(), sys.stdout, indent=1)
        print()
    elif sys.stdout.isatty():
        print_rich(report)
    else:
        print_plain(report)
    for err in report.errors:
        print(f"sharedlink: error: {err} (the data before it were compared)", file=sys.stderr)
    if report.errors:
        return EXIT_USAGE
    return EXIT_OK if report.agree else EXIT_FAIL


def _robot_diff(args: argparse.Namespace) -> int | None:
    """The P2OS/blackboard comparison (analysis/robot_diff.py), or None when neither capture has any."""
    from sharedlink.analysis.robot_diff import diff_robots, render

    rd = diff_robots(args.a, args.b, args.tolerance)
    if not (rd.packets_a or rd.packets_b):
        return None
    if args.json:
        json.dump(rd.to_dict(), sys.stdout, indent=1)
        print()
    else:
        sys.stdout.write(render(rd))
    for err in rd.errors:
        print(f"sharedlink: error: {err} (the packets before it were compared)", file=sys.stderr)
    if rd.errors:
        return EXIT_USAGE
    return EXIT_OK if rd.agree else EXIT_FAIL


# -- formatting ------------------------------------------------------------------------------


def _saving(x: float | None, what: str, short: bool = False) -> str:
    """B against A: ``saves 26.0% of A's SharedLink bytes``, or when B is larger ``takes 36.9%
    more SharedLink bytes than A`` (never a negative saving)."""
    if x is None:
        return f"{what}: -" if short else f"saves - of A's {what}"
    if x >= 0:
        return f"{x:.1%} of {what}" if short else f"saves {x:.1%} of A's {what}"
    return f"{-x:.1%} more {what}" if short else f"takes {-x:.1%} more {what} than A"


def _rel(ns: int | None, side: SideStats) -> str:
    from sharedlink.present import duration

    if ns is None:
        return "-"
    return duration((ns - (side.start_ns or ns)) / 1e9)


def _value(v: str | None) -> str:
    return "(none)" if v is None else repr(v) if (v == "" or v != v.strip()) else v


def _divergence(d: Divergence | None, r: DiffReport) -> str:
    if d is None:
        return "-"
    return (f"A #{d.a_frame} @{_rel(d.a_time_ns, r.a)} = {_value(d.a_value)}; "
            f"B #{d.b_frame} @{_rel(d.b_time_ns, r.b)} = {_value(d.b_value)}")


def _staleness(s: Staleness | None) -> str:
    from sharedlink.present import duration

    if s is None:
        return "-"
    where = f"A #{s.from_a_frame}/B #{s.from_b_frame}"
    late = f" ({s.late.upper()} late)" if s.late else ""
    if s.to_a_frame is None:
        return f"{duration(s.ms / 1000)} from {where}, never caught up{late}"
    return f"{duration(s.ms / 1000)} from {where} to A #{s.to_a_frame}/B #{s.to_b_frame}{late}"


def _capture_rows(r: DiffReport, split: bool = False) -> list[tuple[str, str, str]]:
    """The captures' figures side by side; ``split``: the value frames on a row of their own
    (narrower columns, for tables)."""
    a, b = r.a, r.b
    frames = [("SharedLink frames", f"{a.frames:,}", f"{b.frames:,}"),
              ("frames with values", f"{a.value_frames:,}", f"{b.value_frames:,}")] if split else [
        ("SharedLink frames (with values)", f"{a.frames:,} ({a.value_frames:,})", f"{b.frames:,} ({b.value_frames:,})")]
    rows = [
        ("file", a.path, b.path),
        ("records", f"{a.records:,}", f"{b.records:,}"),
        *frames,
        ("SharedLink bytes", f"{a.payload_bytes:,}", f"{b.payload_bytes:,}"),
        ("captured bytes", f"{a.wire_bytes:,}", f"{b.wire_bytes:,}"),
        ("full-sync frames", f"{a.full:,}", f"{b.full:,}"),
        ("sync intervals missed", f"{a.sync_missed:,}", f"{b.sync_missed:,}"),
        ("checksum failures", f"{a.checksum_failures:,}", f"{b.checksum_failures:,}"),
        ("undecodable (noise)", f"{a.undecodable:,}", f"{b.undecodable:,}"),
        ("other packets", f"{a.other_packets:,}", f"{b.other_packets:,}"),
        ("unmatched value frames", f"{r.unmatched_a:,}", f"{r.unmatched_b:,}"),
    ]
    return rows


def _summary_lines(r: DiffReport) -> list[str]:
    lines = [
        f"B {_saving(r.saving_payload, 'SharedLink bytes')} ({_saving(r.saving_wire, 'captured bytes', short=True)})",
        f"aligned by {r.by}" + (f" within {r.window_ms:g} ms" if r.by == "time" else "")
        + f": {r.pairs:,} matched value-frame pairs",
    ]
    for side, lst in (("A", r.first_unmatched_a), ("B", r.first_unmatched_b)):
        if lst:
            stats = r.a if side == "A" else r.b
            n = r.unmatched_a if side == "A" else r.unmatched_b
            shown = ", ".join(f"#{u.frame} @{_rel(u.time_ns, stats)} ({u.stream})" for u in lst)
            lines.append(f"unmatched in {side}: {n:,} frames: {shown}" + (", ..." if n > len(lst) else ""))
    for side, vs in (("A", r.only_a), ("B", r.only_b)):
        if vs:
            lines.append(f"only in {side}: " + ", ".join(f"{v.stream} {v.name}" for v in vs))
    return lines


def _verdict(r: DiffReport) -> str:
    if r.errors:
        return "INCOMPLETE: a capture is damaged (see the error below)"
    if r.agree:
        return "AGREE: both captures carry the same data"
    bad = [v for v in r.variables if not v.agree]
    what = []
    if bad:
        what.append(f"{len(bad)} variable(s) differ")
    if r.unmatched_a or r.unmatched_b:
        what.append(f"{r.unmatched_a + r.unmatched_b:,} unmatched frame(s)")
    return "DIVERGE: " + ", ".join(what)


def _tables(r: DiffReport) -> tuple:
    """The captures side by side and the variables, as sharedlink.present tables."""
    from sharedlink.present import COUNT, PROSE, VALUE, Column, Table

    caps = Table("captures", [Column("", PROSE), Column("A", VALUE), Column("B", VALUE)])
    for row in _capture_rows(r, split=True)[1:]:
        caps.add(*row)
    vt = Table("variables", [Column("stream", drop=3), Column("name"), Column("type", drop=0),
                             Column("samples", COUNT), Column("mismatches", COUNT),
                             Column("first divergence", PROSE, drop=2), Column("worst staleness", PROSE, drop=1)],
               more="--json has every column")
    for v in r.variables:
        vt.add(v.stream, v.name if v.present == "both" else f"{v.name} (only {v.present.upper()})",
               TYPE_NAMES.get(v.type, "?") if v.type is not None else "?", v.samples, v.mismatches,
               _divergence(v.first_divergence, r), _staleness(v.worst_staleness), style=None if v.agree else "red")
    return caps, vt


def print_plain(r: DiffReport) -> None:
    from sharedlink.present import plain

    print(f"A: {r.a.path}\nB: {r.b.path}")
    caps, _ = _tables(r)
    caps.title = ""
    print(plain(caps))
    for line in _summary_lines(r):
        print(line)
    print()
    print("variables:")
    for v in r.variables:
        t = TYPE_NAMES.get(v.type, "?") if v.type is not None else "?"
        where = "" if v.present == "both" else f" (only in {v.present.upper()})"
        print(f"  {v.stream} {v.name} [{t}]{where}: {v.samples:,} samples, {v.mismatches:,} mismatches")
        if v.first_divergence is not None:
            print(f"    first divergence: {_divergence(v.first_divergence, r)}")
        if v.worst_staleness is not None:
            print(f"    worst staleness: {_staleness(v.worst_staleness)}")
    print()
    print(_verdict(r))


def print_rich(r: DiffReport) -> None:
    from rich.console import Console

    from sharedlink.present import print_fitted

    con = Console()
    caps, vt = _tables(r)
    con.print(f"A: {r.a.path}\nB: {r.b.path}", highlight=False)  # paths wrap as text, outside the table
    print_fitted(con, caps)
    for line in _summary_lines(r):
        con.print(line, highlight=False)
    print_fitted(con, vt)
    con.print(_verdict(r), style="bold green" if r.agree else "bold red", highlight=False)
