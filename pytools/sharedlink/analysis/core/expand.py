"""The expand sink (``sharedlink expand``): a run of one direction's records taken straight from a
classic pcap block with the counts and columns tiers' pattern
(:class:`~sharedlink.analysis.core.lanes.ColLane`, :func:`~sharedlink.analysis.core.lanes.walk_run`;
a positional direction's :class:`~sharedlink.analysis.core.expand_lanes.PosLane`), or from a
pcapng file's records one at a time (:meth:`FullSets.packet`), each frame written back as the
full set its direction holds after it, in a new record.

What :class:`~sharedlink.analysis.transform.Rewriter` makes of such a frame one at a time (the
reference path: every value the table holds, in table order, ``|T t|Q name|D value``, or every
slot of the positional full set, ``|D value``; the IPv4 and UDP lengths and checksums made
right; a packet whose payload stays the same copied as it was), made a run at a time: the
values a frame carries forward-filled per variable at C speed, each frame's text one ``%`` of
the run's template, its checksum by ``zlib.adler32``, the IPv4 and UDP checksums from the
headers' words and the payload read as one integer. ``tests/analysis/test_expand_runs.py``
compares the two byte for byte.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from itertools import accumulate, chain, compress, repeat
from operator import add, is_not, sub
from typing import TYPE_CHECKING
from zlib import adler32

from sharedlink.analysis.core.checksum import ADLER_MAX
from sharedlink.analysis.core.direction import Direction
from sharedlink.analysis.core.expand_lanes import Plan, PosLane, named_plan, packet_groups, pos_plan
from sharedlink.analysis.core.lanes import ColLane, direction_key, lane_for, walk_run
from sharedlink.analysis.core.patterns import SWAP16
from sharedlink.capture.pcapio import NS
from sharedlink.protocols.limits import MAX_CONVERSATIONS

if TYPE_CHECKING:
    from sharedlink.analysis.core.decoder import Decoder

#: frames a run takes at most
RUN_FRAMES = 4096
#: the longest UDP payload an IPv4 packet without options holds
MAX_PAYLOAD = 0xFFFF - 28
#: the first time a nanosecond pcap record cannot hold (ns)
PCAP_END = (1 << 32) * NS
#: the first time a pcapng record cannot hold (ns; none before 1970 either)
PCAPNG_END = 1 << 64
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
    file (:func:`~sharedlink.capture.pcap_blocks.walk_pcap`'s ``offer``: :meth:`run`) and, in a
    pcapng file, each Ethernet record (:meth:`packet`). It takes a run of one direction's records
    that ``dec`` (the input's core) has a lane for (:class:`ColLane` named, :class:`PosLane`
    positional) and that ``accept`` (the direction's key) allows for the lane's form (True: the
    direction is written in the named form), while :func:`walk_run` (:func:`packet_groups`)
    takes them, follows them in the direction's table (as the reference path would) and appends
    each one's new record (pcap: its header and packet; pcapng: the packet, for the caller's
    writer) to :attr:`out`; :attr:`frames`, :attr:`bytes_in`, :attr:`bytes_out`: the frames in
    :attr:`out` and their bytes read and written, :attr:`taken`: the frames taken in all."""

    def __init__(self, dec: Decoder, accept: Callable[[tuple], bool]) -> None:
        self.dec, self.accept = dec, accept
        self.out: list = []
        self.frames = self.bytes_in = self.bytes_out = 0
        self.taken = 0  # frames taken in all
        self.pos: dict[bytes, PosLane] = {}  # addresses, ports and letters -> positional lane
        self.pending: Pending | None = None  # pcapng: the run taken so far
        self.redo: list[tuple] = []  # pcapng: the records of a run given back (the caller rewrites them)
        self.skip = self.miss = 0  # pcapng: records not offered, misses in a row (as walk_pcap's)

    def lane(self, key: bytes) -> tuple[ColLane | PosLane, Plan] | None:
        """The lane and plan of a record whose ``key`` (:func:`lane_for`) was read, if any."""
        dec = self.dec
        lane = lane_for(dec._hot, dec._lanes, key)
        if lane is not None:
            return (lane, named_plan(lane)) if self.accept(lane.hkey) else None
        pos = self.pos.get(key)
        hkey = direction_key(key) if pos is None else pos.hkey
        h = dec._hot.get(hkey)
        if h is None:
            return None
        if pos is None or pos.h is not h or pos.stamp != h.version:
            if len(self.pos) >= MAX_CONVERSATIONS:
                self.pos.clear()
            pos = self.pos[key] = PosLane(h, hkey, h.version, key)
        if pos.rx is None or self.accept(hkey):  # (a direction written named: its bare N0 too)
            return None
        return pos, pos_plan(pos)

    def run(self, buf: bytes, sbuf: str, off: int, number: int, mult: int) -> tuple[int, int, int, int] | None:
        """The offer: ``(offset after the run, its last number, frames, their records' bytes)``,
        or None when the record at ``off`` is not one (the caller rewrites it the usual way)."""
        got = self.lane(buf[off + 42 : off + 54] + buf[off + 60 : off + 62]) if len(buf) >= off + 62 else None
        if got is None:
            return None
        lane, plan = got
        end, groups, stamps, raws, wire = walk_run(lane, buf, sbuf, off, RUN_FRAMES, mult, plan.unvalued)
        n = len(groups)
        if not n:
            return None
        made = _full_sets(plan, groups)
        if made is None or max(stamps) >= PCAP_END:
            return None  # (a full set past one datagram, a time past 2106: the frame-at-a-time path says where)
        payloads, filled, last = made
        offs = accumulate(map((58).__add__, map(len, raws[:-1])), initial=off + 16)  # (records: 58 bytes, then the frame)
        self.out += map(_record, repeat(buf), offs, stamps, raws, payloads, repeat(_sums(buf, off + 16)))
        self.bytes_in += wire - 42 * n
        self._taken(lane, plan, groups, stamps, number + 1, payloads, filled, last)
        return end, number + n, n, wire

    def packet(self, number: int, ts: int, data: bytes, flags: int, iface: int) -> bool:
        """A pcapng file's Ethernet record (``iface``: its interface): True when it is
        taken into the run (written with it when the run ends: :meth:`flush`), False when the
        caller rewrites it the usual way (after what :attr:`out` and :attr:`redo` hold: a run
        this record ended)."""
        p = self.pending
        if p is not None:
            g = packet_groups(p.lane.rx, p.lane.key, data, p.plan.unvalued) if len(p.groups) < RUN_FRAMES else None
            if g is not None:
                p.add(g, ts, data, flags, iface)
                return True
            if not self.flush():
                return False  # (the run given back comes first)
        if self.skip:
            self.skip -= 1
            return False
        got = self.lane(data[26:38] + data[44:46]) if len(data) >= 46 else None
        g = packet_groups(got[0].rx, got[0].key, data, got[1].unvalued) if got is not None else None
        if g is None:
            self.skip, self.miss = self.miss, min(2 * self.miss + 1, 63)
            return False
        self.miss = 0
        self.pending = Pending(got[0], got[1], number)
        self.pending.add(g, ts, data, flags, iface)
        return True

    def flush(self) -> bool:
        """The end of a pcapng run: its records' packets to :attr:`out` as ``(time, packet,
        flags, interface)``; False when a full set would not fit in one datagram (or a time in a
        pcapng record: an interface's time offset may take one before 1970): then the run is
        given back, its records to :attr:`redo`."""
        p, self.pending = self.pending, None
        if p is None:
            return True
        made = _full_sets(p.plan, p.groups)
        if made is None or not 0 <= min(p.stamps) <= max(p.stamps) < PCAPNG_END:
            self.redo += zip(range(p.first, p.first + len(p.groups)), p.stamps, p.packets, p.flags, p.ifaces)
            return False
        payloads, filled, last = made
        packets = map(_record, p.packets, repeat(0), p.stamps, p.raws, payloads, repeat(_sums(p.packets[0], 0)))
        self.out += zip(p.stamps, map(bytes.__getitem__, packets, repeat(slice(16, None))), p.flags, p.ifaces)
        self.bytes_in += sum(map(len, p.raws))
        self._taken(p.lane, p.plan, p.groups, p.stamps, p.first, payloads, filled, last)
        return True

    def _taken(self, lane: ColLane | PosLane, plan: Plan, groups: list[tuple], stamps: list[int], first: int,
               payloads: list[bytes], filled: tuple, last: tuple) -> None:
        """A run taken (its frames numbered from ``first``): counted, the table written back."""
        n = len(groups)
        self.bytes_out += sum(map(len, payloads))
        _write_back(lane.h, plan, groups, stamps, first, [col[-1] for col in filled], last)
        self.dec.fast += n
        self.frames += n
        self.taken += n


class Pending:
    """A pcapng run taken so far (:meth:`FullSets.packet`): its lane, plan, first record's
    number, and each record's groups, time, frame, packet, flags and interface."""

    __slots__ = ("lane", "plan", "first", "groups", "stamps", "raws", "packets", "flags", "ifaces")

    def __init__(self, lane: ColLane | PosLane, plan: Plan, first: int) -> None:
        self.lane, self.plan, self.first = lane, plan, first
        self.groups: list[tuple] = []
        self.stamps: list[int] = []
        self.raws: list[bytes] = []
        self.packets: list[bytes] = []
        self.flags: list[int] = []
        self.ifaces: list[int] = []

    def add(self, g: tuple, ts: int, data: bytes, flags: int, iface: int) -> None:
        self.groups.append(g)
        self.stamps.append(ts)
        self.raws.append(data[42:])
        self.packets.append(data)
        self.flags.append(flags)
        self.ifaces.append(iface)


def _full_sets(plan: Plan, groups: list[tuple]) -> tuple[list[bytes], tuple, tuple] | None:
    """A run's full sets (each frame's payload), each valued group's values forward filled and
    the index of its last frame that gave one; None when one is past one datagram."""
    n = len(groups)
    cur = plan.cur
    valued = plan.valued
    cols = list(zip(*groups))
    filled, last = zip(*(_forward_fill(cols[i], cur[i] or "") for i in valued)) if valued else ((), ())
    payloads = _payloads(plan.template, filled, n)
    return None if max(map(len, payloads)) > MAX_PAYLOAD else (payloads, filled, last)


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


def _sums(pkt: bytes, at: int) -> tuple[int, int]:
    """The run's addresses (the IPv4 header's last four words) and, for the UDP checksum, its
    addresses, ports and protocol, summed as 16-bit words modulo 0xFFFF (the same in every record):
    of the packet at ``at`` of ``pkt``."""
    addrs = int.from_bytes(pkt[at + 26 : at + 34], "big") % 0xFFFF
    return addrs, (addrs + int.from_bytes(pkt[at + 34 : at + 38], "big") + 17) % 0xFFFF


def _record(pkt: bytes, at: int, ts: int, raw: bytes, payload: bytes, sums: tuple[int, int]) -> bytes:
    """The new pcap record (header and packet) of the packet at ``at`` of ``pkt`` (time ``ts``,
    its frame ``raw``) with UDP payload ``payload``: the packet copied when the payload is the
    same, else its IPv4 and UDP lengths and checksums made as
    :func:`~sharedlink.analysis.transform.replace_udp_payload` makes them (the IPv4 header
    summed again; a UDP checksum where the packet had one). The one's complement sum of 16-bit
    words is their sum modulo 0xFFFF: each field's word added."""
    sec, nsec = divmod(ts, NS)
    if payload == raw:
        incl = 42 + len(raw)
        return struct.pack("<IIII", sec, nsec, incl, incl) + pkt[at : at + incl]
    size = len(payload)
    w0, ident, frag, ttl_proto, uck = WORDS.unpack_from(pkt, at + 14)
    tl, ul = 28 + size, 8 + size
    r = (w0 + tl + ident + frag + ttl_proto + sums[0]) % 0xFFFF
    ipck = 0xFFFF - r if r else 0
    if uck:
        r = (sums[1] + 2 * ul + (int.from_bytes(payload, "big") << (size & 1) * 8)) % 0xFFFF
        uck = 0xFFFF - r
    return RECORD.pack(sec, nsec, 42 + size, 42 + size, pkt[at : at + 14], SWAP16[w0], SWAP16[tl],
                       SWAP16[ident], SWAP16[frag], SWAP16[ttl_proto], SWAP16[ipck], pkt[at + 26 : at + 38],
                       SWAP16[ul], SWAP16[uck]) + payload


def _write_back(h: Direction, plan: Plan, groups: list[tuple], stamps: list[int], first: int, texts: list[str],
                last: tuple[int, ...]) -> None:
    """The end of a run (its frames numbered from ``first``): each valued variable's text and the
    frame that last set it, the direction's last full set and its sync clock, as the reference
    path leaves them."""
    vs = plan.vs
    for i, text, j in zip(plan.valued, texts, last):
        if j >= 0:
            v = vs[i]
            v.text, v.set_in, v.set_at = text, first + j, stamps[j]
    nones = list(map(tuple.count, groups, repeat(None)))
    full_nones = plan.full_nones
    if full_nones in nones:
        j = len(nones) - 1 - nones[::-1].index(full_nones)
        h.table.last_full_at, h.table.last_full_in = stamps[j], first + j
        h.sync[1] = stamps[j]  # (each full set resets the clock: the last one is what stays)
    h.last.clear()  # (the Updates kept for reuse hold values the run replaced)
