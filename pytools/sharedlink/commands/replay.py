"""``sharedlink replay``: put a capture's frames back on the network or a serial line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sharedlink.capture.pcapio import CaptureError, rereadable
from sharedlink.commands import (
    BAUD,
    COUNT,
    EXIT_FAIL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_TERMINATED,
    EXIT_USAGE,
    PORT,
    SECONDS_OR_ZERO,
    add_json_option,
    add_old_spelling,
    add_quiet_option,
    add_speed_option,
    capture_input,
    number,
)
from sharedlink.defaults import MAX_PPS, MIN_PPS, SERIAL_DIRECTIONS
from sharedlink.errors import UsageError

if TYPE_CHECKING:  # (sharedlink.replay loads when the command runs: every command's start-up pays for what is imported here)
    from sharedlink.replay import ReplayStats, SerialSink, UdpSink
    from sharedlink.replay_tcp import TcpSink


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help="send a capture's frames over UDP or a serial line, with the capture's timing",
        description="Send the payloads of a pcap/pcapng capture (its UDP payloads; records on a USER "
        "link type 147-162 as raw serial bytes) through an ordinary UDP socket, no root needed, or to a serial "
        "port. A capture whose payloads are TCP (a P2OS robot on TCP 8101, blackboard over TCP) is replayed over TCP, "
        "--side client by default: one TCP connection to --to HOST[:PORT] (default 127.0.0.1 on the captured server "
        "port) carrying the client-to-server segments; --side server plays the robot: it listens on --bind ADDR[:PORT] "
        "(default 127.0.0.1 on the captured server port) and sends the server's segments to the client that connects; "
        "--side both plays the whole conversation over loopback (a listener on --to and a connection to it). "
        "Timing follows the capture against absolute deadlines (no drift), or --speed/--pps/--topspeed.",
        epilog="Exit codes: 0 every frame sent, 1 some frames could not be sent (send errors), 2 bad usage or a "
        "missing/damaged capture (the frames before the damage are still sent), 130 interrupted (Ctrl-C; the "
        "summary is still printed).",
    )
    p.add_argument("capture", type=Path, help="pcap or pcapng file (-: standard input)")
    dest = p.add_argument_group("destination")
    dest.add_argument("--to", metavar="HOST[:PORT]", default=None,
                      help="destination (default 127.0.0.1, on the port each frame had in the capture; a TCP capture: "
                      "the server to connect to, default its captured server port)")
    dest.add_argument("--broadcast", action="store_true", help="allow a broadcast destination (sets SO_BROADCAST)")
    dest.add_argument("--multicast", action="store_true", help="allow a multicast group as the destination")
    dest.add_argument("--bind", metavar="ADDR", default=None, help="source address (ADDR or ADDR:PORT) or interface name")
    dest.add_argument("--side", choices=("client", "server", "both"), default=None,
                      help="a TCP capture: the side to play (default client: connect to --to and send the client's "
                      "segments; server: listen on --bind, default 127.0.0.1 on the captured server port, and send the "
                      "server's segments, a robot's SIPs, to the client that connects; both: the conversation over a "
                      "listener on --to and a connection to it)")
    dest.add_argument("--serial", metavar="DEVICE", default=None, help="write the bytes to this serial port or pty instead")
    dest.add_argument("--baud", type=BAUD, default=9600, help="with --serial: baud rate (default 9600)")
    dest.add_argument("--direction", choices=sorted(SERIAL_DIRECTIONS), default=None,
                      help="serial captures: replay only the records of this direction (in: inbound, from the tap's "
                      "DEV_A; out: outbound, from DEV_B); needed with --serial when the capture holds both")
    timing = p.add_argument_group("timing")
    pace = timing.add_mutually_exclusive_group()
    add_speed_option(pace, "capture timing times X (2 = twice as fast; default 1)")
    pace.add_argument("--pps", type=number(MIN_PPS, MAX_PPS, unit="frames per second (a period of 1 ns to 1e7 s)"),
                      default=None, metavar="N", help="a steady N frames per second instead")
    pace.add_argument("--topspeed", action="store_true", help="as fast as possible")
    timing.add_argument("--loop", type=number(0, 1e12, integer=True), default=1, metavar="N", help="passes over the capture (0 = until stopped; default 1)")
    timing.add_argument("--loop-delay", type=SECONDS_OR_ZERO, default=0.0, metavar="S",
                        help="extra pause between passes in seconds (timed passes are also one frame gap apart)")
    timing.add_argument("--count", dest="limit", type=COUNT, default=None, metavar="N", help="stop after N frames")
    add_old_spelling(timing, "--limit", "--count", "limit", type=COUNT, metavar="N")
    timing.add_argument("--realtime", action="store_true",
                        help="pace at real-time priority (SCHED_FIFO) for steadier timing on a busy machine; needs root, "
                        "CAP_SYS_NICE or an RLIMIT_RTPRIO, else a warning and ordinary scheduling")
    sel = p.add_argument_group("selection")
    sel.add_argument("--filter-port", type=PORT, action="append", default=[], metavar="PORT",
                     help="only frames from or to this UDP port (repeatable)")
    sel.add_argument("--filter-src", action="append", default=[], metavar="ADDR",
                     help="only frames from this source address or network, e.g. 192.168.1.12 or 10.0.0.0/8 (repeatable)")
    out = p.add_argument_group("output")
    add_quiet_option(out)
    add_json_option(out)
    p.set_defaults(func=run)


def _check_direction(args: argparse.Namespace) -> None:
    """A serial capture holding both directions goes into one port only one direction at a
    time: ``--direction in|out`` (as serial import names them) is required then."""
    from sharedlink.capture.pcapio import read_records
    from sharedlink.replay import USER_LINKTYPES

    if args.direction is not None:
        return
    seen: dict[int, int] = {}
    try:
        for rec in read_records(args.capture):
            if rec.linktype in USER_LINKTYPES:
                seen[rec.flags & 3] = seen.get(rec.flags & 3, 0) + 1
    except CaptureError:
        pass  # reported by the replay itself, after the good frames
    if seen.get(1) and seen.get(2):
        raise UsageError(f"{args.source} holds both directions of a serial line ({seen[1]} inbound, {seen[2]} outbound "
                         "records): give --direction in or --direction out, one port takes one direction")


def _sink(args: argparse.Namespace) -> UdpSink | SerialSink | TcpSink:
    from sharedlink.replay import USER_LINKTYPES, SerialSink, UdpSink, first_linktype, split_host_port

    if args.serial:
        if args.to or args.bind or args.broadcast or args.multicast:
            raise UsageError("--serial writes to a serial port: --to, --bind, --broadcast and --multicast do not apply")
        if args.baud <= 0:
            raise UsageError("--baud must be positive")
        _check_direction(args)
        return SerialSink(args.serial, args.baud)
    host, port = split_host_port(args.to) if args.to else ("127.0.0.1", None)
    if args.tcp_port is not None:  # a TCP capture: a side of it (or both) over TCP
        return _tcp_sink(args, host, port)
    if args.side is not None:
        raise UsageError(f"--side: {args.source} is not a TCP capture (its UDP payloads or serial records are sent as "
                         "they are)")
    if port is None:
        try:
            lt = first_linktype(args.capture)
        except CaptureError:
            lt = None  # reported by the replay itself, after the good frames
        if lt in USER_LINKTYPES:
            raise UsageError(
                f"{args.source} holds serial records (link type {lt}), which have no UDP port: "
                "give one with --to HOST:PORT, or write them to a serial port with --serial"
            )
    return UdpSink(host, port, bind=args.bind, broadcast=args.broadcast, multicast=args.multicast)


def _tcp_sink(args: argparse.Namespace, host: str, port: int | None) -> Any:
    """The sink of a TCP capture's ``--side`` (replay_tcp.py)."""
    from sharedlink.replay import split_host_port
    from sharedlink.replay_tcp import TcpPairSink, TcpServerSink, TcpSink

    if args.broadcast or args.multicast:
        raise UsageError(f"{args.source} is a TCP capture, replayed over TCP: --broadcast and --multicast do not apply")
    side = args.side or "client"
    if side == "client":
        return TcpSink(host, port or args.tcp_port, bind=args.bind)
    if side == "both":
        return TcpPairSink(host, port or args.tcp_port, args.tcp_port, bind=args.bind)
    if args.to:
        raise UsageError("--side server listens for a client: give its address with --bind ADDR[:PORT], not --to")
    bhost, bport = split_host_port(args.bind, "--bind") if args.bind else ("127.0.0.1", None)
    return TcpServerSink(bhost, args.tcp_port if bport is None else bport,
                         announce=lambda text: print(f"sharedlink replay: {text}", file=sys.stderr, flush=True))


def run(args: argparse.Namespace) -> int:
    args.source = args.capture  # what messages name
    args.capture = capture_input(args.capture)
    with rereadable(args.capture) as args.capture:  # a pipe is read once, then replayed from a copy
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from sharedlink.replay import CaptureFrames, FrameFilter, Replayer, ReplayOptions

    opts = ReplayOptions(
        speed=args.speed,
        pps=args.pps,
        topspeed=args.topspeed,
        loop=args.loop,
        loop_delay=args.loop_delay,
        limit=args.limit,
        realtime=args.realtime,
    )
    opts.validate()
    flt = FrameFilter.build(args.filter_port, args.filter_src)
    args.tcp_port = None
    if not args.serial:
        from sharedlink.replay_tcp import tcp_server_port

        args.tcp_port = tcp_server_port(args.capture)
    sink = _sink(args)
    progress = None if args.quiet else _Progress(args.source.name, sink.description, opts.mode)
    try:
        def long_wait(record: int, seconds: float) -> None:
            print(f"\nsharedlink: warning: {args.source}: record {record} comes {_duration(seconds)} later in the capture"
                  f"{'' if opts.speed == 1 else f' (at {opts.speed:g}x)'}: waiting for it (Ctrl-C stops; --pps N or "
                  "--topspeed play without the capture's gaps)", file=sys.stderr, flush=True)

        direction = None if args.direction is None else SERIAL_DIRECTIONS[args.direction]
        frames: Any = CaptureFrames(args.capture, flt, direction)
        if args.tcp_port is not None:
            from sharedlink.replay_tcp import TcpFrames

            frames = TcpFrames(args.capture, args.tcp_port, flt, args.side or "client")
        replayer = Replayer(frames, sink, opts, progress=progress,
                            progress_interval=progress.interval if progress else 1.0, long_wait=long_wait)
        stats = replayer.run()
    finally:
        if progress is not None:
            progress.close()
        sink.close()
    summary: dict[str, Any] = {"file": str(args.source), "destination": sink.description, "mode": opts.mode}
    summary.update(stats.as_dict())
    if args.json:
        json.dump(summary, sys.stdout)
        print()
    elif not args.quiet:
        print(_summary_text(stats, _WHAT_SKIPPED[args.tcp_port is not None]), file=sys.stderr)
    if stats.attempted == 0 and not stats.capture_error and not stats.interrupted:
        c = stats.counts
        print(f"sharedlink: warning: nothing to replay in {args.source}: {c.records} records, {c.skipped} without "
              f"{_WHAT_SKIPPED[args.tcp_port is not None]}, {c.filtered} left out by the filter", file=sys.stderr)
    if stats.flat_times:
        print(f"sharedlink: warning: {args.source}: the capture's times do not advance ({stats.flat_times} frames at one "
              "time): they were sent back to back, at full speed; give --pps N for a steady rate", file=sys.stderr)
    if args.realtime and not stats.realtime and not args.topspeed:
        print("sharedlink: warning: --realtime: real-time scheduling not permitted (needs root, CAP_SYS_NICE or "
              "an RLIMIT_RTPRIO); paced with ordinary scheduling", file=sys.stderr)
    if stats.capture_error:
        print(f"sharedlink: error: {stats.capture_error}"
              + (f" (the {stats.frames} frames before it were sent)" if stats.frames else ""), file=sys.stderr)
    if stats.send_errors and not args.json and args.quiet:
        print(f"sharedlink: {stats.send_errors} frames could not be sent (first: {stats.first_error})", file=sys.stderr)
    if stats.interrupted:
        return EXIT_TERMINATED if stats.terminated else EXIT_INTERRUPTED
    if stats.capture_error:
        return EXIT_USAGE
    return EXIT_FAIL if stats.send_errors else EXIT_OK


def _ms(ns: int | None) -> str:
    return "-" if ns is None else f"{ns / 1e6:.3f} ms"


#: what a skipped record lacks: a UDP capture's, a TCP capture's (a record with no new bytes of the side played)
_WHAT_SKIPPED = {False: "a UDP payload", True: "new bytes of the side played"}


def _summary_text(st: ReplayStats, skipped: str = _WHAT_SKIPPED[False]) -> str:
    lines = [
        f"{'stopped' if st.interrupted else 'sent'}: {st.frames:,} frames, {st.bytes:,} bytes in {st.elapsed_s:.3f} s "
        f"({st.rate_fps:,.1f} frames/s, {st.rate_bps:,.0f} bytes/s), {st.passes} pass{'es' if st.passes != 1 else ''}",
    ]
    if st.lag_median_ns is not None:
        lines.append(f"lag behind schedule: median {_ms(st.lag_median_ns)}, max {_ms(st.lag_max_ns)}; cpu {st.cpu_s:.3f} s")
    c = st.counts
    if c.skipped or c.filtered:
        lines.append(f"left out: {c.skipped:,} records without {skipped}, {c.filtered:,} by the filter")
    if st.send_errors:
        kinds = ", ".join(f"{n} {k}" for k, n in sorted(st.errors.items()))
        lines.append(f"send errors: {st.send_errors:,} ({kinds}); first: {st.first_error}")
    return "\n".join(lines)


class _Progress:
    """Live progress on a terminal (rich), plain lines every few seconds otherwise."""

    def __init__(self, name: str, dest: str, mode: str) -> None:
        self.name, self.dest, self.mode = name, dest, mode
        self.live = None
        self.interval = 5.0
        if sys.stderr.isatty():
            from rich.console import Console
            from rich.live import Live
            from rich.text import Text

            self._text = Text

            self.live = Live(console=Console(stderr=True), auto_refresh=False, transient=True)
            self.live.start()
            self.interval = 0.25

    def _line(self, st: ReplayStats) -> str:
        lag = f", lag {_ms(st.lag_now_ns)}" if st.lag_now_ns is not None else ""
        err = f", {st.send_errors:,} send errors" if st.send_errors else ""
        return (f"replay {self.name} -> {self.dest} ({self.mode}): {st.frames:,} frames, "
                f"{st.rate_fps:,.1f} frames/s{lag}{err}, pass {st.passes + 1}")

    def __call__(self, st: ReplayStats) -> None:
        if self.live is not None:
            self.live.update(self._text(self._line(st)), refresh=True)
        else:
            print(self._line(st), file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()


def _duration(seconds: float) -> str:
    """``90`` -> "1.5 min", ``7200`` -> "2.0 h", ``3e7`` -> "347.2 days"."""
    for unit, size in (("days", 86400), ("h", 3600), ("min", 60)):
        if seconds >= size:
            return f"{seconds / size:.1f} {unit}"
    return f"{seconds:.0f} s"
