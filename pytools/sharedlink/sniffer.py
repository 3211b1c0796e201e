"""UDP datagrams of a port sniffed as Wireshark's dumpcap does, for ``sharedlink watch`` (its
default UDP source, :class:`UdpSniffer`): a Linux packet socket with the kernel filter of
``udp port PORT`` (:func:`port_filter`, classic BPF), IP fragments reassembled, nothing taken
from the programs bound to the port. The batches are :mod:`sharedlink.watch`'s
(:func:`~sharedlink.watch.socket_batches`, its :class:`~sharedlink.watch.Backlog`)."""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Iterator
from typing import Any

from sharedlink.capture.packets import PacketDecoder
from sharedlink.capture.pcapio import LINKTYPE_RAW
from sharedlink.watch import DEFAULT_PORT, MAX_LAG_S, Backlog, Batch, big_receive_buffer, socket_batches

ETH_P_ALL, ETH_P_IP, ETH_P_IPV6 = 0x0003, 0x0800, 0x86DD
PACKET_OUTGOING = 4
ARPHRD_LOOPBACK = 772
SO_ATTACH_FILTER = 26
#: getsockopt(SOL_PACKET, PACKET_STATISTICS): struct tpacket_stats {packets, drops}, reset by reading
SOL_PACKET, PACKET_STATISTICS = 263, 6
#: bytes of a packet the filter passes (as dumpcap's default snapshot length)
SNAPLEN = 262144

# classic BPF opcodes (linux/filter.h)
_LD_W_ABS, _LD_H_ABS, _LD_B_ABS, _LDX_B_MSH, _LD_H_IND = 0x20, 0x28, 0x30, 0xB1, 0x48
_JEQ_K, _JSET_K, _RET_K = 0x15, 0x45, 0x06
#: SKF_AD_OFF + SKF_AD_PROTOCOL, SKF_AD_PKTTYPE, SKF_AD_HATYPE: the packet's EtherType, its
#: direction (PACKET_OUTGOING ...), its interface's hardware type (ARPHRD_LOOPBACK ...)
_AD_PROTOCOL, _AD_PKTTYPE, _AD_HATYPE = 0xFFFFF000, 0xFFFFF004, 0xFFFFF01C


def port_filter(port: int) -> bytes:
    """The classic BPF program of Wireshark's capture filter ``udp port PORT`` for a packet
    socket of type SOCK_DGRAM (the packet starts at the IP header): IPv4 or IPv6 UDP from or to
    ``port``, and every UDP fragment of either (its ports are in the first fragment only: the
    reassembly, in Python, checks them); the outgoing copy on a loopback interface left out."""
    prog: list[tuple[int, str | int, str | int, int]] = [  # (code, jump if true, if false, k)
        (_LD_W_ABS, 0, 0, _AD_PKTTYPE),  # a loopback packet going out is seen again coming in
        (_JEQ_K, 0, "ip", PACKET_OUTGOING),
        (_LD_W_ABS, 0, 0, _AD_HATYPE),
        (_JEQ_K, "drop", 0, ARPHRD_LOOPBACK),
        ("ip", 0, 0, 0),
        (_LD_W_ABS, 0, 0, _AD_PROTOCOL),
        (_JEQ_K, 0, "v6", ETH_P_IP),
        (_LD_B_ABS, 0, 0, 9),  # IPv4 protocol
        (_JEQ_K, 0, "drop", 17),
        (_LD_H_ABS, 0, 0, 6),  # flags and fragment offset
        (_JSET_K, "take", 0, 0x3FFF),  # a fragment: more to come, or not the first
        (_LDX_B_MSH, 0, 0, 0),  # X = header length
        (_LD_H_IND, 0, 0, 0),
        (_JEQ_K, "take", 0, port),
        (_LD_H_IND, 0, 0, 2),
        (_JEQ_K, "take", "drop", port),
        ("v6", 0, 0, 0),
        (_JEQ_K, 0, "drop", ETH_P_IPV6),
        (_LD_B_ABS, 0, 0, 6),  # next header
        (_JEQ_K, "take", 0, 44),  # a fragment header
        (_JEQ_K, 0, "drop", 17),
        (_LD_H_ABS, 0, 0, 40),
        (_JEQ_K, "take", 0, port),
        (_LD_H_ABS, 0, 0, 42),
        (_JEQ_K, "take", "drop", port),
        ("take", 0, 0, 0),
        (_RET_K, 0, 0, SNAPLEN),
        ("drop", 0, 0, 0),
        (_RET_K, 0, 0, 0),
    ]
    labels: dict[str, int] = {}
    code: list[tuple[int, str | int, str | int, int]] = []
    for ins in prog:
        if isinstance(ins[0], str):
            labels[ins[0]] = len(code)
        else:
            code.append(ins)  # type: ignore[arg-type]
    out = b""
    for i, (op, jt, jf, k) in enumerate(code):
        t = labels[jt] - i - 1 if isinstance(jt, str) else jt
        f = labels[jf] - i - 1 if isinstance(jf, str) else jf
        out += struct.pack("=HBBI", op, t, f, k)
    return out


class SniffError(OSError):
    """The interface cannot be sniffed (no privileges, no such interface, not Linux)."""


class UdpSniffer:
    """Datagrams from or to UDP ``port`` seen on ``interface`` (every interface by default), read
    from a copy of the traffic as Wireshark's dumpcap reads it (a Linux packet socket, the
    filter ``udp port PORT`` in the kernel, IP fragments reassembled as Wireshark does). The
    programs bound to the port get every datagram as before: the watch only looks.

    Needs root or CAP_NET_RAW (:class:`SniffError` otherwise). On a loopback interface each
    packet passes the tap twice, going out and coming in: the outgoing copy is skipped, as
    libpcap does. ``host``: only datagrams to this address."""

    def __init__(self, port: int = DEFAULT_PORT, interface: str | None = None, host: str = "",
                 max_lag_s: float = MAX_LAG_S) -> None:
        if not hasattr(socket, "AF_PACKET"):
            raise SniffError("sniffing needs Linux packet sockets: give --bind-port to bind the port instead")
        self.port = port
        self.host = host
        try:
            # no protocol yet (nothing queued) while the filter goes on, when an interface is named
            self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_DGRAM, 0 if interface else socket.htons(ETH_P_ALL))
        except PermissionError:
            raise SniffError("sniffing needs root or CAP_NET_RAW (as Wireshark's dumpcap): run it so, or give --bind-port "
                             "to bind the port instead (it must be free: nothing else may listen on it)") from None
        try:
            prog = port_filter(port)
            import ctypes

            self._prog = ctypes.create_string_buffer(prog, len(prog))  # must outlive the setsockopt
            fprog = struct.pack("@HP", len(prog) // 8, ctypes.addressof(self._prog))
            self.sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)
            big_receive_buffer(self.sock)
            if interface:
                try:
                    self.sock.bind((interface, ETH_P_ALL))
                except OSError as exc:
                    raise SniffError(f"interface {interface}: {exc.strerror or exc}") from None
            self.sock.setblocking(False)
        except BaseException:
            self.sock.close()
            raise
        self.number = 0
        self.backlog = Backlog(max_lag_s=max_lag_s)
        # every interface: the socket took all traffic from its creation to the filter, and the
        # kernel counted what it dropped meanwhile (other ports' floods, not ours): reset
        self.kernel_drops()
        self.reassembly = PacketDecoder()
        where = f"interface {interface}" if interface else "every interface"
        self.description = f"udp port {port}{f' to {host}' if host else ''} on {where} (sniffed)"

    def _datagram(self, data: bytes) -> tuple[str, int, str, int, bytes] | None:
        """(src, sport, dst, dport, payload) of a UDP packet from or to the port; None for
        anything else (a fragment that does not complete a datagram, a foreign port)."""
        port = self.port
        if len(data) >= 28 and data[0] == 0x45 and data[9] == 17 and not (data[6] & 0x3F or data[7]):
            sport, dport, ulen = (data[20] << 8) | data[21], (data[22] << 8) | data[23], (data[24] << 8) | data[25]
            if sport != port and dport != port:
                return None
            end = min((data[2] << 8) | data[3], len(data))
            stop = min(20 + ulen, end) if ulen >= 8 else end
            out = (socket.inet_ntoa(data[12:16]), sport, socket.inet_ntoa(data[16:20]), dport, data[28:stop])
        else:
            d = self.reassembly.decode(LINKTYPE_RAW, data)
            if d is None or d.proto != "udp" or port not in (d.sport, d.dport):
                return None
            out = (d.src, d.sport, d.dst, d.dport, d.payload)
        if self.host and out[2] != self.host:
            return None
        return out

    def batches(self, timeout: float) -> Iterator[Batch]:
        """As :meth:`UdpSource.batches`, from the copies the tap gives."""
        datagram = self._datagram

        def take(data: bytes, addr: Any) -> tuple[tuple, bytes] | None:
            if addr[2] == PACKET_OUTGOING and addr[3] == ARPHRD_LOOPBACK:
                return None  # seen again coming in
            u = datagram(data)
            return None if u is None else (("udp", u[0], u[1], u[2], u[3]), u[4])

        from sharedlink.analysis.robots import RobotLinks
        from sharedlink.robot_watch import with_robots

        if not hasattr(self, "robots"):  # P2OS, blackboard over UDP: their messages (robot_watch.with_robots)
            self.robots = RobotLinks(messages=True)
        return with_robots(socket_batches(self, SNAPLEN, take, timeout), self.robots)

    def kernel_drops(self) -> int:
        """Packets the filter passed that the kernel dropped from the full receive buffer since
        the last call (PACKET_STATISTICS, which the reading resets)."""
        try:
            return struct.unpack("II", self.sock.getsockopt(SOL_PACKET, PACKET_STATISTICS, 8))[1]
        except OSError:
            return 0

    def now_ns(self) -> int:
        return time.time_ns()

    def close(self) -> None:
        self.sock.close()
