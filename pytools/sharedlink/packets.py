"""Link, IPv4, UDP and TCP headers: fast building of beacon datagrams and decoding of captured
packets down to their transport payload."""

from __future__ import annotations

import socket
import struct
from dataclasses import dataclass

from .pcapio import LINKTYPE_ETHERNET, LINKTYPE_LINUX_SLL, LINKTYPE_NULL, LINKTYPE_RAW

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
        """The Ethernet, IPv4 and UDP headers for ``payload`` (its length is ``plen``)."""
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


@dataclass(frozen=True)
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
    """Strip link, IPv4/IPv6 and UDP/TCP headers. None when the packet is something else or
    too short. Never raises."""
    try:
        return _decode(linktype, data)
    except (struct.error, IndexError, ValueError, OSError):
        return None


def _decode(linktype: int, data: bytes) -> Datagram | None:
    if linktype == LINKTYPE_ETHERNET:
        off = 12
        etype = struct.unpack_from("!H", data, off)[0]
        off += 2
        while etype in (0x8100, 0x88A8):
            etype = struct.unpack_from("!H", data, off + 2)[0]
            off += 4
    elif linktype == LINKTYPE_LINUX_SLL:
        etype = struct.unpack_from("!H", data, 14)[0]
        off = 16
    elif linktype == LINKTYPE_RAW:
        etype = 0x0800 if data[0] >> 4 == 4 else 0x86DD
        off = 0
    elif linktype == LINKTYPE_NULL:
        fam = struct.unpack_from("<I", data, 0)[0]
        etype = 0x0800 if fam == 2 else 0x86DD
        off = 4
    else:
        return None
    if etype == 0x0800:
        vihl = data[off]
        if vihl >> 4 != 4:
            return None
        ihl = (vihl & 15) * 4
        tlen = struct.unpack_from("!H", data, off + 2)[0]
        frag = struct.unpack_from("!H", data, off + 6)[0]
        if frag & 0x1FFF or frag & 0x2000:
            return None  # fragments are not reassembled
        proto = data[off + 9]
        src = socket.inet_ntoa(data[off + 12 : off + 16])
        dst = socket.inet_ntoa(data[off + 16 : off + 20])
        end = off + tlen if tlen >= ihl else len(data)
        off += ihl
    elif etype == 0x86DD:
        proto = data[off + 6]
        plen = struct.unpack_from("!H", data, off + 4)[0]
        src = socket.inet_ntop(socket.AF_INET6, data[off + 8 : off + 24])
        dst = socket.inet_ntop(socket.AF_INET6, data[off + 24 : off + 40])
        off += 40
        end = off + plen
    else:
        return None
    if proto == 17:
        if len(data) < off + 8:
            return None
        sport, dport, ulen = struct.unpack_from("!HHH", data, off)
        stop = min(off + ulen, end, len(data)) if ulen >= 8 else min(end, len(data))
        return Datagram("udp", src, dst, sport, dport, data[off + 8 : stop])
    if proto == 6:
        if len(data) < off + 20:
            return None
        sport, dport, seq = struct.unpack_from("!HHI", data, off)
        doff = (data[off + 12] >> 4) * 4
        flags = data[off + 13]
        return Datagram("tcp", src, dst, sport, dport, data[off + doff : min(end, len(data))], seq, flags)
    return None
