"""Link, IPv4, UDP and TCP headers: fast building of beacon datagrams and decoding of captured
packets down to their transport payload."""

from __future__ import annotations

import socket
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, BinaryIO

from sharedlink.capture.pcapio import (
    DIR_INBOUND,
    DIR_OUTBOUND,
    LINKTYPE_ETHERNET,
    LINKTYPE_IPV4,
    LINKTYPE_IPV6,
    LINKTYPE_LINUX_SLL,
    LINKTYPE_LINUX_SLL2,
    LINKTYPE_LOOP,
    LINKTYPE_NULL,
    LINKTYPE_RAW,
    LINKTYPE_RAW_DLT12,
    LINKTYPE_RAW_DLT14,
    make_writer,
)

_IP_HDR = struct.Struct("!BBHHHBBH4s4s")
_NET_HDR = struct.Struct("!BBHHHBBH4s4sHHHH")  # IPv4 + UDP


def ones_complement_checksum(data: bytes) -> int:
    """The Internet checksum of ``data`` (RFC 1071).

    The one's-complement sum of 16-bit words is the data read as one big-endian integer
    modulo 0xFFFF (2**16 is 1 modulo 0xFFFF), which Python computes in C.
    """
    if len(data) & 1:
        data += b"\0"
    r = int.from_bytes(data, "big") % 0xFFFF
    # r == 0 means the sum is 0xFFFF (for non-zero data) or 0: the complement is 0 either way
    return 0xFFFF - r if r else 0


def mac_bytes(mac: str) -> bytes:
    return bytes(int(x, 16) for x in mac.split(":"))


#: the largest UDP payload an IPv4 datagram holds (65535 - 20 - 8)
MAX_UDP_PAYLOAD = 65507


class UdpBuilder:
    """Builds Ethernet/IPv4/UDP frames between fixed endpoints with correct IP and UDP
    checksums. Everything that does not change per packet is computed once."""

    def __init__(
        self,
        src_ip: str,
        dst_ip: str,
        sport: int,
        dport: int,
        src_mac: str = "02:00:00:00:00:02",
        dst_mac: str = "ff:ff:ff:ff:ff:ff",
        ttl: int = 64,
    ) -> None:
        for port in (sport, dport):
            if not 0 <= port <= 0xFFFF:
                raise ValueError(f"UDP port {port} is not in 0..65535")
        self.src = socket.inet_aton(src_ip)
        self.dst = socket.inet_aton(dst_ip)
        self.sport, self.dport, self.ttl = sport, dport, ttl
        self.eth = mac_bytes(dst_mac) + mac_bytes(src_mac) + b"\x08\x00"
        # partial sums of the constant parts of the IP header and the UDP pseudo header
        self._ip_const = (0x4500 + (ttl << 8 | 17) + _sum16(self.src) + _sum16(self.dst)) & 0xFFFFFFFF
        self._pseudo = _sum16(self.src) + _sum16(self.dst) + 17 + sport + dport

    def frame(self, payload: bytes, ip_id: int) -> bytes:
        return self.headers(len(payload), payload, ip_id) + payload

    def headers(self, plen: int, payload: bytes, ip_id: int) -> bytes:
        """The Ethernet, IPv4 and UDP headers for ``payload`` (its length is ``plen``). The IP
        identification is ``ip_id`` modulo 65536 (a counter may run past it); a payload longer
        than an IPv4 UDP datagram holds (:data:`MAX_UDP_PAYLOAD`) is a ValueError."""
        if plen > MAX_UDP_PAYLOAD:
            raise ValueError(f"a UDP payload of {plen:,} bytes is more than an IPv4 datagram holds ({MAX_UDP_PAYLOAD:,})")
        ip_id &= 0xFFFF
        ulen = 8 + plen
        tlen = 20 + ulen
        s = self._ip_const + tlen + ip_id + 0x4000  # DF set
        s = (s & 0xFFFF) + (s >> 16)
        s = (s & 0xFFFF) + (s >> 16)
        ip_ck = 0xFFFF - s
        # UDP checksum: pseudo header + header (length twice) + payload
        data = payload + b"\0" if len(payload) & 1 else payload
        r = (int.from_bytes(data, "big") + self._pseudo + 2 * ulen) % 0xFFFF
        udp_ck = 0xFFFF - r if r else 0xFFFF
        return self.eth + _NET_HDR.pack(
            0x45, 0, tlen, ip_id, 0x4000, self.ttl, 17, ip_ck, self.src, self.dst, self.sport, self.dport, ulen, udp_ck
        )


def _sum16(b: bytes) -> int:
    return sum(struct.unpack("!%dH" % (len(b) // 2), b))


@dataclass(slots=True)  # (not frozen: a frozen dataclass's __init__ is 3-5x slower, and one is made a packet)
class Datagram:
    """A transport payload and its addressing."""

    proto: str  # "udp" or "tcp"
    src: str
    dst: str
    sport: int
    dport: int
    payload: bytes
    tcp_seq: int = 0
    tcp_flags: int = 0


def decode_packet(linktype: int, data: bytes) -> Datagram | None:
    """Strip link, IPv4/IPv6 (extension headers walked) and UDP/TCP headers. None when the
    packet is something else, too short, or an IP fragment (see :class:`PacketDecoder` for
    reassembly). Never raises."""
    try:
        return _decode(linktype, data, None)
    except (struct.error, IndexError, ValueError, OSError):
        return None


class PacketDecoder:
    """:func:`decode_packet` for the packets of one capture, in order, with IPv4 and IPv6
    fragments reassembled as Wireshark does it (``ip.defragment`` and ``ipv6.defragment``
    on): the datagram comes out of the fragment that completes it, so it carries that
    fragment's frame number; the other fragments give None."""

    def __init__(self) -> None:
        self.reassembler = Reassembler()

    def decode(self, linktype: int, data: bytes) -> Datagram | None:
        try:
            return _decode(linktype, data, self.reassembler)
        except (struct.error, IndexError, ValueError, OSError):
            return None


# -- fragments ---------------------------------------------------------------------------

#: fragmented datagrams waiting for their missing pieces; the oldest is dropped beyond this
MAX_PENDING_DATAGRAMS = 1024


class Reassembler:
    """IP fragments put back together, streaming. Written by hand rather than with scapy's
    ``defragment``, which takes a whole packet list in memory: here a datagram is complete
    at the fragment that fills its last hole (any order, duplicates and overlaps allowed;
    the first copy of a byte wins, as in Wireshark), and memory stays bounded."""

    def __init__(self, max_pending: int = MAX_PENDING_DATAGRAMS) -> None:
        self.max_pending = max_pending
        self._pending: dict[tuple, tuple[list[tuple[int, bytes]], list[int]]] = {}

    def add(self, key: tuple, offset: int, payload: bytes, more: bool) -> bytes | None:
        """Add one fragment (``offset`` in bytes); the whole payload once it is complete."""
        entry = self._pending.get(key)
        if entry is None:
            if len(self._pending) >= self.max_pending:
                del self._pending[next(iter(self._pending))]
            entry = self._pending[key] = ([], [-1])
        parts, total = entry
        parts.append((offset, payload))
        if not more:
            total[0] = offset + len(payload)
        if total[0] < 0:
            return None
        end = total[0]
        covered = 0
        for off, data in sorted(parts, key=lambda p: p[0]):
            if off > covered:
                return None  # a hole
            covered = max(covered, off + len(data))
        if covered < end:
            return None
        del self._pending[key]
        buf = bytearray(end)
        for off, data in reversed(parts):  # the first copy of a byte wins
            buf[off : off + len(data)] = data[: max(0, end - off)]
        return bytes(buf)


# -- link layers -------------------------------------------------------------------------

_ETYPE_IPV4, _ETYPE_IPV6 = 0x0800, 0x86DD
#: BSD loopback address families that mean IPv6 (NetBSD/OpenBSD, FreeBSD, Darwin; Linux)
_AF_INET6 = frozenset({24, 28, 30, 10})


def _ip_version(data: bytes, off: int) -> int:
    return _ETYPE_IPV4 if data[off] >> 4 == 4 else _ETYPE_IPV6


def _null_family(data: bytes, order: str) -> tuple[int, int] | None:
    fam = struct.unpack_from(order + "I", data, 0)[0]
    if fam > 0xFFFF:  # written on a host of the other byte order
        fam = struct.unpack_from(("<" if order == ">" else ">") + "I", data, 0)[0]
    if fam == 2:
        return _ETYPE_IPV4, 4
    return (_ETYPE_IPV6, 4) if fam in _AF_INET6 else None


#: link type -> function giving (EtherType, offset of the network header), for link types
#: with a fixed header (Ethernet, the common case, is decoded inline in _decode)
_LINK_LAYERS: dict[int, Callable[[bytes], tuple[int, int] | None]] = {
    LINKTYPE_LINUX_SLL: lambda d: (struct.unpack_from("!H", d, 14)[0], 16),
    LINKTYPE_LINUX_SLL2: lambda d: (struct.unpack_from("!H", d, 0)[0], 20),
    LINKTYPE_RAW: lambda d: (_ip_version(d, 0), 0),
    LINKTYPE_RAW_DLT12: lambda d: (_ip_version(d, 0), 0),
    LINKTYPE_RAW_DLT14: lambda d: (_ip_version(d, 0), 0),
    LINKTYPE_IPV4: lambda d: (_ETYPE_IPV4, 0),
    LINKTYPE_IPV6: lambda d: (_ETYPE_IPV6, 0),
    LINKTYPE_NULL: lambda d: _null_family(d, "<"),
    LINKTYPE_LOOP: lambda d: _null_family(d, ">"),
}

def network_offset(linktype: int, data: bytes) -> int | None:
    """Where the IPv4/IPv6 header of a packet starts (link types with a fixed header only;
    None for anything else)."""
    try:
        if linktype == LINKTYPE_ETHERNET:
            off = 12
            etype = struct.unpack_from("!H", data, off)[0]
            while etype in (0x8100, 0x88A8):
                off += 4
                etype = struct.unpack_from("!H", data, off)[0]
            return off + 2 if etype in (_ETYPE_IPV4, _ETYPE_IPV6) else None
        link = _LINK_LAYERS.get(linktype)
        found = link(data) if link is not None else None
    except (struct.error, IndexError):
        return None
    return found[1] if found is not None and found[0] in (_ETYPE_IPV4, _ETYPE_IPV6) else None


#: link types no IP rides on here (serial captures): never handed to scapy
_NOT_IP = frozenset(range(147, 163))
_scapy_classes: dict[int, Any] = {}


def _scapy_link(linktype: int, data: bytes) -> tuple[int, bytes] | None:
    """Any other link type scapy knows (802.11, PPP, ...): scapy dissects the packet, and the
    IP layer inside it, as bytes, comes back with its EtherType. Rare, so scapy is only
    imported when such a capture is read."""
    if linktype in _NOT_IP:
        return None
    cls = _scapy_classes.get(linktype, False)
    if cls is False:
        from scapy.config import conf  # noqa: PLC0415 - slow import, rare path
        from scapy.layers import all as _layers  # noqa: F401, PLC0415 - fills conf.l2types

        cls = _scapy_classes[linktype] = conf.l2types.get(linktype)
    if cls is None:
        return None
    from scapy.layers.inet import IP  # noqa: PLC0415
    from scapy.layers.inet6 import IPv6  # noqa: PLC0415

    pkt = cls(data)
    for layer, etype in ((IP, _ETYPE_IPV4), (IPv6, _ETYPE_IPV6)):
        inner = pkt.getlayer(layer)
        if inner is not None:
            return etype, bytes(inner)
    return None


# -- network and transport layers -----------------------------------------------------------

#: IPv6 extension headers Wireshark walks: Hop-by-Hop, Routing, Fragment, Destination
#: Options (8-octet units) and the Authentication Header (4-octet units)
_IPV6_HOPOPT, _IPV6_ROUTING, _IPV6_FRAGMENT, _IPV6_DSTOPTS, _IPPROTO_AH = 0, 43, 44, 60, 51
_IPV6_EXTENSIONS = frozenset({_IPV6_HOPOPT, _IPV6_ROUTING, _IPV6_FRAGMENT, _IPV6_DSTOPTS, _IPPROTO_AH})


def _decode(linktype: int, data: bytes, reasm: Reassembler | None) -> Datagram | None:
    if linktype == LINKTYPE_ETHERNET:
        off = 12
        etype = struct.unpack_from("!H", data, off)[0]
        off += 2
        while etype in (0x8100, 0x88A8):
            etype = struct.unpack_from("!H", data, off + 2)[0]
            off += 4
    else:
        link = _LINK_LAYERS.get(linktype)
        if link is not None:
            found = link(data)
        else:
            inner = _scapy_link(linktype, data)
            found = None if inner is None else (inner[0], 0)
            if inner is not None:
                data = inner[1]
        if found is None:
            return None
        etype, off = found
    if etype == _ETYPE_IPV4:
        ip = _ipv4(data, off, reasm)
    elif etype == _ETYPE_IPV6:
        ip = _ipv6(data, off, reasm)
    else:
        return None
    return None if ip is None else _transport(*ip)


#: what an IP header gives the transport: protocol, addresses, the bytes, where its header starts and ends
_Ip = tuple[int, str, str, bytes, int, int]


#: an IPv4 header's version and length, total length, flags and fragment offset, protocol, addresses
_IPV4_HEAD = struct.Struct("!BxH2xHxB2x4s4s")
#: addresses as text, by their 4 bytes (a capture has few; cleared past MAX_ADDRESSES)
_ADDRESSES: dict[bytes, str] = {}
MAX_ADDRESSES = 4096


def _address(raw: bytes) -> str:
    a = _ADDRESSES.get(raw)
    if a is None:
        if len(_ADDRESSES) >= MAX_ADDRESSES:
            _ADDRESSES.clear()
        a = _ADDRESSES[raw] = socket.inet_ntoa(raw)
    return a


def _ipv4(data: bytes, off: int, reasm: Reassembler | None) -> _Ip | None:
    """An IPv4 packet at ``off``: its transport (a fragment completed by ``reasm``, None until then)."""
    vihl, tlen, frag, proto, src4, dst4 = _IPV4_HEAD.unpack_from(data, off)
    if vihl >> 4 != 4:
        return None
    ihl = (vihl & 15) * 4
    src, dst = _address(src4), _address(dst4)
    end = min(off + tlen, len(data)) if tlen >= ihl else len(data)
    off += ihl
    if frag & 0x3FFF:  # an offset or more fragments
        if reasm is None:
            return None
        ident = struct.unpack_from("!H", data, off - ihl + 4)[0]
        whole = reasm.add((4, src, dst, ident, proto), (frag & 0x1FFF) * 8, data[off:end], bool(frag & 0x2000))
        if whole is None:
            return None
        data, off, end = whole, 0, len(whole)
    if proto == _IPPROTO_AH:
        proto, off = data[off], off + (data[off + 1] + 2) * 4
    return proto, src, dst, data, off, end


def _ipv6(data: bytes, off: int, reasm: Reassembler | None) -> _Ip | None:
    """An IPv6 packet at ``off``: its transport after the extension headers (a fragment
    completed by ``reasm``, None until then)."""
    proto = data[off + 6]
    plen = struct.unpack_from("!H", data, off + 4)[0]
    src = socket.inet_ntop(socket.AF_INET6, data[off + 8 : off + 24])
    dst = socket.inet_ntop(socket.AF_INET6, data[off + 24 : off + 40])
    off += 40
    end = min(off + plen, len(data)) if plen else len(data)  # 0: a jumbogram
    while proto in _IPV6_EXTENSIONS:
        nxt = data[off]
        if proto == _IPV6_FRAGMENT:
            fo, ident = struct.unpack_from("!HI", data, off + 2)
            off += 8
            if fo & 0xFFF9:  # an offset or more fragments: not an atomic fragment
                if reasm is None:
                    return None
                whole = reasm.add((6, src, dst, ident), fo & 0xFFF8, data[off:end], bool(fo & 1))
                if whole is None:
                    return None
                data, off, end = whole, 0, len(whole)
        elif proto == _IPPROTO_AH:
            off += (data[off + 1] + 2) * 4
        else:
            off += (data[off + 1] + 1) * 8
        proto = nxt
    return proto, src, dst, data, off, end


#: a TCP header's ports, sequence number, data offset and flags
_TCP_HEAD = struct.Struct("!HHI4xBB")


def _transport(proto: int, src: str, dst: str, data: bytes, off: int, end: int) -> Datagram | None:
    if proto == 17:
        if end < off + 8:
            return None
        sport, dport, ulen = struct.unpack_from("!HHH", data, off)
        stop = min(off + ulen, end) if ulen >= 8 else end
        return Datagram("udp", src, dst, sport, dport, data[off + 8 : stop])
    if proto == 6:
        if end < off + 20:
            return None
        sport, dport, seq, doff, flags = _TCP_HEAD.unpack_from(data, off)
        return Datagram("tcp", src, dst, sport, dport, data[off + (doff >> 4) * 4 : end], seq, flags)
    return None


# --- TCP (generated sessions) -----------------------------------------------------------------

TCP_FIN, TCP_SYN, TCP_RST, TCP_PSH, TCP_ACK = 0x01, 0x02, 0x04, 0x08, 0x10


class TcpBuilder:
    """Builds Ethernet/IPv4/TCP segments from one endpoint to another with correct IP and TCP
    checksums (20-byte TCP header, a fixed window)."""

    def __init__(
        self,
        src_ip: str,
        dst_ip: str,
        sport: int,
        dport: int,
        src_mac: str = "02:00:00:00:00:01",
        dst_mac: str = "02:00:00:00:00:02",
        ttl: int = 64,
        window: int = 65535,
    ) -> None:
        self.src = socket.inet_aton(src_ip)
        self.dst = socket.inet_aton(dst_ip)
        self.sport, self.dport, self.ttl, self.window = sport, dport, ttl, window
        self.eth = mac_bytes(dst_mac) + mac_bytes(src_mac) + b"\x08\x00"

    def segment(self, seq: int, ack: int, flags: int, payload: bytes, ip_id: int) -> bytes:
        tcp_len = 20 + len(payload)
        tlen = 20 + tcp_len
        ip = _IP_HDR.pack(0x45, 0, tlen, ip_id & 0xFFFF, 0x4000, self.ttl, 6, 0, self.src, self.dst)
        ip = ip[:10] + struct.pack("!H", ones_complement_checksum(ip)) + ip[12:]
        hdr = struct.pack(
            "!HHIIBBHHH", self.sport, self.dport, seq & 0xFFFFFFFF, ack & 0xFFFFFFFF, 5 << 4, flags, self.window, 0, 0
        )
        pseudo = self.src + self.dst + struct.pack("!BBH", 0, 6, tcp_len)
        ck = ones_complement_checksum(pseudo + hdr + payload)
        return self.eth + ip + hdr[:16] + struct.pack("!H", ck) + hdr[18:] + payload


class TcpConversation:
    """One TCP connection between a client and a server with consistent sequence and
    acknowledgement numbers: :meth:`open` (three-way handshake), :meth:`send` (data from
    either side, acknowledging everything received so far), :meth:`ack`, :meth:`close`.
    Each returns the link-layer frames to write."""

    def __init__(
        self, client_ip: str, client_port: int, server_ip: str, server_port: int, client_isn: int = 1000, server_isn: int = 5000
    ) -> None:
        self.c2s = TcpBuilder(client_ip, server_ip, client_port, server_port, "02:00:00:00:00:01", "02:00:00:00:00:02")
        self.s2c = TcpBuilder(server_ip, client_ip, server_port, client_port, "02:00:00:00:00:02", "02:00:00:00:00:01")
        self.seq = {True: client_isn, False: server_isn}  # next sequence number, by from_client
        self.ip_id = {True: 0, False: 0}

    def _seg(self, from_client: bool, flags: int, payload: bytes = b"") -> bytes:
        b = self.c2s if from_client else self.s2c
        self.ip_id[from_client] += 1
        ack = self.seq[not from_client] if flags & TCP_ACK else 0
        frame = b.segment(self.seq[from_client], ack, flags, payload, self.ip_id[from_client])
        self.seq[from_client] += len(payload) + (1 if flags & (TCP_SYN | TCP_FIN) else 0)
        return frame

    def open(self) -> list[bytes]:
        return [self._seg(True, TCP_SYN), self._seg(False, TCP_SYN | TCP_ACK), self._seg(True, TCP_ACK)]

    def send(self, from_client: bool, payload: bytes) -> bytes:
        return self._seg(from_client, TCP_PSH | TCP_ACK, payload)

    def ack(self, from_client: bool) -> bytes:
        return self._seg(from_client, TCP_ACK)

    def close(self, from_client: bool = True) -> list[bytes]:
        """FIN from one side, FIN+ACK back, final ACK."""
        return [self._seg(from_client, TCP_FIN | TCP_ACK), self._seg(not from_client, TCP_FIN | TCP_ACK), self._seg(from_client, TCP_ACK)]


#: a receiver acknowledges data it has no reply for after this long (Linux's delayed ACK)
DELAYED_ACK_NS = 40_000_000


def session_frames(
    events: Iterable[tuple[int, bool, bytes]],
    transport: str,
    client: tuple[str, int],
    server: tuple[str, int],
    start_ns: int | None = None,
    close: bool = True,
) -> Iterator[tuple[int, bool, bytes]]:
    """Link-layer frames ``(ts_ns, from_client, frame)`` for a client/server exchange given
    as time-ordered ``(ts_ns, from_client, payload)`` events.

    ``udp``: one datagram per event. ``tcp``: a real conversation: the three-way handshake
    just before the first event (or at ``start_ns``), one segment per event acknowledging all
    received data, a pure ACK from a receiver that has nothing to send within
    :data:`DELAYED_ACK_NS`, and (``close``) a FIN exchange after the last event.
    """
    if transport == "udp":
        c2s = UdpBuilder(client[0], server[0], client[1], server[1], "02:00:00:00:00:01", "02:00:00:00:00:02")
        s2c = UdpBuilder(server[0], client[0], server[1], client[1], "02:00:00:00:00:02", "02:00:00:00:00:01")
        ip_id = 0
        for ts, from_client, payload in events:
            ip_id = (ip_id + 1) & 0xFFFF
            yield ts, from_client, (c2s if from_client else s2c).frame(payload, ip_id)
        return
    if transport != "tcp":
        raise ValueError(f"unknown transport {transport!r} (udp or tcp)")
    conv = TcpConversation(client[0], client[1], server[0], server[1])
    pending_ack: dict[bool, int | None] = {True: None, False: None}  # side -> ACK due time
    opened = False
    last_ts = start_ns or 0

    def flush(until: int) -> Iterator[tuple[int, bool, bytes]]:
        for side in sorted((s for s in (True, False) if pending_ack[s] is not None), key=lambda s: pending_ack[s] or 0):
            due = pending_ack[side]
            if due is not None and due <= until:
                pending_ack[side] = None
                yield due, side, conv.ack(side)

    for ts, from_client, payload in events:
        if not opened:
            t0 = start_ns if start_ns is not None else ts - 300_000
            t0 = min(t0, ts - 300_000)
            for i, frame in enumerate(conv.open()):
                yield t0 + i * 50_000, i != 1, frame
            opened = True
        yield from flush(ts)
        pending_ack[from_client] = None  # this segment carries the ACK
        yield ts, from_client, conv.send(from_client, payload)
        if pending_ack[not from_client] is None:
            pending_ack[not from_client] = ts + DELAYED_ACK_NS
        last_ts = ts
    if opened:
        yield from flush(last_ts + DELAYED_ACK_NS)
        if close:
            t = last_ts + DELAYED_ACK_NS + 1_000_000
            for i, frame in enumerate(conv.close(True)):
                yield t + i * 50_000, i != 1, frame


def write_session(
    out: BinaryIO,
    fmt: str,
    events: Iterable[tuple[int, bool, bytes]],
    transport: str,
    client: tuple[str, int],
    server: tuple[str, int],
) -> int:
    """Write a client/server exchange (time-ordered ``(ts_ns, from_client, payload)``) as a
    capture over ``transport``; in pcapng the client's packets are outbound. Returns the
    number of records written."""
    writer = make_writer(out, fmt)
    records = [
        writer.record(ts, frame, DIR_OUTBOUND if from_client else DIR_INBOUND)
        for ts, from_client, frame in session_frames(events, transport, client, server)
    ]
    out.write(b"".join(records))
    return len(records)
