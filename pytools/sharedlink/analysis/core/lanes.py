"""The run takers of the counts and columns sinks: one direction's records taken straight from a
classic pcap block (:class:`ColLane`: its pattern; :func:`walk_run`: the walk)."""

from __future__ import annotations

import re
import socket
import struct
from collections.abc import Callable

from sharedlink.analysis.core.checksum import frame_ok
from sharedlink.analysis.core.direction import Direction
from sharedlink.analysis.core.patterns import MAX_COMPILED_VARS, PCAP_UDP, fullmatch, plain_udp
from sharedlink.capture.pcapio import NS
from sharedlink.protocols.limits import MAX_CONVERSATIONS


class ColLane:
    """Columns and counts only: one direction's run taker (:meth:`Decoder.column_run`,
    :meth:`Decoder.count_run`), the compiled-layout technique on rows and on counts. Made only
    for a direction in its steady state: named, every variable with a value typed and sent
    (then a frame is full when it holds every variable with a value; a frame that would give a
    first value is left to the other paths), at most
    :data:`MAX_COMPILED_VARS` variables; one str pattern on the latin-1 block, every typed
    variable in table order as an optional ``|T t|Q name|D value``. ``stamp``: the state it was
    made for (the direction's version, its variable and sent-name counts, its form); any other
    state and it is made again."""

    __slots__ = ("h", "hkey", "key", "conv", "src", "dst", "stamp", "rx", "names", "types", "vs", "carry")

    def __init__(self, h: Direction, hkey: tuple, stamp: tuple, key: bytes = b"") -> None:
        self.h, self.hkey, self.stamp, self.key = h, hkey, stamp, key
        self.conv, self.src, self.dst = hkey
        t = h.table
        self.rx: Callable | None = None
        if len(t.vars) > MAX_COMPILED_VARS:
            # too wide for a lane: nothing listed, so a table that grows by new names every frame
            # costs nothing a frame here (a lane walks every variable: quadratic, issue 31)
            self.vs, self.names, self.types, self.carry = [], (), (), ()
            return
        every = list(t.vars.values())
        vs = [v for v in every if v.type_code is not None]
        self.vs = vs
        self.names = tuple(v.name for v in vs)
        self.types = tuple(v.type_code for v in vs)
        # carried values go in the order the direction sent their names first (as the reference's)
        sent = t.sent_names
        self.carry = tuple(sorted(range(len(vs)), key=lambda i: sent.get(vs[i].name, len(sent) + i)))
        if (t.named is True and 0 < len(vs) <= MAX_COMPILED_VARS
                and all(v.type_code is not None for v in every if v.text is not None)
                and {v.name for v in every if v.text is not None} == set(t.sent_names)):
            rx = r"\[:%s%s\|N0%s\|C([0-9A-F]{2})\]\r\n" % (re.escape(self.dst), re.escape(self.src), "".join(
                r"(?:\|T%d\|Q%s\|D([^|\x00-\x1f\[\]]+))?" % (v.type_code, re.escape(v.name)) for v in vs))
            self.rx = fullmatch(rx)



def lane_at(hot: dict[tuple, Direction], lanes: dict[bytes, ColLane], buf: bytes, off: int) -> ColLane | None:
    """The run taker of the direction of the record at ``off`` of a classic pcap block (its
    addresses, ports and letters, read where a plain Ethernet/IPv4/UDP frame has them), made
    again when the direction's state moved since; None when the direction has no fast state
    or no pattern (the record goes the usual way)."""
    if len(buf) < off + 62:
        return None
    return lane_for(hot, lanes, buf[off + 42 : off + 54] + buf[off + 60 : off + 62])


def lane_for(hot: dict[tuple, Direction], lanes: dict[bytes, ColLane], key: bytes) -> ColLane | None:
    """:func:`lane_at` of a record whose ``key`` (its packet's addresses and ports, 12 bytes as
    the IPv4 and UDP headers hold them, then its frame's two letters) was read."""
    lane = lanes.get(key)
    # (the direction's state, checked at every run's start)
    hkey = direction_key(key) if lane is None else lane.hkey
    h = hot.get(hkey)
    if h is None:
        return None
    t = h.table
    stamp = (h.version, len(t.vars), len(t.sent_names), t.named)
    if lane is None or lane.h is not h or lane.stamp != stamp:
        if len(lanes) >= MAX_CONVERSATIONS:
            lanes.clear()
        lane = lanes[key] = ColLane(h, hkey, stamp, key)
    return lane if lane.rx is not None else None


def direction_key(key: bytes) -> tuple:
    """The core's key of a direction, ``(conversation, source, destination)``, from a record's
    ``key`` (:func:`lane_for`)."""
    a = key[:12]
    sport, dport = struct.unpack_from("!HH", a, 8)
    conv = ("udp", socket.inet_ntoa(a[:4]), sport, socket.inet_ntoa(a[4:8]), dport)
    letters = key[12:].decode("latin-1")
    return conv, letters[1], letters[0]


def walk_run(lane: ColLane, buf: bytes, sbuf: str, off: int, room: int, mult: int, unvalued: list[int]
             ) -> tuple[int, list[tuple], list[int], list[bytes], int]:
    """The records a run of :meth:`Decoder.column_run` or :meth:`Decoder.count_run` takes, from
    ``off`` of a classic little-endian pcap block (``sbuf``: the block as latin-1; ``mult``: 1
    for nanosecond times, 1000 for microseconds), at most ``room``: while each is a plain
    IPv4/UDP datagram of the lane's direction holding one frame its pattern matches, with a
    right checksum and no value for a variable of ``unvalued`` (a first value is left to the
    other paths). Returns the offset after the last one taken, each one's match groups (the
    values, then the checksum), time (ns) and frame bytes, and the records' bytes in all."""
    rx = lane.rx
    lane_addr = lane.key[:12]
    end = len(buf)
    unpack_x = PCAP_UDP.unpack_from
    struct_error = struct.error
    groups: list[tuple] = []
    stamps: list[int] = []
    raws: list[bytes] = []
    g_app, t_app, r_app = groups.append, stamps.append, raws.append
    n = wire = 0
    while n < room:
        try:
            sec, frac, incl, _orig, eth, tl, frag, proto, here, ul = unpack_x(buf, off)
        except struct_error:
            break
        start = off + 58
        e = off + 16 + incl
        if here != lane_addr or e > end or not plain_udp(eth, tl, frag, proto, incl, ul):
            break
        m = rx(sbuf, start, e)
        if m is None:
            break
        g = m.groups()
        if unvalued and any(g[i] is not None for i in unvalued):
            break
        raw = buf[start:e]
        if not frame_ok(raw, g[-1]):
            break
        off = e
        wire += incl
        g_app(g)
        t_app(sec * NS + frac * mult)
        r_app(raw)
        n += 1
    return off, groups, stamps, raws, wire


#: fast frames gathered into one :class:`Columns` at most, into one :class:`Counted` about (at
#: most twice as many: a run of :meth:`Decoder.count_run` takes up to as many)
BATCH_FRAMES = 512
