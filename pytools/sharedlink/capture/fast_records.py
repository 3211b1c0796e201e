"""The fast per-record tier of :class:`~sharedlink.capture.stream.ChangeReader`.

Same contract as the reference path (``ChangeReader._walk_plain``): take the complete records
of a block of a classic nanosecond/microsecond pcap, append the same change records, events and
statistics to the reader, return (offset of the rest, last record number). It recognises the
common case, one frame per Ethernet/IPv4/UDP datagram of a conversation whose layout is known
(:class:`FastKey`, made by the reference path after a frame of that conversation), with one
struct call and one compiled regular expression per record; every other record goes to the
reference path (``reader._general``). The tests check both give identical chunks on varied
input (tests/analysis/test_diff.py).
"""

from __future__ import annotations

import re
import struct
import zlib
from collections.abc import Sequence
from typing import TYPE_CHECKING

from sharedlink.capture.change_records import SEP_CHANGE, SEP_VALUE, escape
from sharedlink.capture.pcapio import LINKTYPE_ETHERNET, NS, CaptureError
from sharedlink.protocols.state import VariableTable

if TYPE_CHECKING:
    from sharedlink.capture.stream import ChangeReader

#: a value as the fast path accepts it (the general path takes anything else)
_V = rb"[^|\x00-\x1f\[\]]"
#: Ethernet II, IPv4 without options, not fragmented, UDP: 42 bytes before the payload
_ETH_IP_UDP = rb"(?s).{12}\x08\x00\x45.{5}[\x00\x40]\x00.\x11.{18}"
#: the same with the pcap record header before it, for whole blocks of records of one
#: conversation (see fast_blocks.take): groups record header, IP total length, UDP length


def _bulk_head(addr: bytes) -> bytes:
    """The pattern of a record header and the packet headers of conversation ``addr`` (IPv4
    source and destination, UDP source and destination ports: 12 bytes)."""
    return rb"(?s)(.{16}).{12}\x08\x00\x45.(..)..[\x00\x40]\x00.\x11.." + re.escape(addr) + rb"(..).."
#: checksum digits -> what to subtract from (1 + byte sum of the whole payload) so that the
#: rest is the checksum's own sum: '[' (91), ']' CR LF (116), the two digits, the value
_CKADJ = {b"%02X" % i: 1 + 91 + 116 + (b"%02X" % i)[0] + (b"%02X" % i)[1] + i for i in range(256)}

_REC = struct.Struct("<IIII")
#: variables a direction may have for the fast tier to keep a layout of it (wider tables, and
#: tables that keep growing, go the general way: a layout is one compiled pattern of every name)
MAX_FAST_VARS = 64
#: the record header plus, at fixed offsets of an Ethernet/IPv4/UDP packet: IP total length,
#: IP addresses and UDP ports (12 bytes: the conversation), UDP length (both lengths read
#: little-endian: compared against _SWAP16), the frame's two address letters and the byte
#: after "[:AB|N0|"
_REC_X = struct.Struct("<IIII16xH8x12sH4x2s4xB")
_SWAP16 = [((x & 0xFF) << 8) | (x >> 8) for x in range(65536)]


#: compiled layouts, shared by the conversations that have the same one (a capture of thousands of
#: conversations compiled the same pattern for each); emptied when it holds this many
_PATTERNS: dict[bytes, re.Pattern[bytes]] = {}
MAX_PATTERNS = 1024


def _compiled(pattern: bytes) -> re.Pattern[bytes]:
    rx = _PATTERNS.get(pattern)
    if rx is None:
        if len(_PATTERNS) >= MAX_PATTERNS:
            _PATTERNS.clear()
        rx = _PATTERNS[pattern] = re.compile(pattern)
    return rx


class _Lazy:
    """A block pattern compiled when the block tier first asks (it runs on one direction only)."""

    __slots__ = ("pattern", "_rx")

    def __init__(self, pattern: bytes) -> None:
        self.pattern, self._rx = pattern, None

    def get(self) -> re.Pattern[bytes]:
        if self._rx is None:
            self._rx = _compiled(self.pattern)
        return self._rx


class FastKey:
    """The fast path's view of one direction of one UDP conversation: compiled layouts and
    current values (bytes), kept in step with the :class:`VariableTable` (flushed to it
    before the general path touches the direction, reloaded after). ``key`` is the letters
    (destination, source) the change records carry, ``hkey`` the letters plus the
    conversation's addresses and ports as the packet holds them (the hot loop's lookup).

    The fast layouts hold only while the table's "required" sets match its values: every
    positional slot with a value has been filled by a positional frame, every variable
    with a value has been sent by a named frame (else the layout is left to the general
    path). A frame that gives a variable its first value updates those sets and rebuilds
    (:meth:`first_values`)."""

    __slots__ = ("key", "hkey", "table", "sig", "slots", "cur", "pre", "types", "named", "nslots", "pos", "pslots",
                 "preq", "sync", "hot", "bulk_named", "bulk_pos", "registry")

    def __init__(self, key: bytes, hkey: bytes, table: VariableTable, sync: list, registry: dict) -> None:
        self.key, self.hkey, self.table, self.sync, self.registry = key, hkey, table, sync, registry
        self.sig: tuple = ()
        self.build()

    @staticmethod
    def signature(table: VariableTable) -> tuple:
        return (
            tuple((n, v.type_code, v.text is None) for n, v in table.vars.items()),
            tuple(table.names),
            tuple(sorted(table.filled)),
            tuple(table.sent_names),
        )

    def build(self) -> None:
        t = self.table
        self.sig = self.signature(t)
        self.slots = list(t.vars)
        self.cur = [None if v.text is None else v.text.encode("latin-1", "replace") for v in t.vars.values()]
        self.pre = [SEP_CHANGE + escape(n) + SEP_VALUE for n in self.slots]
        self.types = [v.type_code for v in t.vars.values()]
        head = rb"\[:" + re.escape(self.key) + rb"\|N0"
        tail = rb"\|C([0-9A-F]{2})\]\r\n"
        bulk_head = _bulk_head(self.hkey[2:])
        latin = [n.encode("latin-1", "replace") for n in self.slots]
        valued = {n for n, v in t.vars.items() if v.text is not None}
        # named: optional T/Q/D triplets in table order, for typed variables; only when no
        # variable with a value lacks a type and every one was sent named (else "full"
        # would be judged differently)
        if all(v.type_code is not None or v.text is None for v in t.vars.values()) and valued == set(t.sent_names):
            self.nslots = [i for i, v in enumerate(t.vars.values()) if v.type_code is not None]
            body = b"".join(
                rb"(?:\|T" + str(self.types[i]).encode() + rb"\|Q" + re.escape(latin[i]) + rb"\|D(" + _V + rb"+))?"
                for i in self.nslots
            )
            self.named = _compiled(_ETH_IP_UDP + head + body + tail).fullmatch
            self.bulk_named = _Lazy(bulk_head + b"(" + head + body + tail + b")")
        else:
            self.nslots, self.named, self.bulk_named = [], None, None
        names = t.names
        if (
            names
            and len(set(names)) == len(names)
            and all(n in t.vars for n in names)
            and t.filled == {i for i, n in enumerate(names) if n in valued}
            and valued <= set(names)
        ):
            self.pslots = [self.slots.index(n) for n in names]
            self.preq = sorted(t.filled)
            body = (rb"\|D(" + _V + rb"*)") * len(names)
            self.pos = _compiled(_ETH_IP_UDP + head + body + tail).fullmatch
            self.bulk_pos = _Lazy(bulk_head + b"(" + head + body + tail + b")")
        else:
            self.pslots, self.preq, self.pos, self.bulk_pos = [], [], None, None
        self._hot()

    def _hot(self) -> None:
        """What the hot loop unpacks, in one tuple (published in the reader's registry)."""
        self.hot = (self.key, self.named, self.pos, self.cur, self.pre, self.nslots, self.pslots, self.types, self.sync,
                    self.preq, self)
        self.registry[self.hkey] = self.hot

    def first_values(self, groups: Sequence[bytes | None], positional: bool) -> None:
        """The hot loop gave variables their first value (``groups``: the frame's values,
        ``cur`` already updated): record the slots filled or names sent, then rebuild."""
        t = self.table
        vars_ = t.vars
        if positional:
            for i, (v, k) in enumerate(zip(groups, self.pslots)):
                if v and vars_[self.slots[k]].text is None:
                    t.filled.add(i)
        else:
            for v, k in zip(groups, self.nslots):
                if v is not None:
                    t.sent_names.setdefault(self.slots[k], len(t.sent_names))
        self.flush()
        self.build()

    def flush(self) -> None:
        """Write the fast path's values back into the table."""
        vars_ = self.table.vars
        for name, val in zip(self.slots, self.cur):
            if val is not None:
                vars_[name].text = val.decode("latin-1")

    def refresh(self) -> None:
        """After the general path changed the table: reload (rebuild when the layout moved)."""
        if self.signature(self.table) != self.sig:
            self.build()
        else:
            self.cur = [None if v.text is None else v.text.encode("latin-1", "replace") for v in self.table.vars.values()]
            self._hot()


def walk(reader: ChangeReader, buf: bytes, linktype: int, mult: int, number: int, p: str, start: int = 0) -> tuple[int, int]:
    """Process the complete records in ``buf``; return (offset of the rest, last number).

    The hot loop: everything it needs is in locals. One struct call reads the record
    header and, for an Ethernet/IPv4/UDP packet, the IP and UDP lengths, the frame's
    address letters and the letter after ``N0|``; one regular expression match checks
    the headers and the frame's layout and takes out its values."""
    unpack, unpack_x = _REC.unpack_from, _REC_X.unpack_from
    struct_error = struct.error
    hot = reader._hot if (reader.fast_enabled and linktype == LINKTYPE_ETHERNET) else {}
    hotget = hot.get
    swap = _SWAP16
    adler = zlib.adler32
    ckadj = _CKADJ
    ts_app, num_app, rec_app = reader._ts.append, reader._num.append, reader._recs.append
    recs, events = reader._recs, reader._events
    join = b"".join
    general = reader._general
    sync_ns = reader.sync_ns
    half = sync_ns // 2
    limit = sync_ns + sync_ns - half  # a gap must round to 2 intervals to miss one
    end = len(buf)
    off = start
    if reader.stats.start_ns is None and end >= 16:
        sec, frac = unpack(buf, 0)[:2]
        reader.stats.start_ns = sec * NS + frac * mult
    nrec = wire = pbytes = nfull = missed = bad = 0
    base = reader._base
    ts = reader._last_ts
    while True:
        try:
            sec, frac, incl, _orig, tl, ab, ul, kb, c50 = unpack_x(buf, off)
        except struct_error:
            if off + 16 > end:
                break
            sec, frac, incl, _orig = unpack(buf, off)
            kb = None
        d = off + 16
        e = d + incl
        if e > end:
            if incl > 0x4000000:  # reported by the reader once this block's frames are out
                reader._damage = CaptureError(p, number + 1, f"record length {incl} is implausible (damaged file)")
            break
        off = e
        number += 1
        nrec += 1
        wire += incl
        ts = sec * NS + frac * mult
        tp = sec | (frac * mult) << 32
        h = hotget(kb + ab) if kb is not None and 50 < incl < 65000 else None
        if h is not None and tl == swap[incl - 14] and ul == swap[incl - 34]:
            key, named, pos, cur, pre, nslots, pslots, types, sy, preq, fk = h
            if c50 == 68:  # 'D': positional
                m = pos(buf, d, e) if pos is not None else None
                if m is not None:
                    g = m.groups()
                    plen = incl - 42
                    s = (adler(buf[d + 42 : e]) & 0xFFFF) if plen <= 256 else sum(buf[d + 42 : e]) + 1
                    pbytes += plen
                    ts_app(tp)
                    num_app(number)
                    if (s - ckadj[g[-1]]) & 255:
                        bad += 1
                        rec_app(key)
                        continue
                    parts = [key]
                    first = False
                    for v, k in zip(g, pslots):
                        if v and v != cur[k]:
                            if cur[k] is None:
                                events.append((base + len(recs), key, pre[k][1:-1], types[k]))
                                first = True
                            cur[k] = v
                            parts += (pre[k], v)
                    # full: every slot that has held a value is present (preq: before this frame)
                    if b"" not in g or all(g[i] for i in preq):
                        nfull += 1
                        gap = ts - sy[0]
                        if gap >= limit:
                            missed += (gap + half) // sync_ns - 1
                        sy[0] = ts
                    rec_app(join(parts))
                    if first:
                        fk.first_values(g, True)
                    continue
            else:
                m = named(buf, d, e) if named is not None else None
                if m is not None:
                    g = m.groups()
                    plen = incl - 42
                    s = (adler(buf[d + 42 : e]) & 0xFFFF) if plen <= 256 else sum(buf[d + 42 : e]) + 1
                    pbytes += plen
                    ts_app(tp)
                    num_app(number)
                    if (s - ckadj[g[-1]]) & 255:
                        bad += 1
                        rec_app(key)
                        continue
                    if None in g:
                        # full only if every variable with a value is present (and one is)
                        full = g.count(None) < len(g) - 1
                        if full:
                            for v, k in zip(g, nslots):
                                if v is None and cur[k] is not None:
                                    full = False
                                    break
                    else:
                        full = len(g) > 1
                    parts = [key]
                    first = False
                    for v, k in zip(g, nslots):
                        if v is not None and v != cur[k]:
                            if cur[k] is None:
                                events.append((base + len(recs), key, pre[k][1:-1], types[k]))
                                first = True
                            cur[k] = v
                            parts += (pre[k], v)
                    if full:
                        nfull += 1
                        gap = ts - sy[0]
                        if gap >= limit:
                            missed += (gap + half) // sync_ns - 1
                        sy[0] = ts
                    rec_app(join(parts))
                    if first:
                        fk.first_values(g, False)
                    continue
        # anything else: the general path (flush counters first: it updates stats itself)
        st = reader.stats
        st.payload_bytes += pbytes
        st.full += nfull
        st.sync_missed += missed
        st.checksum_failures += bad
        pbytes = nfull = missed = bad = 0
        general(number, ts, linktype, buf[d:e])
    st = reader.stats
    st.records += nrec
    st.wire_bytes += wire
    st.payload_bytes += pbytes
    st.full += nfull
    st.sync_missed += missed
    st.checksum_failures += bad
    reader._last_ts = ts
    return off, number
