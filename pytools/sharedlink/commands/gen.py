"""``sharedlink gen``: write a beacon capture."""

from __future__ import annotations

import argparse
from pathlib import Path

from sharedlink.commands import (
    BAUD,
    BEACON_RECORD_BYTES,
    COUNT,
    FRACTION,
    PORT,
    RATE,
    SECONDS,
    add_force_option,
    add_json_option,
    add_old_spelling,
    add_output_option,
    add_quiet_option,
    check_room,
    format_from_suffix,
    generate_to,
    honours_force,
    number,
    plural,
    refuse_terminal,
    report,
    require_output,
    start_time,
)
from sharedlink.errors import UsageError
from sharedlink.present.formats import count


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "gen",
        help="generate a beacon capture",
        description="Write a capture of SharedLink beacon traffic: a vehicle driving a plausible track, "
        "broadcast over UDP at --rate Hz, with optional compression and faults.",
    )
    add_old_spelling(p, "OUT", "-o OUT", "out", type=Path)
    add_output_option(p, "capture file to write (-: standard output)", dest="out")
    add_force_option(p)
    p.add_argument("--duration", type=SECONDS, default=60.0, help="seconds of traffic (default 60)")
    p.add_argument("--frames", type=COUNT, default=None, help="number of beacon frames (overrides --duration)")
    p.add_argument("--rate", type=RATE, default=5.0, help="frames per second (default 5: every 200 ms)")
    p.add_argument("--compress", action="store_true", help="leave out unchanged values (shared-variable compression)")
    p.add_argument("--sync-interval", type=SECONDS, default=1.0, metavar="S",
                   help="with --compress: full set at least every S seconds (default 1)")
    p.add_argument("--seed", type=int, default=1, help="random seed: the same seed gives the same bytes (default 1)")
    p.add_argument("--format", dest="fmt", choices=("pcap", "pcapng"), default=None, help="file format (default: from the file name, else pcap)")
    p.add_argument("--port", type=PORT, default=None, help="port (default: sharedlink 7013, p2os 8101, blackboard 7100)")
    p.add_argument("--protocol", choices=("sharedlink", "p2os", "blackboard"), default="sharedlink",
                   help="what to generate: SharedLink beacons (default), a P2OS robot session, or a blackboard master/slave session")
    p.add_argument("--transport", choices=("udp", "tcp", "serial"), default=None,
                   help="sharedlink: udp beacons (default) or serial (a BUL-049 point-to-point session); p2os: tcp (default), "
                   "udp or serial; blackboard: udp (default), tcp or serial. Serial captures are pcapng with a USER link type")
    p.add_argument("--baud", type=BAUD, default=9600, help="--transport serial: line speed (default 9600)")
    p.add_argument("--noise", type=FRACTION, default=0.0, metavar="RATE", help="--transport serial: chance of a burst of line noise before a frame")
    p.add_argument("--src", default="B", help="source node letter A-P (default B)")
    p.add_argument("--dst", default="A", help="destination node letter A-P (default A)")
    p.add_argument("--form", choices=("named", "positional"), default="named", help="value form: named T/Q/D triplets (beacon, default) or positional D fields")
    p.add_argument("--bad-checksum", type=FRACTION, default=0.0, metavar="RATE", help="fraction of frames sent with a wrong checksum")
    p.add_argument("--drop", type=FRACTION, default=0.0, metavar="RATE", help="fraction of frames lost")
    p.add_argument("--jitter", type=number(0, 3_600_000, unit="ms"), default=0.0, metavar="MS", help="timing jitter, uniform over +-MS/2 milliseconds")
    p.add_argument("--start", type=start_time(), default=None, metavar="TIME",
                   help="time of the first beacon, UTC ISO 8601 (e.g. 2026-03-02T08:00:00Z; default 2026-01-01T12:00:00Z)")
    p.add_argument("--outage", action="append", default=[], metavar="T:D", type=_outage,
                   help="plant a silence of D seconds T seconds after the start (repeatable): the beacon's direction, "
                   "on --transport serial the vehicle's (its data and replies); --protocol p2os/blackboard: both directions "
                   "(the line cut; a blackboard answer goes with its message)")
    add_json_option(p)
    add_quiet_option(p)
    p.set_defaults(func=run)


#: file name suffixes gen knows, and the format each is written in
_SUFFIXES = {".pcap": "pcap", ".cap": "pcap", ".dmp": "pcap", ".pcapng": "pcapng", ".ntar": "pcapng"}


def _outage(text: str) -> tuple[float, float]:
    """``--outage T:D`` (argparse type: a bad value is a usage error, exit 2)."""
    from sharedlink.generators.outages import parse_outage

    try:
        return parse_outage(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix(f"--outage {text!r}: ")) from None


@honours_force
def run(args: argparse.Namespace) -> int:
    from sharedlink.generators.beacon import (  # (when the command runs: quick start-up)
        GenOptions,
        generate_file,
    )

    require_output(args, "out")
    refuse_terminal(args.out)
    fmt = format_from_suffix(args.out, _SUFFIXES, "pcap", args.fmt)  # (a suffix of no capture format: refused)
    if args.fmt is None and args.transport == "serial":
        fmt = "pcapng"  # serial captures are pcapng
    if args.transport == "serial" and args.protocol == "sharedlink":
        return run_gen_serial(args)
    if args.protocol != "sharedlink":
        return run_session(args, fmt)
    if args.transport not in (None, "udp"):
        raise UsageError("SharedLink beacons are generated over udp")
    if args.port is None:
        args.port = 7013
    opts = GenOptions(
        duration=args.duration,
        frames=args.frames,
        rate=args.rate,
        compress=args.compress,
        sync_interval=args.sync_interval,
        seed=args.seed,
        fmt=fmt,
        port=args.port,
        src=args.src.upper(),
        dst=args.dst.upper(),
        form=args.form,
        bad_checksum=args.bad_checksum,
        drop=args.drop,
        jitter_ms=args.jitter,
        outages=tuple(args.outage),
    )
    if args.start is not None:
        opts.start_ns = args.start
    if args.frames is not None and args.frames <= 0:
        raise UsageError("--frames must be positive")
    frames = args.frames if args.frames is not None else int(args.duration * args.rate)
    check_room(args.out, frames, BEACON_RECORD_BYTES)
    stats = generate_to(opts, generate_file, args.out)
    summary = {
        "file": str(args.out),
        "format": fmt,
        "frames": stats.frames,
        "payload_bytes": stats.bytes,
        "kinds": stats.kinds,
        "dropped": stats.dropped,
        "silenced": stats.silenced,
        "bad_checksums": stats.bad_checksums,
    }
    kinds = ", ".join(f"{count(v)} {k}" for k, v in stats.kinds.items())
    report(
        summary, args.json,
        f"wrote {args.out}: {plural(stats.frames, 'frame')} ({kinds}), {count(stats.bytes)} payload bytes"
        + (f", {count(stats.dropped)} dropped" if stats.dropped else "")
        + (f", {count(stats.silenced)} silenced in {plural(len(args.outage), 'outage')}" if args.outage else "")
        + (f", {stats.bad_checksums} bad checksums" if stats.bad_checksums else ""),
    )
    return 0


def run_session(args: argparse.Namespace, fmt: str) -> int:
    """``--protocol p2os`` / ``blackboard``: a generated client/server session."""
    from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
    from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file

    opts: P2osGenOptions | BlackboardGenOptions
    if args.protocol == "p2os":
        opts = P2osGenOptions(duration=args.duration, seed=args.seed, fmt=fmt, transport=args.transport or "tcp", baud=args.baud,
                              outages=tuple(args.outage))
        if args.port is not None:
            opts.port = args.port
        generate = generate_p2os_file
    else:
        opts = BlackboardGenOptions(
            duration=args.duration, seed=args.seed, fmt=fmt, transport=args.transport or "udp", baud=args.baud,
            outages=tuple(args.outage),
        )
        if args.port is not None:
            opts.port = args.port
        generate = generate_blackboard_file  # type: ignore[assignment]
    if args.start is not None:
        opts.start_ns = args.start
    stats = generate_to(opts, generate, args.out)
    summary = {
        "file": str(args.out),
        "format": fmt,
        "protocol": args.protocol,
        "transport": opts.transport,
        "port": opts.port,
        "frames": stats.frames,
        "payload_bytes": stats.bytes,
        "kinds": stats.kinds,
        "silenced": stats.silenced,
    }
    kinds = ", ".join(f"{v} {k}" for k, v in stats.kinds.items())
    quiet = f", {stats.silenced} silenced in {plural(len(args.outage), 'outage')}" if args.outage else ""
    report(summary, args.json, f"wrote {args.out}: {plural(stats.frames, 'frame')} over {opts.transport} port {opts.port} ({kinds}){quiet}")
    return 0


def run_gen_serial(args: argparse.Namespace) -> int:
    """``sharedlink gen OUT --transport serial``."""
    from sharedlink.generators.serial import SerialGenOptions, generate_serial_file

    if getattr(args, "protocol", "sharedlink") not in (None, "sharedlink"):
        raise UsageError("--transport serial generates SharedLink (BUL-049) sessions only")
    if args.fmt == "pcap":
        raise UsageError("serial captures are pcapng (the direction lives in the packet flags)")
    duration = args.duration if args.frames is None else args.frames / args.rate
    opts = SerialGenOptions(
        duration=duration,
        rate=args.rate,
        baud=args.baud,
        seed=args.seed,
        compress=True,  # a BUL-049 session elides unchanged values (full set every --sync-interval)
        sync_interval=args.sync_interval,
        noise=args.noise,
        host=args.dst.upper(),
        vehicle=args.src.upper(),
        outages=tuple(args.outage),
    )
    if args.start is not None:
        opts.start_ns = args.start
    stats = generate_to(opts, generate_serial_file, args.out)
    summary = {
        "file": str(args.out),
        "format": "pcapng",
        "transport": "serial",
        "frames": stats.frames,
        "records": stats.records,
        "bytes": stats.bytes,
        "noise_bytes": stats.noise_bytes,
        "kinds": stats.kinds,
        "by_direction": stats.by_direction,
    }
    kinds = ", ".join(f"{v} {k}" for k, v in stats.kinds.items())
    report(
        summary, args.json,
        f"wrote {args.out}: {plural(stats.frames, 'frame')} ({kinds}) in {plural(stats.records, 'serial record')} at {opts.baud} baud"
        + (f", {stats.noise_bytes} noise bytes" if stats.noise_bytes else ""),
    )
    return 0
