"""Wireshark extcap: the machine's serial ports as capture interfaces.

Wireshark runs the launcher ``extcap/sharedlink-serial`` (``make install`` copies it into the
personal extcap folder) with the extcap options:

- ``--extcap-interfaces``: one interface per serial port pyserial finds
  (``sharedlink-serial-ttyUSB0`` ...) and ``sharedlink-serial``, for a device typed in by hand
  (a pty, a port the scan misses);
- ``--extcap-interface IF --extcap-dlts``: the USER link type the captures use;
- ``--extcap-interface IF --extcap-config``: the options Wireshark shows: device, baud rate,
  tap (a second device: relay between the two and record both directions), link type;
- ``--capture --extcap-interface IF --fifo PATH [--device D] [--baud N] [--tap D2]
  [--linktype user0]``: capture into the fifo (pcapng, see docs/serial-capture-format.md)
  until Wireshark stops it (SIGTERM) or closes the fifo.

Errors go to stderr with exit code 2 (bad options) or 1 (the port cannot be opened), which
Wireshark shows to the user.
"""

from __future__ import annotations

import argparse
import os
import sys
import unicodedata
from collections.abc import Sequence

from sharedlink.capture.serial_format import SerialCaptureWriter, parse_linktype
from sharedlink.capture.serial_port import capture, list_ports

from . import __version__

PREFIX = "sharedlink-serial"
BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
DEFAULT_BAUD = 9600


def extcap_text(text: str) -> str:
    """``text`` made safe inside an extcap field ``{name=TEXT}``. The protocol has no escape:
    Wireshark reads one sentence per line and a field's text up to the first ``}`` followed by
    ``{``, a space or the end (wiretap's extcap_parser.c). So a line break would start a
    sentence of its own (a USB product string could add ``interface {...}`` lines) and a brace
    could end the field or add one: control characters (line breaks, tabs, NUL, DEL and the
    C1 set) become spaces, braces become parentheses."""
    out = []
    for c in text:
        if c == "{":
            c = "("
        elif c == "}":
            c = ")"
        elif unicodedata.category(c) in ("Cc", "Zl", "Zp"):
            c = " "
        out.append(c)
    return "".join(out)


def interfaces() -> list[tuple[str, str, str]]:
    """(interface value, display name, device) for every port, plus the by-hand one."""
    out = [(PREFIX, "SharedLink serial: device given in the options", "")]
    seen = set()
    for dev, desc in list_ports():
        base = _slug(os.path.basename(dev))
        name = f"{PREFIX}-{base}"
        if name in seen:
            continue
        seen.add(name)
        out.append((name, f"SharedLink serial: {dev} ({desc})" if desc and desc != dev else f"SharedLink serial: {dev}", dev))
    return out


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in text) or "port"


def device_of(interface: str) -> str:
    for value, _disp, dev in interfaces():
        if value == interface:
            return dev
    if interface.startswith(PREFIX + "-"):
        # a port that went away since the listing: guess its path
        return "/dev/" + interface[len(PREFIX) + 1 :]
    return ""


def print_interfaces(out=sys.stdout) -> None:
    print(f"extcap {{version={__version__}}}{{display=SharedLink serial capture}}", file=out)
    for value, display, _dev in interfaces():
        print(f"interface {{value={extcap_text(value)}}}{{display={extcap_text(display)}}}", file=out)


def print_dlts(linktype: int, out=sys.stdout) -> None:
    print(f"dlt {{number={linktype}}}{{name=USER{linktype - 147}}}{{display=Serial line bytes (LINKTYPE_USER{linktype - 147})}}", file=out)


def print_config(interface: str, out=sys.stdout) -> None:
    dev = device_of(interface) if interface else ""
    lines = [
        "arg {number=0}{call=--device}{display=Serial device}{type=string}"
        + (f"{{default={extcap_text(dev)}}}" if dev else "")
        + "{tooltip=The port to read, e.g. /dev/ttyUSB0}{required=true}{group=Port}",
        # an integer, not an editselector: Wireshark 4.0 knows no editselector
        f"arg {{number=1}}{{call=--baud}}{{display=Baud rate}}{{type=integer}}{{range=50,4000000}}{{default={DEFAULT_BAUD}}}"
        f"{{tooltip=Line speed in bits per second (8N1), e.g. {', '.join(map(str, BAUDS))}}}{{group=Port}}",
    ]
    lines += [
        "arg {number=2}{call=--tap}{display=Tap: second device}{type=string}"
        "{tooltip=Relay between the device and this one (man in the middle), recording bytes from the "
        "device as inbound and bytes from this one as outbound}{group=Tap}",
        "arg {number=3}{call=--linktype}{display=Link type}{type=selector}"
        "{tooltip=USER link type of the capture (the serial dissector's preference must match)}{group=Capture}",
    ]
    lines += [
        f"value {{arg=3}}{{value=user{i}}}{{display=LINKTYPE_USER{i} ({147 + i})}}" + ("{default=true}" if i == 0 else "")
        for i in range(16)
    ]
    for ln in lines:
        print(ln, file=out)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sharedlink-serial", description="Wireshark extcap for serial ports (SharedLink tools)")
    p.add_argument("--extcap-interfaces", action="store_true")
    p.add_argument("--extcap-version", default=None)
    p.add_argument("--extcap-interface", default="")
    p.add_argument("--extcap-dlts", action="store_true")
    p.add_argument("--extcap-config", action="store_true")
    p.add_argument("--extcap-capture-filter", default=None)
    p.add_argument("--extcap-control-in", default=None)
    p.add_argument("--extcap-control-out", default=None)
    p.add_argument("--capture", action="store_true")
    p.add_argument("--fifo", default=None)
    p.add_argument("--device", default="")
    p.add_argument("--baud", default=str(DEFAULT_BAUD))
    p.add_argument("--tap", default="")
    p.add_argument("--linktype", default="user0")
    p.add_argument("--duration", type=float, default=None, help=argparse.SUPPRESS)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args, _unknown = parser.parse_known_args(argv)
    try:
        linktype = parse_linktype(args.linktype or "user0")
        baud = int(args.baud)
        if baud <= 0:
            raise ValueError
    except ValueError as exc:
        print(f"sharedlink-serial: {exc if str(exc) else 'bad --baud ' + repr(args.baud)}", file=sys.stderr)
        return 2
    if args.extcap_interfaces:
        print_interfaces()
        return 0
    if args.extcap_dlts:
        print_dlts(linktype)
        return 0
    if args.extcap_config:
        print_config(args.extcap_interface)
        return 0
    if not args.capture:
        parser.print_usage(sys.stderr)
        return 2
    if not args.fifo:
        print("sharedlink-serial: --capture needs --fifo", file=sys.stderr)
        return 2
    device = args.device or device_of(args.extcap_interface)
    if not device:
        print("sharedlink-serial: no device: give one in the interface options (--device)", file=sys.stderr)
        return 2
    tap = (device, args.tap) if args.tap else None
    try:
        with open(args.fifo, "wb") as fh:
            w = SerialCaptureWriter(
                fh, linktype, if_name=device if not tap else f"{device}<->{args.tap}",
                if_description=f"serial {'tap ' if tap else ''}at {baud} baud",
            )
            capture(w, device, baud, tap=tap, duration=args.duration)
    except BrokenPipeError:
        return 0
    except Exception as exc:  # serial.SerialException, OSError: the user must see why
        print(f"sharedlink-serial: {device}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
