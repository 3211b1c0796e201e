"""``sharedlink watch``: a live view of a link (UDP, serial, or a capture at its pace)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from sharedlink.analysis.decode import Decoded
from sharedlink.capture.pcapio import buffered_stdout
from sharedlink.commands import EXIT_OK, add_decode_options, check_capture, decode_options
from sharedlink.errors import UsageError
from sharedlink.watch import (
    DEFAULT_PORT,
    CaptureSource,
    FastDecoder,
    LiveView,
    SerialSource,
    UdpSource,
    json_line,
    run_watch,
)

LAT, LON, HEADING, VELOCITY = "AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "watch",
        help="live view of a link: UDP port, serial line or a capture at its pace",
        description="Decode SharedLink traffic as it arrives and show, per direction, every variable's last value, "
        "its age and update rate, and the link's frames/s, checksum failures, late syncs and gaps (highlighted "
        "when they happen). --json prints one JSON line per frame instead; --foxglove also serves the decoded "
        "stream to Foxglove over its WebSocket protocol.",
        epilog="Exit codes: 0 the capture (--from) ended, 2 bad usage, 130 stopped with Ctrl-C.",
    )
    src = p.add_argument_group("source (default: UDP port 7013)")
    src.add_argument("--port", type=int, default=DEFAULT_PORT,
                     help=f"UDP port to listen on, every address, broadcasts included, shared with other "
                     f"listeners (default {DEFAULT_PORT})")
    src.add_argument("--listen", default="", metavar="ADDR", help="listen on this address only (default: all)")
    src.add_argument("--serial", metavar="DEVICE", default=None, help="read a serial port or pty instead")
    src.add_argument("--baud", type=int, default=9600, help="with --serial: baud rate (default 9600)")
    src.add_argument("--from", dest="capture", type=Path, default=None, metavar="CAPTURE",
                     help="play a capture at its recorded pace instead")
    src.add_argument("--speed", type=float, default=1.0, metavar="X", help="with --from: pace times X (default 1)")
    out = p.add_argument_group("output")
    out.add_argument("--json", action="store_true", help="one JSON line per frame on standard output instead of the view")
    out.add_argument("--foxglove", action="store_true", help="serve the stream over the Foxglove WebSocket protocol")
    out.add_argument("--foxglove-port", type=int, default=8765, metavar="PORT", help="its port (default 8765; 0: any free)")
    out.add_argument("--foxglove-host", default="127.0.0.1", metavar="ADDR", help="its address (default 127.0.0.1)")
    out.add_argument("--lat", default=LAT, help=f"latitude variable for Foxglove (default {LAT})")
    out.add_argument("--lon", default=LON, help=f"longitude variable for Foxglove (default {LON})")
    out.add_argument("--heading", default=HEADING, help=f"heading variable for Foxglove (default {HEADING})")
    out.add_argument("--velocity", default=VELOCITY, help=f"speed variable for Foxglove (default {VELOCITY})")
    add_decode_options(p)
    p.set_defaults(func=run)


def _source(args: argparse.Namespace) -> Any:
    if args.capture is not None and args.serial:
        raise UsageError("--from and --serial: one source at a time")
    if args.capture is not None:
        check_capture(args.capture)
        if not args.speed > 0:
            raise UsageError("--speed must be positive")
        return CaptureSource(args.capture, args.speed)
    if args.serial:
        if args.baud <= 0:
            raise UsageError("--baud must be positive")
        try:
            return SerialSource(args.serial, args.baud)
        except Exception as exc:  # pyserial's SerialException, OSError
            raise UsageError(f"{args.serial}: {exc}") from None
    if not 0 < args.port < 65536:
        raise UsageError("--port must be 1..65535")
    try:
        return UdpSource(args.port, args.listen)
    except OSError as exc:
        raise UsageError(f"udp port {args.port}: {exc.strerror or exc}") from None


def _foxglove(args: argparse.Namespace) -> tuple[Any, Any]:
    import foxglove

    from sharedlink.analysis.foxglove_channels import ChannelOptions, FoxgloveChannels

    ctx = foxglove.Context()
    try:
        server = foxglove.start_server(name="sharedlink watch", host=args.foxglove_host, port=args.foxglove_port, context=ctx)
    except Exception as exc:  # foxglove raises its own error type when the port is taken
        raise UsageError(f"--foxglove-port {args.foxglove_port}: {exc}") from None
    print(f"sharedlink watch: Foxglove WebSocket server on ws://{args.foxglove_host}:{server.port}", file=sys.stderr, flush=True)
    opts = ChannelOptions(lat=args.lat, lon=args.lon, heading=args.heading, speed=args.velocity)
    return server, FoxgloveChannels(ctx, opts)


def run(args: argparse.Namespace) -> int:
    variables, sync = decode_options(args)
    source = _source(args)
    server = None
    try:
        decoder = FastDecoder(variables, sync, carried=False)  # the outputs read values from the table
        outputs: list = []
        if args.foxglove:
            server, channels = _foxglove(args)
            outputs.append(channels.frame)
        print(f"sharedlink watch: {source.description}", file=sys.stderr, flush=True)
        if args.json:  # Ctrl-C waits until a batch's lines are written whole (see run_watch)
            with buffered_stdout(binary=False) as out:
                write = out.write

                def emit(d: Decoded) -> None:
                    write(json_line(d) + "\n")

                outputs.append(emit)
                run_watch(source, decoder, outputs, out=out)
            return EXIT_OK
        return _live(source, decoder, outputs, sync)
    finally:
        if server is not None:
            server.stop()
        source.close()


def _live(source: Any, decoder: FastDecoder, outputs: list, sync: float) -> int:
    from rich.console import Console
    from rich.live import Live

    view = LiveView(sync, source.description)
    outputs.append(view.update)
    console = Console()
    with Live(view.render(source.now_ns()), console=console, auto_refresh=False, transient=False) as live:
        def tick(now_ns: int) -> None:
            live.update(view.render(now_ns), refresh=True)

        run_watch(source, decoder, outputs, tick=tick, stats=view.stats)
    return EXIT_OK
