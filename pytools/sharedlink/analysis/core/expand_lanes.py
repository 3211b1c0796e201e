"""What expand's run taker (:class:`~sharedlink.analysis.core.expand.FullSets`) takes a run with:
the direction's lane (the named form's :class:`~sharedlink.analysis.core.lanes.ColLane`, the
positional form's :class:`PosLane`), the run's :class:`Plan` (which values a full set takes from
the run's frames, which it keeps, its text), and a pcapng record's frame matched as
:func:`~sharedlink.analysis.core.lanes.walk_run` matches a classic pcap record's.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from sharedlink.analysis.core.checksum import frame_ok
from sharedlink.analysis.core.direction import Direction
from sharedlink.analysis.core.lanes import ColLane
from sharedlink.analysis.core.patterns import fullmatch, plain_udp

#: a positional slot's value as the Decoded fast path takes one (:data:`~sharedlink.analysis.core.fastpath.HOT_POS`)
POS_VALUE = r"[-+0-9.eE]"
#: an Ethernet packet's fields :func:`~sharedlink.analysis.core.patterns.plain_udp` tests (as
#: :data:`~sharedlink.analysis.core.patterns.PCAP_UDP` reads them, without the pcap record header)
PACKET_UDP = struct.Struct("<12x3sxHxxHxB2x12sH")


class PosLane:
    """Expand only: a positional direction's run taker, the twin of the named form's
    :class:`~sharedlink.analysis.core.lanes.ColLane` for :func:`walk_run`. Made only while the
    Decoded fast path takes the direction's frames of its full set's slot count (the last frame
    its reference path decoded was one, ``h.pos``), each slot a variable of its own named as the
    table's full set names it; ``rx``: a frame of that many slots, each an optional value (an
    empty slot is carried), None when the direction is not in that state. ``stamp``: the state it
    was made for (the direction's version: every reference-path frame moves it)."""

    __slots__ = ("h", "hkey", "key", "src", "dst", "stamp", "rx", "vs")

    def __init__(self, h: Direction, hkey: tuple, stamp: int, key: bytes) -> None:
        self.h, self.hkey, self.stamp, self.key = h, hkey, stamp, key
        _conv, self.src, self.dst = hkey
        self.rx: Callable | None = None
        t = h.table
        names = t.names
        lay = h.pos.get(len(names))
        self.vs = list(lay.vars) if lay is not None else []
        if (t.named is not False or lay is None or [v.name for v in self.vs] != names
                or len(set(names)) != len(names) or any(t.vars.get(v.name) is not v for v in self.vs)):
            self.vs = []
            return
        self.rx = fullmatch(r"\[:%s%s\|N0%s\|C([0-9A-F]{2})\]\r\n" % (self.dst, self.src,
                                                                      r"\|D(%s+)?" % POS_VALUE * len(names)))


class Plan:
    """A run's full sets: ``valued`` (the groups a full set takes from the frames, forward
    filled from ``cur``, the variables' texts before the run), ``unvalued`` (the groups a frame
    of the run may not hold: a first value, left to the frame-at-a-time path), ``template`` (a
    full set up to its checksum's ``C``, ``%s`` a valued group), ``full_nones`` (the Nones of a
    full set's groups; -1: the run has none), ``vs`` (the variable each group is)."""

    __slots__ = ("vs", "cur", "valued", "unvalued", "template", "full_nones")

    def __init__(self, vs: list, valued: list[int], unvalued: list[int], template: str, full_nones: int) -> None:
        self.vs, self.valued, self.unvalued = vs, valued, unvalued
        self.cur = [v.text for v in vs]
        self.template, self.full_nones = template, full_nones


def named_plan(lane: ColLane) -> Plan:
    """A named run's: every typed variable with a value, in table order (a full set holds every
    variable with a value: the reference path writes them so), ``|T t|Q name|D value`` each."""
    vs, names, types = lane.vs, lane.names, lane.types
    valued = [i for i, v in enumerate(vs) if v.text is not None]
    unvalued = [i for i, v in enumerate(vs) if v.text is None]
    template = "[:%s%s|N0%s|C" % (lane.dst, lane.src, "".join(
        "|T%d|Q%s|D%%s" % (types[i], names[i].replace("%", "%%")) for i in valued))
    return Plan(vs, valued, unvalued, template, len(unvalued) if valued else -1)


def pos_plan(lane: PosLane) -> Plan:
    """A positional run's: every slot of the full set, ``|D value`` (empty without one), the
    slots that have held a value from the frames, the others as they are (a frame is full when
    every slot that has held a value has one: none is when such a slot is past the full set)."""
    vs = lane.vs
    filled = lane.h.table.filled
    valued = [i for i in range(len(vs)) if i in filled]
    unvalued = [i for i in range(len(vs)) if i not in filled]
    template = "[:%s%s|N0%s|C" % (lane.dst, lane.src, "".join(
        "|D%s" if i in filled else "|D" + (v.text or "").replace("%", "%%") for i, v in enumerate(vs)))
    return Plan(vs, valued, unvalued, template, len(unvalued) if len(valued) == len(filled) else -1)


def packet_groups(rx: Callable, key: bytes, data: bytes, unvalued: list[int]) -> tuple | None:
    """The groups of a pcapng record's Ethernet packet ``data`` (its values, then its checksum)
    when :func:`~sharedlink.analysis.core.lanes.walk_run` would take it as a classic pcap record
    of the lane (pattern ``rx``, ``key`` its addresses and ports first): a plain IPv4/UDP datagram of
    the lane holding one frame its pattern matches, with a right checksum and no value in
    ``unvalued``; else None."""
    try:
        eth, tl, frag, proto, here, ul = PACKET_UDP.unpack_from(data)
    except struct.error:
        return None
    if here != key[:12] or not plain_udp(eth, tl, frag, proto, len(data), ul):
        return None
    m = rx(data.decode("latin-1"), 42)
    if m is None:
        return None
    g = m.groups()
    if unvalued and any(g[i] is not None for i in unvalued):
        return None
    return g if frame_ok(data[42:], g[-1]) else None
