"""The expand sink (``sharedlink expand``): a run of one direction's records taken straight from a
classic pcap block with the counts and columns tiers' pattern
(:class:`~sharedlink.analysis.core.lanes.ColLane`, :func:`~sharedlink.analysis.core.lanes.walk_run`),
each frame written back as the full set its direction holds after it, in a new record.

What :class:`~sharedlink.analysis.transform.Rewriter` makes of such a frame one at a time (the
reference path: every value the table holds, in table order, ``|T t|Q name|D value``; the IPv4
and UDP lengths and checksums made right; a packet whose payload stays the same copied as it
was), made a run at a time: the values a frame carries forward-filled per variable at C speed,
each frame's text one ``%`` of the run's template, its checksum by ``zlib.adler32``, the IPv4
and UDP checksums from the headers' words and the payload read as one integer.
``tests/analysis/test_expand_runs.py`` compares the two byte for byte.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from itertools import accumulate, chain, compress, repeat
from operator import add, is_not, sub
from typing import TYPE_CHECKING
from zlib import adler32

from sharedlink.analysis.core.checksum import ADLER_MAX
from sharedlink.analysis.core.lanes import ColLane, lane_at, walk_run
from sharedlink.analysis.core.patterns import SWAP16
from sharedlink.capture.pcapio import NS

if TYPE_CHECKING:
    from sharedlink.analysis.core.decoder import Decoder

#: frames a run takes at most
RUN_FRAMES = 4096
#: the longest UDP payload an IPv4 packet without options holds
MAX_PAYLOAD = 0xFFFF - 28
#: the first time a nanosecond pcap record cannot hold (ns)
PCAP_END = (1 << 32) * NS
#: a record written: its pcap header (nanoseconds), then the packet's Ethernet header, and the
#: IPv4 and UDP headers' 16-bit fields (each as :data:`SWAP16` gives it: big-endian), addresses
#: and ports
RECORD = struct.Struct("<IIII14sHHHHHH12sHH")
#: from byte 14 of the packet: the IPv4 header's first word, identification, flags and fragment
#: offset, TTL and protocol; the UDP checksum
WORDS = struct.Struct("!HxxHHHxx12xxxH")
#: a frame's end after its checksum's ``C``: the two digits, ``]`` and CR LF
TAILS = [b"%02X]\r\n" % i for i in range(256)]


class FullSets:
    """Expand only: the run taker offered each record of a classic little-endian Ethernet pcap
    file (:func:`~sharedlink.capture.pcap_blocks.walk_pcap`'s ``offer``). It takes a run of one
    direction's records that ``dec`` (the input's core) has a :class:`ColLane` for and that
    ``accept`` (the direction's key) allows, while :func:`walk_run` takes them, follows them in
    the direction's table (as the reference path would) and appends each one's new record
    (pcap header and packet) to :attr:`out`; :attr:`bytes_in`, :attr:`bytes_out`: the frames'
    bytes read and written since the caller last took them, :attr:`taken`: the frames taken in all."""

    def __init__(self, dec: Decoder, accept: Callable[[tuple], bool]) -> None:
        self.dec, self.accept = dec, accept
        self.out: list[bytes] = []
        self.bytes_in = self.bytes_out = 0
        self.taken = 0  # frames taken in all

    def run(self, buf: bytes, sbuf: str, off: int, number: int, mult: int) -> tuple[int, int, int, int] | None:
        """The offer: ``(offset after the run, its last number, frames, their records' bytes)``,
        or None when the record at ``off`` is not one (the caller rewrites it the usual way)."""
        dec = self.dec
        lane = lane_at(dec._hot, dec._lanes, buf, off)
        if lane is None or not self.accept(lane.hkey):
            return None
        vs = lane.vs
        cur = [v.text for v in vs]
        unvalued = [i for i, text in enumerate(cur) if text is None]  # (a frame giving one a value: not taken)
        end, groups, stamps, raws, wire = walk_run(lane, buf, sbuf, off, RUN_FRAMES, mult, unvalued)
        n = len(groups)
        if not n:
            return None
        valued = [i for i, text in enumerate(cur) if text is not None]
        cols = list(zip(*groups))
        filled, last = zip(*(_forward_fill(cols[i], cur[i]) for i in valued)) if valued else ((), ())
        payloads = _payloads(_template(lane, valued), filled, n)
        if max(map(len, payloads)) > MAX_PAYLOAD or max(stamps) >= PCAP_END:
            return None  # (a full set past one datagram, a time past 2106: the frame-at-a-time path says where)
        offs = accumulate(map((58).__add__, map(len, raws[:-1])), initial=off)  # (records: 58 bytes, then the frame)
        self.out += map(_record, repeat(buf), offs, stamps, raws, payloads, repeat(_sums(buf, off)))
        self.bytes_in += wire - 42 * n
        self.bytes_out += sum(map(len, payloads))
        _write_back(lane, groups, stamps, number + 1, valued, [filled[k][-1] for k in range(len(valued))], last)
        dec.fast += n
        self.taken += n
        return end, number + n, n, wire


def _forward_fill(col: tuple, first: str) -> tuple[list[str], int]:
    """A variable's values over a run's frames (``col``: its group in each, None where the
    frame leaves it out), each frame's the last one given up to it (``first`` before any), and
    the index of the last frame that gave one (-1: none)."""
    n = len(col)
    present = list(map(is_not, col, repeat(None)))
    at = list(compress(range(n), present))
    if not at:
        return [first] * n, -1
    held = map(sub, [*at[1:], n], at)  # frames each value holds for
    return [first] * at[0] + list(chain.from_iterable(map(repeat, compress(col, present), held))), at[-1]


def _template(lane: ColLane, valued: list[int]) -> str:
    """A full set of the lane's direction up to its checksum's ``C``, ``%s`` for each value."""
    names, types = lane.names, lane.types
    return "[:%s%s|N0%s|C" % (lane.dst, lane.src, "".join(
        "|T%d|Q%s|D%%s" % (types[i], names[i].replace("%", "%%")) for i in valued))


def _payloads(template: str, filled: tuple, n: int) -> list[bytes]:
    """Each frame of a run as the full set its values fill in, checksum and CR LF made."""
    bodies = [(template % row).encode("latin-1") for row in zip(*filled)] if filled else [template.encode("latin-1")] * n
    # the checksum is the byte sum after "[" (91): adler32's low half is 1 + the sum, its high
    # half a multiple of 256, for up to ADLER_MAX bytes
    if max(map(len, bodies)) <= ADLER_MAX:
        sums = map(sub, map(adler32, bodies), repeat(92))
    else:
        sums = map(sub, map(sum, bodies), repeat(91))
    return list(map(add, bodies, map(TAILS.__getitem__, map((255).__and__, sums))))


def _sums(buf: bytes, off: int) -> tuple[int, int]:
    """The run's addresses (the IPv4 header's last four words) and, for the UDP checksum, its
    addresses, ports and protocol, summed as 16-bit words modulo 0xFFFF (the same in every record)."""
    addrs = int.from_bytes(buf[off + 42 : off + 50], "big") % 0xFFFF
    return addrs, (addrs + int.from_bytes(buf[off + 50 : off + 54], "big") + 17) % 0xFFFF


def _record(buf: bytes, off: int, ts: int, raw: bytes, payload: bytes, sums: tuple[int, int]) -> bytes:
    """The new record of the record at ``off`` (time ``ts``, its frame ``raw``) with UDP payload
    ``payload``: the packet copied when the payload is the same, else its IPv4 and UDP lengths
    and checksums made as :func:`~sharedlink.analysis.transform.replace_udp_payload` makes
    them (the IPv4 header summed again; a UDP checksum where the packet had one). The one's
    complement sum of 16-bit words is their sum modulo 0xFFFF: each field's word added."""
    sec, nsec = divmod(ts, NS)
    if payload == raw:
        incl = 42 + len(raw)
        return struct.pack("<IIII", sec, nsec, incl, incl) + buf[off + 16 : off + 16 + incl]
    size = len(payload)
    w0, ident, frag, ttl_proto, uck = WORDS.unpack_from(buf, off + 30)
    tl, ul = 28 + size, 8 + size
    r = (w0 + tl + ident + frag + ttl_proto + sums[0]) % 0xFFFF
    ipck = 0xFFFF - r if r else 0
    if uck:
        r = (sums[1] + 2 * ul + (int.from_bytes(payload, "big") << (size & 1) * 8)) % 0xFFFF
        uck = 0xFFFF - r
    return RECORD.pack(sec, nsec, 42 + size, 42 + size, buf[off + 16 : off + 30], SWAP16[w0], SWAP16[tl],
                       SWAP16[ident], SWAP16[frag], SWAP16[ttl_proto], SWAP16[ipck], buf[off + 42 : off + 54],
                       SWAP16[ul], SWAP16[uck]) + payload


def _write_back(lane: ColLane, groups: list[tuple], stamps: list[int], first: int, valued: list[int], texts: list[str],
                last: tuple[int, ...]) -> None:
    """The end of a run (its frames numbered from ``first``): each variable's text and the frame
    that last set it, the direction's last full set (a frame holding every variable with a value)
    and its sync clock, as the reference path leaves them."""
    h, vs = lane.h, lane.vs
    for i, text, j in zip(valued, texts, last):
        if j >= 0:
            v = vs[i]
            v.text, v.set_in, v.set_at = text, first + j, stamps[j]
    nones = list(map(tuple.count, groups, repeat(None)))
    full_nones = len(vs) - len(valued)
    if valued and full_nones in nones:
        j = len(nones) - 1 - nones[::-1].index(full_nones)
        h.table.last_full_at, h.table.last_full_in = stamps[j], first + j
        h.sync[1] = stamps[j]  # (each full set resets the clock: the last one is what stays)
    h.last.clear()  # (the Updates kept for reuse hold values the run replaced)
