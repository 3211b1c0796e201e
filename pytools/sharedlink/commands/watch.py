"""``sharedlink watch``: a live view of a link (UDP, serial, or a capture at its pace)."""

from __future__ import annotations

import argparse
import errno
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sharedlink._interrupt import Terminated
from sharedlink.capture.pcapio import buffered_stdout
from sharedlink.commands import (
    BAUD,
    EXIT_OK,
    EXIT_USAGE,
    PORT,
    OptionalPositional,
    add_decode_options,
    add_json_option,
    add_location_options,
    add_old_spelling,
    add_quiet_option,
    add_speed_option,
    capture_input,
    decode_options,
)
from sharedlink.defaults import WATCH_DEFAULT_PORT as DEFAULT_PORT
from sharedlink.errors import UsageError
from sharedlink.extras import require

if TYPE_CHECKING:  # (loaded when the command runs: every command's start-up pays for what is imported here)
    from sharedlink.analysis.decode import Decoded, Decoder


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "watch",
        help="live view of a link: UDP port, serial line or a capture at its pace",
        description="Decode SharedLink traffic as it arrives and show, per direction, every variable's last value, "
        "its age and update rate, and the link's frames/s, checksum failures, late syncs and late full sets "
        "(highlighted when they happen). --json prints one JSON line per frame instead; --foxglove also serves the decoded "
        "stream to Foxglove over its WebSocket protocol.",
        epilog="Exit codes: 0 stopped with Ctrl-C (as tcpdump) or the CAPTURE ended, 2 bad usage, no permission to "
        "sniff, a port --bind-port finds taken or a damaged capture (after the frames before the damage), 143 "
        "stopped by SIGTERM.",
    )
    src = p.add_argument_group("source (default: UDP port 7013)")
    p.add_argument("capture", nargs="?", type=Path, default=None, metavar="CAPTURE", action=OptionalPositional,
                   help="play this capture at its recorded pace instead of listening (-: standard input)")
    src.add_argument("--port", type=PORT, default=DEFAULT_PORT,
                     help=f"UDP port to watch (default {DEFAULT_PORT}): its datagrams, from or to it, are sniffed on the "
                     "interface as Wireshark does (root or CAP_NET_RAW), so every program on the port still gets them all")
    src.add_argument("--interface", default=None, metavar="IFACE",
                     help="sniff this interface only (default: every interface)")
    src.add_argument("--bind-port", action="store_true",
                     help="bind the port instead of sniffing (no privileges needed): the watch then takes the datagrams, "
                     "so it refuses a port another program holds")
    src.add_argument("--listen", default="", metavar="ADDR",
                     help="only datagrams to this address (with --bind-port: bind this address; default: all)")
    src.add_argument("--max-lag", type=float, default=None, metavar="S",
                     help="UDP: drop (and count) a datagram that waited more than S seconds to be decoded, so a flood "
                     "cannot leave the watch behind the link (default 10; 0: only the backlog's size bounds it)")
    src.add_argument("--serial", metavar="DEVICE", default=None, help="read a serial port or pty instead")
    src.add_argument("--baud", type=BAUD, default=9600, help="with --serial: baud rate (default 9600)")
    add_old_spelling(src, "--from", "a positional CAPTURE (sharedlink watch CAPTURE)", "capture", type=Path)
    add_speed_option(src, "with CAPTURE: its pace times X (2 = twice as fast; default 1)")
    out = p.add_argument_group("output")
    add_json_option(out, "one line per frame (instead of the view)")
    add_quiet_option(out)
    out.add_argument("--outages", action="store_true",
                     help="with --json: each outage of a link as a line of its own (kind: outage, as export --outages "
                     "writes it) before the frame that ends it; with a CAPTURE the open ones at its end")
    out.add_argument("--foxglove", action="store_true", help="serve the stream over the Foxglove WebSocket protocol")
    out.add_argument("--foxglove-port", type=int, default=8765, metavar="PORT", help="its port (default 8765; 0: any free)")
    out.add_argument("--foxglove-host", default="127.0.0.1", metavar="ADDR", help="its address (default 127.0.0.1)")
    add_location_options(out, "Foxglove", checked=False)
    add_decode_options(p)
    p.set_defaults(func=run)


def _source(args: argparse.Namespace) -> Any:
    from sharedlink.sniffer import UdpSniffer
    from sharedlink.watch import CaptureSource, SerialSource, UdpSource

    if args.capture is not None and args.serial:
        raise UsageError("--from and --serial: one source at a time")
    if args.capture is not None:
        args.capture = capture_input(args.capture)
        if not args.speed > 0:
            raise UsageError("--speed must be positive")
        # P2OS, blackboard: with --foxglove, else if the capture has robot links (found as it is read)
        return CaptureSource(args.capture, args.speed, sessions=True if args.foxglove else None)
    if args.serial:
        if args.baud <= 0:
            raise UsageError("--baud must be positive")
        try:
            return SerialSource(args.serial, args.baud)
        except Exception as exc:  # pyserial's SerialException, OSError
            from sharedlink.capture.serial_port import port_error

            raise UsageError(port_error(args.serial, exc)) from None
    if not 0 < args.port < 65536:
        raise UsageError("--port must be 1..65535")
    from sharedlink.watch import MAX_LAG_S

    lag = MAX_LAG_S if args.max_lag is None else args.max_lag
    if not 0 <= lag < 1e9:
        raise UsageError("--max-lag must be 0 or more seconds")
    if args.bind_port:
        if args.interface:
            raise UsageError("--bind-port binds an address, not an interface: give --listen ADDR, or sniff with --interface")
        try:
            return UdpSource(args.port, args.listen, max_lag_s=lag)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise UsageError(f"udp port {args.port}: another program holds it; --bind-port never shares a port (it "
                                 "would take datagrams away from that program): leave out --bind-port to sniff it") from None
            raise UsageError(f"udp port {args.port}: {exc.strerror or exc}") from None
    try:
        return UdpSniffer(args.port, args.interface, args.listen, max_lag_s=lag)
    except OSError as exc:
        raise UsageError(f"udp port {args.port}: {exc.strerror or exc}") from None


def _foxglove(args: argparse.Namespace) -> tuple[Any, Any]:
    require("foxglove", "sharedlink watch --foxglove")
    import foxglove

    from sharedlink.analysis.foxglove_channels import ChannelOptions, FoxgloveChannels
    from sharedlink.foxglove_server import LiveServer
    from sharedlink.watch import FOXGLOVE_CHANNELS

    ctx = foxglove.Context()
    try:  # both subprotocol names (foxglove.sdk.v1, foxglove.websocket.v1): see foxglove_server
        server = LiveServer(ctx, args.foxglove_host, args.foxglove_port)
    except Exception as exc:  # OSError, or foxglove's own error type
        raise UsageError(f"--foxglove-port {args.foxglove_port}: {exc}") from None
    print(f"sharedlink watch: Foxglove WebSocket server on ws://{args.foxglove_host}:{server.port}", file=sys.stderr, flush=True)
    opts = ChannelOptions(lat=args.lat, lon=args.lon, heading=args.heading, speed=args.velocity,
                          max_channels=FOXGLOVE_CHANNELS)
    return server, FoxgloveChannels(ctx, opts)


def run(args: argparse.Namespace) -> int:
    """Ctrl-C is how a watch ends, as tcpdump's: exit 0 after the summary (SIGTERM: 143)."""
    try:
        return _run(args)
    except KeyboardInterrupt as exc:
        if isinstance(exc, Terminated):
            raise
        return EXIT_OK


def _run(args: argparse.Namespace) -> int:
    from sharedlink.analysis.decode import Decoder
    from sharedlink.watch import JsonLines, WatchStats, run_watch, served

    variables, sync = decode_options(args)
    if args.outages and not args.json:
        raise UsageError("--outages: outage lines are written with --json (the view shows each link's outages)")
    if args.foxglove:  # before the source opens
        require("foxglove", "sharedlink watch --foxglove")
    source = _source(args)
    server = None
    stats = WatchStats()
    try:
        decoder = Decoder(variables, sync, carried=False)  # the outputs read values from the table
        outputs: list = []
        sessions: list = []
        tick = None
        if args.foxglove:
            from sharedlink.analysis.foxglove_health import LiveQuality

            server, channels = _foxglove(args)
            quality = LiveQuality(channels)  # a link_quality channel per link, each second once ended
            outputs.append(served(quality.gap, stats))  # (an outage's gap before the frame that ends it)
            outputs.append(served(channels.frame, stats))
            sessions.append(served(quality.session_gap, stats))  # (a SIP outage's gap before the packet that ends it)
            sessions.append(served(channels.session, stats))
            sessions.append(served(quality.session, stats))  # (the robot links': after their session's channels)
            outputs.append(served(quality.frame, stats))
            tick = quality.tick
        if not args.quiet:  # what is watched (the Foxglove server's address is always said)
            print(f"sharedlink watch: {source.description}", file=sys.stderr, flush=True)
        if args.json:  # Ctrl-C waits until a batch's lines are written whole (see run_watch)
            with buffered_stdout(binary=False) as out:
                write = out.write
                line = JsonLines()

                def emit(d: Decoded) -> None:
                    write(line(d, stats.dropped) + "\n")

                feed = _outage_lines(outputs, write) if args.outages else None
                outputs.append(emit)
                from sharedlink.analysis.robot_export import RobotJsonl

                robot = RobotJsonl([], lambda: None)  # P2OS, blackboard: export's lines
                sessions.append(lambda m: write(robot.fast_line(m) or robot.line(m)))
                run_watch(source, decoder, outputs, tick=tick, out=out, stats=stats, session_outputs=sessions)
                if feed is not None:  # (the capture ended: its open outages)
                    feed()
            return _damage(source)
        _live(source, decoder, outputs, sync, sessions, stats, tick)
        return _damage(source)
    finally:
        if server is not None:
            server.stop()
        source.close()
        if stats.summary():  # also after Ctrl-C: what the view or the lines could not show
            print(f"sharedlink watch: {stats.summary()}", file=sys.stderr, flush=True)


def _outage_lines(outputs: list, write: Any) -> Any:
    """An output, before the frame lines, writing the outages each frame ends (export's rows);
    returns what writes the open ones (at a capture's end)."""
    import json

    from sharedlink.analysis.health import OutageFeed, outage_row

    feed = OutageFeed()

    def outages(d: Decoded) -> None:
        for o in feed.feed(d):
            write(json.dumps(outage_row(o)) + "\n")

    def finish() -> None:
        for o in feed.finish():
            write(json.dumps(outage_row(o)) + "\n")

    outputs.append(outages)
    return finish


def _damage(source: Any) -> int:
    """A damaged capture (--from) is reported after the frames before the damage."""
    error = getattr(source, "error", None)
    if error is None:
        return EXIT_OK
    print(f"sharedlink: error: {error} (the frames before it were shown)", file=sys.stderr)
    return EXIT_USAGE


def _live(source: Any, decoder: Decoder, outputs: list, sync: float, sessions: list, stats: Any,
          also: Any = None) -> int:
    from rich.console import Console, Group
    from rich.live import Live

    from sharedlink.robot_watch import RobotView
    from sharedlink.watch import LiveView, run_watch

    view = LiveView(sync, source.description)
    view.stats = stats
    outputs.append(view.update)
    robots = RobotView()  # P2OS and blackboard sessions, below the SharedLink view
    sessions.append(robots.update)
    console = Console()

    def render(now_ns: int) -> Any:
        shown = view.render(now_ns, console.height)
        return Group(shown, robots.render(now_ns)) if robots.sessions else shown

    with Live(render(source.now_ns()), console=console, auto_refresh=False, transient=False) as live:
        def tick(now_ns: int) -> None:
            if also is not None:  # (--foxglove's link quality)
                also(now_ns)
            live.update(render(now_ns), refresh=True)

        run_watch(source, decoder, outputs, tick=tick, stats=view.stats, session_outputs=sessions)
    if not console.is_terminal:  # redirected, rich leaves the last view without its newline
        console.line()
    return EXIT_OK
