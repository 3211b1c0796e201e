"""Where ``sharedlink replay`` sends a capture's payloads: a UDP socket (:class:`UdpSink`) or a
serial port (:class:`SerialSink`), with the destinations' syntax (``--to``, ``--bind``) and the
errors of a replay's set-up (:class:`ReplayError`) and of a destination that takes nothing
(:class:`SinkStalled`). A sink is what :class:`~sharedlink.replay.Replayer` needs: ``send(payload,
target)``, ``target(frame)`` (None: this frame cannot be sent), ``description`` and ``close()``.
A TCP capture's sinks are in :mod:`sharedlink.replay_tcp`. Users import these names from
:mod:`sharedlink.replay`."""

from __future__ import annotations

import ipaddress
import socket
import struct
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Union

from sharedlink.errors import UsageError

if TYPE_CHECKING:
    from sharedlink.replay import OutFrame

Target = Any  # what a sink needs to send one payload (an address for UDP); None = cannot send


class ReplayError(UsageError):
    """Bad replay setup: an unusable destination, source address or serial port."""


def split_host_port(text: str, what: str = "--to") -> tuple[str, int | None]:
    """``HOST``, ``HOST:PORT``, ``[V6]:PORT`` or a bare IPv6 address -> (host, port or None)."""
    host, port = text, None
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise ReplayError(f"{what} {text!r}: missing ']'")
        host, rest = text[1:end], text[end + 1 :]
        if rest:
            if not rest.startswith(":"):
                raise ReplayError(f"{what} {text!r}: expected [ADDRESS]:PORT")
            port = _port(rest[1:], what, text)
    elif text.count(":") == 1:
        host, p = text.split(":")
        port = _port(p, what, text)
    if not host:
        raise ReplayError(f"{what} {text!r}: no host")
    return host, port


def _port(p: str, what: str, text: str) -> int:
    lowest = 0 if what == "--bind" else 1
    if not p.isdigit() or not lowest <= int(p) < 65536:
        raise ReplayError(f"{what} {text!r}: port must be {lowest}..65535")
    return int(p)


def _resolve(host: str, port: int, what: str) -> tuple[int, tuple]:
    try:
        infos = socket.getaddrinfo(host, port, 0, socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise ReplayError(f"{what} {host}: cannot resolve ({exc})") from None
    infos.sort(key=lambda i: i[0] != socket.AF_INET)  # prefer IPv4 when a name has both
    fam, _, _, _, addr = infos[0]
    return fam, addr


def is_broadcast(host: str, family: int = socket.AF_INET) -> bool:
    """Whether the kernel routes ``host`` as a broadcast (limited or directed, on any local
    network): a UDP socket without SO_BROADCAST may not connect to it."""
    if family != socket.AF_INET:
        return False
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect((host, 9))
        except PermissionError:
            return True
        except OSError:
            return host == "255.255.255.255"
    return False


def is_multicast(host: str) -> bool:
    """Whether ``host`` (an address) is a multicast group (224.0.0.0/4, ff00::/8)."""
    try:
        return ipaddress.ip_address(host.split("%")[0]).is_multicast
    except ValueError:
        return False


def _interface_ipv4(name: str) -> str | None:
    """The IPv4 address of a network interface (Linux SIOCGIFADDR), or None."""
    try:
        import fcntl

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            res = fcntl.ioctl(s.fileno(), 0x8915, struct.pack("256s", name.encode()[:15]))
        return socket.inet_ntoa(res[20:24])
    except (OSError, ImportError):
        return None


class UdpSink:
    """Sends payloads to ``host`` on the given port, or on each frame's captured port.

    ``broadcast`` must be set for a broadcast destination (SO_BROADCAST), ``multicast`` for a
    multicast group; without it a :class:`ReplayError` is raised before anything is sent. ``bind`` is a source address,
    ``ADDR:PORT``, or an interface name.
    """

    def __init__(self, host: str = "127.0.0.1", port: int | None = None, bind: str | None = None, broadcast: bool = False,
                 multicast: bool = False) -> None:
        self.host, self.port = host, port
        fam, addr = _resolve(host, port or 9, "destination")
        self.family, self.address = fam, addr[0]
        if not broadcast and is_broadcast(self.address, fam):
            raise ReplayError(
                f"{host} is a broadcast address: replaying there reaches every host on that network; "
                "add --broadcast if that is what you want"
            )
        if not multicast and is_multicast(self.address):
            raise ReplayError(
                f"{host} is a multicast group: replaying there reaches every member of it, on the network too; "
                "add --multicast if that is what you want"
            )
        self.sock = socket.socket(fam, socket.SOCK_DGRAM)
        try:
            if broadcast:
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            try:
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
            except OSError:
                pass
            if bind:
                self._bind(bind)
        except BaseException:
            self.sock.close()
            raise
        self._targets: dict[int | None, Target] = {}
        self.send: Callable[[bytes, Target], Any] = self.sock.sendto

    def _bind(self, spec: str) -> None:
        ifnames = {n for _, n in socket.if_nameindex()} if hasattr(socket, "if_nameindex") else set()
        if spec in ifnames:
            try:
                self.sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_BINDTODEVICE", 25), spec.encode())
                return
            except OSError:
                addr = _interface_ipv4(spec) if self.family == socket.AF_INET else None
                if addr is None:
                    raise ReplayError(f"--bind {spec}: cannot bind to that interface without privileges, and it has no IPv4 address") from None
                host, port = addr, 0
        else:
            host, p = split_host_port(spec, "--bind")
            port = p or 0
        try:
            fam, addr = _resolve(host, port, "--bind")
            if fam != self.family:
                raise ReplayError(f"--bind {spec}: not the same address family as the destination {self.host}")
            self.sock.bind(addr)
        except OSError as exc:
            raise ReplayError(f"--bind {spec}: {exc.strerror or exc}") from None

    @property
    def description(self) -> str:
        host = f"[{self.address}]" if self.family == socket.AF_INET6 else self.address
        return f"udp {host}:{self.port if self.port else '<captured port>'}"

    def target(self, frame: OutFrame) -> Target:
        port = self.port or frame.port
        t = self._targets.get(port)
        if t is None and port:
            t = self._targets[port] = (self.address, port) if self.family == socket.AF_INET else (self.address, port, 0, 0)
        return t

    def close(self) -> None:
        self.sock.close()


class SinkStalled(OSError):
    """The destination takes nothing (a serial port nobody reads: the write timed out). The
    replay stops at the first one instead of waiting out the timeout for every frame."""


class SerialSink:
    """Writes payloads to a serial port or pty (pyserial), raw 8N1 at ``baud``. A write that
    times out raises :class:`SinkStalled`."""

    def __init__(self, device: str, baud: int = 9600, write_timeout: float = 5.0) -> None:
        import serial  # pyserial

        try:
            self.port = serial.Serial(device, baudrate=baud, write_timeout=write_timeout)
        except (serial.SerialException, ValueError, OSError) as exc:
            from sharedlink.capture.serial_port import port_error

            raise ReplayError(port_error(device, exc)) from None
        self.device, self.baud = device, baud
        write, stalled = self.port.write, serial.SerialTimeoutException

        def send(payload: bytes, _t: Target) -> Any:
            try:
                return write(payload)
            except stalled:
                raise SinkStalled(f"{device}: write timed out after {write_timeout:g} s: is anything reading the port?") from None

        self.send: Callable[[bytes, Target], Any] = send

    @property
    def description(self) -> str:
        return f"serial {self.device} at {self.baud} baud"

    def target(self, frame: OutFrame) -> Target:
        return True

    def close(self) -> None:
        try:
            self.port.flush()
        except Exception:  # noqa: BLE001 - the port may be gone; closing must not raise
            pass
        self.port.close()


Sink = Union[UdpSink, SerialSink]
