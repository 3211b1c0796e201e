"""What the fast tiers' patterns share: the value class of a compiled layout, the compiled
patterns' cache, and the one test of a plain Ethernet/IPv4/UDP record in a classic pcap block.
"""

from __future__ import annotations

import re
import struct
from array import array
from collections.abc import Callable

#: a value as a compiled layout takes it (a frame with any other goes the reference path)
CV = rb"[^|\x00-\x1f\[\]]"
#: a direction with more variables than this gets no compiled layouts (a steady state is narrow;
#: a pattern of every name of a wide table, rebuilt as it grows, would cost more than it saves)
MAX_COMPILED_VARS = 64
#: compiled patterns, shared by the directions that have the same layouts; emptied at this many
MAX_PATTERNS = 1024
_PATTERNS: dict[bytes, Callable] = {}
_STR_PATTERNS: dict[str, Callable] = {}  # the columns lanes' text patterns, bounded the same


def cached_pattern(cache: dict, bound: int, pattern: bytes | str, method: str) -> Callable:
    """``re.compile(pattern).<method>``, kept in ``cache`` (emptied once it holds ``bound``)."""
    rx = cache.get(pattern)
    if rx is None:
        if len(cache) >= bound:
            cache.clear()
        rx = cache[pattern] = getattr(re.compile(pattern), method)
    return rx


def fullmatch(pattern: bytes | str) -> Callable:
    return cached_pattern(_PATTERNS if isinstance(pattern, bytes) else _STR_PATTERNS, MAX_PATTERNS, pattern,
                          "fullmatch")


#: a classic pcap record header, then from byte 12 of an Ethernet packet: the type and the IP
#: version and header length (3 bytes), IP total length, flags and fragment offset, protocol,
#: the addresses and UDP ports (12 bytes: the conversation), UDP length: the 16-bit fields
#: little-endian, compared through SWAP16; the fragment field is 0, or 0x40 for "don't fragment"
PCAP_UDP = struct.Struct("<IIII12x3sxHxxHxB2x12sH")
SWAP16 = array("H", range(65536))
SWAP16.byteswap()  # x with its two bytes swapped
SWAP16 = SWAP16.tolist()


#: Ethernet II, IPv4 without options (IHL 5): bytes 12..14 of the packet
ETH_IPV4 = b"\x08\x00\x45"
#: the IP protocol number of UDP
UDP = 17


def plain_udp(eth: bytes, tl: int, frag: int, proto: int, incl: int, ul: int) -> bool:
    """Whether a classic pcap record whose header and packet :data:`PCAP_UDP` unpacked is one
    whole Ethernet/IPv4/UDP datagram (no IP options, not a fragment, IP and UDP lengths that
    match the captured length, 50 < length <= 65000): the record test every per-record loop of
    the fast tiers makes (they write it out, the same expression, where a call a record counts)."""
    return (eth == ETH_IPV4 and proto == UDP and not frag & 0xFFBF and 50 < incl <= 65000
            and tl == SWAP16[incl - 14] and ul == SWAP16[incl - 34])
