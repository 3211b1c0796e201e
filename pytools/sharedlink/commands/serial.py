"""``sharedlink serial``: capture a serial line into pcapng, import serial logs, list ports."""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

from sharedlink.capture.pcapio import DeferredOutput, buffered_stdout, open_output, refuse_overwrite
from sharedlink.commands import (
    BAUD,
    COUNT,
    EXIT_USAGE,
    SECONDS,
    add_force_option,
    add_json_option,
    add_old_spelling,
    add_output_option,
    add_quiet_option,
    capture_input,
    honours_force,
    note,
    number,
    plural,
    refuse_terminal,
    report,
    require_output,
    start_time,
)
from sharedlink.defaults import SERIAL_DIRECTIONS as _DIRECTIONS
from sharedlink.defaults import SERIAL_LOG_FORMATS as FORMATS
from sharedlink.defaults import SERIAL_MAX_LOG_NS as MAX_LOG_NS
from sharedlink.defaults import SERIAL_PROTOCOLS as PROTOCOLS
from sharedlink.errors import Error, UsageError

if TYPE_CHECKING:  # (loaded when the command runs: every command's start-up pays for what is imported here)
    from sharedlink.capture.serial_import import SerialImportError


def _linktype(text: str) -> int:
    from sharedlink.capture.serial_format import parse_linktype

    try:
        return parse_linktype(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serial",
        help="capture a serial line, import serial logs",
        description="Serial links in pcapng (USER link type, one record per chunk, direction in the "
        "packet flags): see docs/serial-capture-format.md.",
    )
    ss = p.add_subparsers(dest="serial_command", metavar="SUBCOMMAND")
    ss.required = True

    c = ss.add_parser(
        "capture",
        help="record a live serial port (or tap between two)",
        description="Read DEVICE and write each chunk as it arrives (inbound), or with --tap A B relay "
        "between two ports recording both directions (bytes from A inbound, from B outbound). "
        "Ctrl-C or SIGTERM ends the capture; every record is flushed as written.",
    )
    c.add_argument("device", nargs="?", help="serial port, e.g. /dev/ttyUSB0 (not with --tap)")
    c.add_argument("--baud", type=BAUD, default=9600, help="line speed, bits per second (default 9600)")
    add_output_option(c, "capture file to write (default, or -: standard output)", dest="out", default="-")
    add_old_spelling(c, "--out", "-o/--output", "out", type=Path, metavar="FILE")
    add_force_option(c)
    c.add_argument("--tap", nargs=2, metavar=("DEV_A", "DEV_B"), help="relay between two ports, recording both directions")
    c.add_argument("--linktype", type=_linktype, default=147, help="USER link type: 147..162 or user0..user15 (default user0)")
    c.add_argument("--duration", type=SECONDS, default=None, help="stop after S seconds")
    c.add_argument("--count", type=COUNT, default=None, metavar="N", help="stop after N records")
    add_json_option(c)
    add_quiet_option(c)
    c.set_defaults(func=run_capture)

    i = ss.add_parser(
        "import",
        help="convert a serial log (raw, hex dump, timestamped text) into a capture",
        description="Convert a raw binary dump, a hex dump (xxd, hexdump -C, od) or a text log with "
        "timestamps into a serial capture.",
    )
    i.add_argument("log", type=Path, help="the log file")
    add_output_option(i, "capture file to write (pcapng; -: standard output)", dest="out")
    add_old_spelling(i, "--out", "-o/--output", "out", type=Path, metavar="FILE")
    add_force_option(i)
    i.add_argument("--log-format", dest="fmt", choices=FORMATS, default="auto", help="the log's format (default: detected)")
    add_old_spelling(i, "--format", "--log-format (--format is an output format elsewhere)", "fmt", choices=FORMATS)
    i.add_argument("--frame", action="store_true", help="one record per decoded frame (and per noise run) instead of per chunk")
    i.add_argument("--protocol", choices=("auto",) + PROTOCOLS, default="auto", help="with --frame: the protocol (default: detected)")
    i.add_argument("--baud", type=BAUD, default=9600, help="raw and hex dumps: line speed for the timestamps (default 9600)")
    i.add_argument("--chunk", type=number(1, 1 << 24, integer=True), default=64, help="raw and hex dumps: bytes per record (default 64)")
    i.add_argument("--direction", choices=sorted(_DIRECTIONS), default="in", help="raw and hex dumps: direction of the bytes (default in)")
    i.add_argument("--start", type=start_time(MAX_LOG_NS), default=None, metavar="TIME",
                   help="raw and hex dumps: time of the first byte, UTC ISO 8601 (e.g. 2026-03-02T08:00:00Z; default: the "
                   "file's modification time)")
    i.add_argument("--linktype", type=_linktype, default=147, help="USER link type (default user0 = 147)")
    add_json_option(i)
    add_quiet_option(i)
    i.set_defaults(func=run_import)

    ls = ss.add_parser("ports", help="list the machine's serial ports")
    add_json_option(ls, "the ports")
    ls.set_defaults(func=run_ports)


@honours_force
def run_capture(args: argparse.Namespace) -> int:
    from sharedlink.capture.serial_format import SerialCaptureWriter
    from sharedlink.capture.serial_port import capture, port_error

    if args.tap and args.device:
        raise UsageError("give either DEVICE or --tap DEV_A DEV_B, not both")
    if not args.tap and not args.device:
        raise UsageError("no serial device: give DEVICE or --tap DEV_A DEV_B")
    if args.baud <= 0:
        raise UsageError("--baud must be positive")
    if args.count is not None and args.count <= 0:
        raise UsageError("--count must be positive")
    to_stdout = str(args.out) == "-"
    refuse_terminal(args.out, "a serial capture")
    if to_stdout and args.json:
        raise UsageError("--json needs -o FILE (the capture goes to standard output)")
    name = f"{args.tap[0]}<->{args.tap[1]}" if args.tap else args.device
    with ExitStack() as files:
        # standard output buffered even under python -u: a record cut by SIGINT is written whole;
        # a file is opened only once the ports are: a capture that cannot start leaves it as it was
        deferred = None if to_stdout else files.enter_context(DeferredOutput(args.out))
        fh: BinaryIO = files.enter_context(buffered_stdout()) if deferred is None else deferred  # type: ignore[assignment]
        w = SerialCaptureWriter(fh, args.linktype, if_name=name, if_description=f"serial {'tap ' if args.tap else ''}at {args.baud} baud")

        def ready() -> None:
            if deferred is not None:
                deferred.open()
            note(f"capturing {name} at {args.baud} baud into {args.out} (Ctrl-C to stop)")

        try:
            stats = capture(w, args.device, args.baud, tuple(args.tap) if args.tap else None, args.duration, args.count,
                            on_ready=ready)
        except Exception as exc:  # serial.SerialException / OSError opening or configuring a port
            if isinstance(exc, (KeyboardInterrupt, BrokenPipeError, Error)):
                raise
            raise UsageError(port_error(name, exc)) from None
    summary = {
        "file": str(args.out),
        "records": stats.records,
        "bytes": stats.bytes,
        "by_direction": stats.by_direction,
        "stopped_by": stats.stopped_by,
    }
    report(summary, args.json, f"wrote {args.out}: {plural(stats.records, 'record')}, {plural(stats.bytes, 'byte')} (stopped: {stats.stopped_by or 'end'})")
    return 0


@honours_force
def run_import(args: argparse.Namespace) -> int:
    from sharedlink.capture.serial_format import SerialCaptureWriter, StreamReader
    from sharedlink.capture.serial_import import SerialImportError, read_log

    require_output(args, "out")
    refuse_terminal(args.out, "a serial capture")
    args.log = capture_input(args.log)  # one wording for a missing file; -: standard input
    start_ns = args.start
    if args.baud <= 0:
        raise UsageError("--baud must be positive")
    refuse_overwrite(args.out, args.log)
    damage: SerialImportError | None = None
    try:
        fmt, chunks = read_log(args.log, args.fmt, args.baud, args.chunk, _DIRECTIONS[args.direction], start_ns)
    except SerialImportError as exc:
        if not exc.partial:
            raise
        fmt, chunks, damage = "log", exc.partial, exc  # the lines before the bad one are written
    if not chunks:
        raise UsageError(f"{args.log}: no bytes to import")
    records = frames = 0
    with open_output(args.out, inputs=(args.log,)) as fh:
        w = SerialCaptureWriter(fh, args.linktype, if_name=str(args.log), if_description=f"imported {fmt} log", flush=False)
        if args.frame:
            reader = StreamReader(args.protocol)
            for c in chunks:
                for p in reader.feed(c.direction, c.data):
                    w.write(p.data, c.direction, c.ts_ns)
                    frames += p.is_frame
            last = chunks[-1].ts_ns
            for d, p in reader.flush():
                w.write(p.data, d, last)
                frames += p.is_frame
        else:
            for c in chunks:
                w.write(c.data, c.direction, c.ts_ns)
        records = w.records
    summary = {"file": str(args.out), "format": fmt, "records": records, "bytes": sum(len(c.data) for c in chunks)}
    if args.frame:
        summary["frames"] = frames
    log = "the log" if fmt == "log" else f"a {fmt} log"  # "log": the damaged one, its format unsaid
    report(summary, args.json, f"wrote {args.out}: {plural(records, 'record')} from {log}"
           + (f" ({plural(frames, 'frame')})" if args.frame else ""))
    if damage is not None:
        print(f"sharedlink: error: {damage} (the lines before it were written)", file=sys.stderr)
        return EXIT_USAGE
    return 0


def run_ports(args: argparse.Namespace) -> int:
    from sharedlink.capture.serial_port import list_ports

    ports = list_ports()
    if args.json:
        json.dump([{"device": d, "description": desc} for d, desc in ports], sys.stdout)
        print()
    else:
        for d, desc in ports:
            print(f"{d}\t{desc}")
    return 0
