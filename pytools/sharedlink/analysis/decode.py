"""The decoding core: frames in, :class:`Decoded` frames (typed updates, the table after each) out.

Every command that decodes goes through :class:`Decoder` (stats, export in every format, plot,
ingest, watch): :func:`iter_decoded` walks a capture (streaming, TCP reassembled, serial captures
deframed per direction, as :func:`sharedlink.capture.stream.iter_frames`) and keeps a
:class:`~sharedlink.protocols.state.LinkState`, so every SharedLink frame comes out as a
:class:`Decoded`: its kind in stream context, its checksum verdict, the variables it set and the
direction's whole table as the frame leaves it. :class:`ReferenceDecoder` is the plain path the
core is checked against (and hands what its fast path does not take). On UDP and TCP each ``[:``
of bytes that hold no well-formed frame is a :class:`Decoded` of kind ``malformed``
(:mod:`sharedlink.analysis.malformed`: cut and checked as the dissector does; no updates, never
late). Noise and records that are neither UDP/TCP nor serial SharedLink pass through (a
:class:`~sharedlink.capture.stream.StreamFrame` with ``frame`` None, or a ``(number, ts_ns)``
tuple) so callers can count them.

Choices (shared with the dissector, see ``docs/protocol.md``):

* State is kept per conversation and direction, as the dissector keys it: UDP/TCP by
  addresses, ports and the source and destination letters, serial by capture direction and
  letters (:class:`~sharedlink.protocols.state.LinkState`). ``pair`` (``"B>A"``) is what
  reports group by.
* A frame whose checksum is wrong is counted, labelled and judged against the state before it,
  but does not touch the state: nothing is stored or carried from it, no list learnt, no sync
  clock reset. ``shown`` has its values as sent; ``updates`` is empty.
* ``late`` is the dissector's ``sharedlink.sync.late``: a data frame that is not a full set,
  seen more than the sync interval plus :data:`SYNC_SLACK_S` after the direction's last full
  set with a good (or no) checksum, or its first data frame before any.
* ``response_to``: a reply's query or declaration (the latest unanswered one whose names
  include the reply's, from the queried address to the querier's address and port, whatever
  the reply's source port), or the list request (``L?``/``N?``) a declaration answers
  (:func:`sharedlink.protocols.state.link_response`).
"""

from __future__ import annotations

import os
import re
import socket
import struct
from array import array
from collections.abc import Callable, Iterator, Sequence
from itertools import compress, repeat
from operator import is_not, mul, ne, sub
from pathlib import Path
from typing import NamedTuple
from zlib import adler32

from sharedlink.analysis.malformed import PIECE, Unframed
from sharedlink.capture.packets import Datagram, PacketDecoder
from sharedlink.capture.pcapio import (
    LINKTYPE_ETHERNET,
    NS,
    PCAP_MAGIC_NS,
    PCAP_MAGIC_US,
    CaptureError,
    pcap_header,
    read_records,
    shown_name,
)
from sharedlink.capture.serial_format import USER_LINKTYPES
from sharedlink.capture.stream import FrameSplitter, SerialSplitter, StreamFrame
from sharedlink.protocols.codec import Frame, oversized_numbers, parse_frame
from sharedlink.protocols.limits import MAX_CONVERSATIONS
from sharedlink.protocols.state import (
    BEACON_VARIABLES,
    LinkState,
    PendingAsks,
    Update,
    Variable,
    VariableTable,
    _update,
    conversation_key,
    link_response,
)
from sharedlink.protocols.state import parse_variables as parse_variables  # its home is state

#: seconds past the sync interval before a value frame counts as late (as in the dissector)
SYNC_SLACK_S = 0.5
#: kinds that carry values
VALUE_KINDS = ("full", "delta", "reply")
#: kinds that take part in sync tracking
DATA_KINDS = ("full", "delta")


class Decoded:
    """One SharedLink frame in stream context.

    ``table`` is the live table of the frame's direction (it changes as later frames are
    decoded): read what you need from it before taking the next item. ``frame`` is parsed
    from ``raw`` only when asked (the fast path never needs it).
    """

    __slots__ = ("number", "ts_ns", "conv", "raw", "kind", "checksum_ok", "updates", "table", "late", "sync_gap_ns",
                 "shown", "response_to", "src", "dst", "_frame")

    def __init__(
        self,
        number: int,
        ts_ns: int,
        conv: tuple[str, str, int, str, int],
        raw: bytes,
        frame: Frame | None,
        kind: str,
        checksum_ok: bool | None,  # None: the frame has no checksum field
        updates: tuple[Update, ...],  # empty when the checksum is bad
        table: VariableTable,
        late: bool,  # sync late (see the module doc)
        sync_gap_ns: int | None,  # on a full frame: time since the direction's previous full one
        shown: tuple[Update, ...] = (),  # the values the frame shows: ``updates``, or as sent when bad
        response_to: int | None = None,  # a reply: the number of its query or declaration
        src: str = "",  # the letters (taken from ``frame`` when it is given)
        dst: str = "",
    ) -> None:
        self.number, self.ts_ns, self.conv, self.raw, self._frame = number, ts_ns, conv, raw, frame
        self.kind, self.checksum_ok, self.updates, self.table = kind, checksum_ok, updates, table
        self.late, self.sync_gap_ns, self.shown, self.response_to = late, sync_gap_ns, shown, response_to
        if frame is not None:
            src, dst = frame.src, frame.dst
        self.src, self.dst = src, dst

    @property
    def frame(self) -> Frame:
        """The parsed frame; a ``malformed`` one's: its letters, no fields, no checksum field."""
        f = self._frame
        if f is None:
            if self.kind == "malformed":
                f = Frame(self.dst, self.src, (), self.raw.endswith(b"\r\n"), None, ("malformed",))
            else:
                f = parse_frame(self.raw)
            self._frame = f
        return f

    @property
    def pair(self) -> str:
        """``"B>A"``: from B to A."""
        return f"{self.src}>{self.dst}"

    def changes(self) -> list[Update]:
        """The variables this frame gave a new value (carried values left out)."""
        return [u for u in self.updates if u.changed and not u.carried and u.text is not None]

    def present(self) -> list[Update]:
        """The values this frame carries itself (changed or not)."""
        return [u for u in self.updates if not u.carried and u.text is not None]

    def __repr__(self) -> str:
        return f"Decoded(number={self.number}, pair={self.pair!r}, kind={self.kind!r}, checksum_ok={self.checksum_ok})"


#: the table a malformed frame shows: none (it sets nothing, shows no values)
_NO_TABLE = VariableTable()


class ReferenceDecoder:
    """The plain decoder, frame by frame through :class:`~sharedlink.protocols.state.LinkState`:
    obviously right, slow. The tests' oracle, and the path :class:`Decoder` hands every frame
    its fast path does not take; no command uses it on its own.

    ``carried`` False leaves a named frame's carried values out of ``updates`` (for callers that
    read only what frames carry: then a frame costs what it holds, not the direction's table)."""

    def __init__(self, variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES, sync_interval: float = 1.0,
                 carried: bool = True) -> None:
        self.link = LinkState(default_list=list(variables))
        self.limits = self.link.limits
        self.carried = carried
        self.late_ns = round((sync_interval + SYNC_SLACK_S) * NS)
        self._sync: dict[tuple, list[int | None]] = {}  # table key -> [first data ts, last full ts]
        self._asks = PendingAsks(self.limits)  # unanswered queries, list requests and declarations, per querier
        self._unframed = Unframed()  # malformed frames cut from the bytes that hold no frame

    def decode(self, sf: StreamFrame) -> Decoded:
        frame = sf.frame
        assert frame is not None
        conv = conversation_key(sf.conv)
        table = self.link.table(frame.src, frame.dst, conv)
        kind = table.kind(frame)
        ok = frame.checksum.ok if frame.checksum is not None else None
        self.limits.numbers += oversized_numbers(frame.fields)
        late = False
        gap: int | None = None
        if ok is False:
            updates: tuple[Update, ...] = ()
            shown = tuple(table.preview(frame, sf.number, sf.ts_ns, self.carried)) if kind in VALUE_KINDS else ()
            dropped = table.dropped if kind in VALUE_KINDS else ()
        else:
            updates = shown = tuple(self.link.apply(frame, sf.number, sf.ts_ns, conv, self.carried))
            dropped = self.link.dropped
        if dropped:  # values past a limit: shown as the dissector shows them, in no update
            shown = (*shown, *dropped)
        if kind in DATA_KINDS:
            skey = (conv, frame.src, frame.dst)
            sync = self._sync.get(skey)
            if sync is None:
                sync = [sf.ts_ns, None]
                if len(self._sync) < MAX_CONVERSATIONS:
                    self._sync[skey] = sync
            if kind == "full" and ok is not False:
                if sync[1] is not None:
                    gap = sf.ts_ns - sync[1]
                sync[1] = sf.ts_ns
            elif kind != "full":
                since = sync[1] if sync[1] is not None else sync[0]
                late = sf.ts_ns - since > self.late_ns  # type: ignore[operator]
        response_to = self._link_response(sf, frame, kind) if kind in ("query", "declaration", "reply") else None
        return Decoded(
            sf.number, sf.ts_ns, sf.conv, sf.raw, frame, kind, ok, updates, table, late, gap, shown, response_to
        )

    def _link_response(self, sf: StreamFrame, frame: Frame, kind: str) -> int | None:
        """Remember a query or declaration; for a reply (or a declaration answering a list
        request), the one it answers (:func:`sharedlink.protocols.state.link_response`)."""
        return link_response(self._asks, conversation_key(sf.conv), frame, kind, sf.number)

    def unframed(self, sf: StreamFrame) -> Iterator[Decoded | StreamFrame]:
        """Bytes that hold no well-formed frame (``sf.frame`` None): on UDP and TCP a
        :class:`Decoded` of kind ``malformed`` for each ``[:`` in them (its letters from its
        header, ``?`` for one it lacks; ``raw`` its bytes; ``checksum_ok`` False when its checksum
        is wrong, else None; no updates, an empty table, never late) and the noise between them
        (a :class:`~sharedlink.capture.stream.StreamFrame` of reason
        :data:`~sharedlink.analysis.malformed.PIECE`); ``sf`` itself when it is left whole
        (:meth:`sharedlink.analysis.malformed.Unframed.pieces`)."""
        pieces = self._unframed.pieces(sf)
        if pieces is None:
            yield sf
            return
        raw, number, ts, conv = sf.raw, sf.number, sf.ts_ns, sf.conv
        for src, dst, a, e, bad in pieces:
            if src is None:
                yield StreamFrame(number, ts, conv, raw[a:e], None, PIECE)
            else:
                yield Decoded(number, ts, conv, raw[a:e], None, "malformed", False if bad else None, (), _NO_TABLE,
                              False, None, (), None, src, dst)


# -- the core: the reference decoder with a fast path for frames in a layout already seen -----------

#: one named full/delta frame alone in a datagram (decoded as latin-1), with plain names and
#: numeric values, or a bare ``N0`` (nothing changed): groups destination letter, source letter,
#: body ("T2|QName|Dvalue|" ..., empty when bare), checksum
_HOT = re.compile(r"\[:([A-P])([A-P])\|N0\|((?:T[024]\|Q[A-Za-z0-9_.]+\|D[-+0-9.eE]+\|)*)C([0-9A-F]{2})\]\r\n")
#: one positional ``N0`` frame alone in a datagram, numeric or empty (carried) values: groups
#: destination letter, source letter, body ("|Dvalue|D|Dvalue" ..., at least one value), checksum
_HOT_POS = re.compile(r"\[:([A-P])([A-P])\|N0((?:\|D[-+0-9.eE]*)+)\|C([0-9A-F]{2})\]\r\n")
_HEX = {f"{i:02X}": i for i in range(256)}
#: checksum digits -> what to take from (1 + the byte sum of the whole frame) so that the rest is
#: 0 mod 256 when the checksum is right: the 1, '[' (91), the digits, ']' CR LF (116) and the value
_CKSUB = {f"{i:02X}": 1 + 91 + ord(f"{i:02X}"[0]) + ord(f"{i:02X}"[1]) + 116 + i for i in range(256)}
#: layouts kept per direction (a compressed beacon has a handful)
MAX_LAYOUTS = 32


def _layout_key(parts: list[str]) -> tuple[str, ...]:
    """A hot body's layout (its ``T`` and ``Q`` fields, no values) from ``body.split("|")``."""
    return (*parts[0::3], *parts[1::3])


class _Layout:
    """One frame layout of a direction: its names, their types, and what follows from them
    while the direction's names stay the same (``stamp``): the names the frame leaves out
    (carried) and whether it is full."""

    __slots__ = ("names", "types", "present", "stamp", "missing", "full", "checked", "full_at", "vars", "cols")

    def __init__(self, names: tuple[str, ...], types: tuple[int, ...], vars_: tuple = ()) -> None:
        self.names, self.types, self.present = names, types, frozenset(names)
        self.vars = vars_  # positional: the slots' Variables, as the reference path named them
        self.checked = -1  # the direction's version its types were last checked at
        self.full_at = -1  # ... and ``full`` worked out at (counts only)
        self.stamp: tuple[int, int] = (-1, -1)  # (len(table.vars), len(table.sent_names)) the two below hold for
        self.missing: tuple[str, ...] = ()
        self.full = False
        #: columns only (:meth:`Decoder.column`): what its frames' rows share while the direction's
        #: version and names stay: (version, stamp), whether a name is not yet in ``sent_names``,
        #: the carried names' type codes, True and False as many times as names carried and present
        self.cols: tuple = ()


class _Hot:
    """A direction's steady state: its table, sync state and the layouts its good full and
    delta frames have had (named: by types and names; positional: by slot count, named as the
    reference path named the slots of the last such frame it decoded); ``last``: the last
    Update the fast path made for each variable, reused while it still says the same (Updates
    are immutable; forgotten whenever the reference path decodes a frame of the direction)."""

    __slots__ = ("table", "sync", "layouts", "last", "stamp", "version", "pos", "compiled")

    def __init__(self, table: VariableTable, sync: list) -> None:
        self.table, self.sync = table, sync
        self.compiled: _Compiled | None = None  # changes only: its layouts as compiled patterns
        self.version = 0  # counts the direction's frames through the reference path (types may move)
        self.layouts: dict[tuple[str, ...], _Layout] = {}
        self.pos: dict[int, _Layout] = {}  # positional layouts by slot count
        self.last: dict[str, Update] = {}
        self.stamp: tuple[int, int] = (-1, -1)  # (len(table.vars), len(table.sent_names)) ``last`` was made for


def _named_size(name: str, type_code: int | None, text: str | None) -> int:
    """Bytes of one value in a named full set, ``|T t|Q name|D text`` (0 without a value)."""
    if text is None:
        return 0
    return 4 + len(name) + len(text) + (2 + len(str(type_code)) if type_code is not None else 0)


#: a value as a compiled layout takes it (a frame with any other goes the reference path)
_CV = rb"[^|\x00-\x1f\[\]]"
#: checksum digits (bytes) -> what to take from (1 + the byte sum of the whole frame) so that the
#: rest is 0 mod 256 when the checksum is right (as :data:`_CKSUB`)
_CKSUB_B = {k.encode(): v for k, v in _CKSUB.items()}
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


def _fullmatch(pattern: bytes | str) -> Callable:
    return cached_pattern(_PATTERNS if isinstance(pattern, bytes) else _STR_PATTERNS, MAX_PATTERNS, pattern,
                          "fullmatch")


#: a classic pcap record header, then from byte 12 of an Ethernet packet: the type and the IP
#: version and header length (3 bytes), IP total length, flags and fragment offset, protocol,
#: the addresses and UDP ports (12 bytes: the conversation), UDP length: the 16-bit fields
#: little-endian, compared through _SWAP16; the fragment field is 0, or 0x40 for "don't fragment"
_PCAP_UDP = struct.Struct("<IIII12x3sxHxxHxB2x12sH")
_SWAP16 = array("H", range(65536))
_SWAP16.byteswap()  # x with its two bytes swapped
_SWAP16 = _SWAP16.tolist()


class _Compiled:
    """Changes only: a direction's layouts as compiled patterns on the frame's bytes, one a
    form, and :attr:`take`, the function that decodes a frame with them.

    Named: every typed variable of the table, in table order, as an optional ``|T t|Q name|D
    value`` (so every subset a compressed stream sends, in that order, is one match);
    positional: one ``|D value`` a slot of the table's full set. Each group is a value as bytes,
    compared with ``cur`` (the table's texts, latin-1, kept in step: a changed value is written
    to the table at the end of the run that changed it). Made from the table as the reference
    path leaves it; valid while the direction's :class:`_Hot` version is ``version`` (every
    reference-path frame of the direction moves it) and made again when a frame gives a
    variable its first value.

    ``take(buf, off, number, mult, lane, out)`` decodes a run of records of a classic pcap block
    (``buf`` from ``off``; ``number``: the last record's number; ``mult``: 1 for nanosecond
    times, 1000 for microseconds): while a record is a plain Ethernet/IPv4/UDP datagram of
    ``lane`` (the packet's addresses and ports, as it holds them), its payload one
    frame of this direction a compiled layout matches, with a right checksum, the table is
    updated and ``out`` (four appends) gets its packed time, number and change record (the
    record as :mod:`sharedlink.capture.change_records` makes it: the letters, then each value
    the frame changed) and, for a full frame, its time. It stops at the first record it does
    not take (the caller decodes that one with :meth:`Decoder.reference`) or after a frame that
    gave a variable its first value (then the layouts are made again, with a new ``take``) and
    returns ``(offset, number, frames taken, their captured bytes, first)``, ``first`` the
    variables that frame gave a first value, else None. The caller counts what it took in
    :attr:`Decoder.fast`. No Decoded, no Updates: a frame costs one struct call, one match
    and a comparison per value it holds; ``set_in``/``set_at`` are not kept. A run of one
    direction (a capture of one sender) is one call; everything the loop uses is bound in the
    closure (no attribute look-ups per frame)."""

    __slots__ = ("hot", "version", "key", "vars", "cur", "named", "pos", "take")

    def __init__(self, h: _Hot, key: bytes) -> None:
        self.hot = h
        self.key = key  # destination and source letters: a change record's first two bytes
        self.build(h)

    def build(self, h: _Hot) -> None:
        from sharedlink.analysis.compiled_blocks import BLOCK_AFTER, block_taker
        from sharedlink.capture.change_records import SEP_CHANGE, SEP_VALUE, escape

        t = h.table
        self.version = h.version
        if len(t.vars) > MAX_COMPILED_VARS:
            # too wide to compile: nothing made, so a table that grows by new names every frame
            # costs nothing a frame here (a build walks every variable: quadratic, issue 31)
            self.vars, self.cur, self.named, self.pos = [], [], None, None
            return
        vs = list(t.vars.values())
        self.vars = vs
        cur = self.cur = [None if v.text is None else v.text.encode("latin-1", "replace") for v in vs]
        rec = [SEP_CHANGE + escape(v.name) + SEP_VALUE for v in vs]
        key = self.key
        head = rb"\[:" + re.escape(key) + rb"\|N0"
        tail = rb"\|C([0-9A-F]{2})\]\r\n"
        valued = {v.name for v in vs if v.text is not None}
        named = pos = None
        named_rx = pos_rx = None  # (their patterns, for the block tier)
        nslots: list[int] = []
        pslots: list[int] = []
        preq: list[int] = []
        if len(vs) <= MAX_COMPILED_VARS:
            # named: only when every variable with a value has a type and was sent named (then
            # "full", every sent name present, is "every variable with a value present")
            if all(v.type_code is not None or v.text is None for v in vs) and valued == set(t.sent_names):
                nslots = [i for i, v in enumerate(vs) if v.type_code is not None]
                named_rx = head + b"".join(
                    rb"(?:\|T%d\|Q%s\|D(%s+))?" % (vs[i].type_code, re.escape(vs[i].name.encode("latin-1", "replace")),
                                                  _CV) for i in nslots) + tail
                named = _fullmatch(named_rx)
            # positional: the table's full set, each slot named as the reference path names it
            # in a frame of that many slots, every value held in a slot that has held one
            names = t.names
            n = len(names)
            index = {v.name: i for i, v in enumerate(vs)}
            if (names and len(set(names)) == n and all(x in index for x in names)
                    and all(t.slot_name(i, n) == names[i] for i in range(n))
                    and t.filled == {i for i, x in enumerate(names) if x in valued} and valued <= set(names)):
                pslots = [index[x] for x in names]
                preq = sorted(t.filled)
                pos_rx = head + (rb"\|D(%s*)" % _CV) * n + tail
                pos = _fullmatch(pos_rx)
        self.named, self.pos = named, pos
        sync = h.sync
        cksub = _CKSUB_B
        compiled = self
        unpack_x = _PCAP_UDP.unpack_from
        struct_error = struct.error
        swap = _SWAP16
        eth_ipv4 = _ETH_IPV4
        block = block_taker(key, named_rx, pos_rx, _CV, nslots, pslots, cur, rec, sync)

        def take(buf: bytes, off: int, number: int, mult: int, lane: bytes, out: tuple, bulk: tuple | None = None
                 ) -> tuple[int, int, int, int, list[Variable] | None]:
            # a run of records, while each is one frame of this direction a layout matches
            end = len(buf)
            ts_app, num_app, rec_app, full_app = out
            first: list[Variable] | None = None
            n = wire = 0
            form = None
            last_full = None
            dirty: list[int] = []  # the variables whose value changed (written to the table at the end)
            changed = dirty.append
            # the block tier: once BLOCK_AFTER records in a row were taken here
            run = 0 if bulk is not None else -(1 << 62)
            while first is None:
                if run >= BLOCK_AFTER and off + 67 <= end:
                    bpos = buf[off + 66] == 68  # positional: "[:AB|N0|D" (after 16 + 42 bytes of headers)
                    got = block(buf, off, number, mult, lane, bulk, bpos, t.named is True, changed)
                    if got is None:
                        run = 0
                    else:
                        off, number, k, w, lf, whole = got
                        n += k
                        wire += w
                        form = bpos
                        if lf is not None:
                            last_full = lf
                        if not whole:
                            run = 0
                        continue
                try:
                    sec, frac, incl, _orig, eth, tl, frag, proto, here, ul = unpack_x(buf, off)
                except struct_error:
                    break
                start = off + 58
                e = off + 16 + incl
                if (here != lane or e > end or eth != eth_ipv4 or proto != 17 or frag & 0xFFBF or incl <= 50
                        or incl > 65000 or tl != swap[incl - 14] or ul != swap[incl - 34]):
                    break
                positional = buf[start + 8] == 68  # "[:AB|N0|D"
                if positional:
                    if pos is None:
                        break
                    m = pos(buf, start, e)
                    if m is None:
                        break
                    g = m.groups()
                    slots = pslots
                    # full (as VariableTable.kind, before the frame): every slot that has held a value has one
                    full = b"" not in g or all(g[i] for i in preq)
                else:
                    if named is None or (buf[start + 8] == 67 and t.named is not True):
                        break  # (a bare N0 takes the direction's form: named only in a named direction)
                    m = named(buf, start, e)
                    if m is None:
                        break
                    g = m.groups()
                    slots = nslots
                    # full: every variable with a value present (all were sent named), and one present
                    if None not in g:
                        full = len(g) > 1
                    elif g.count(None) < len(g) - 1:
                        full = True
                        for v, k in zip(g, slots):
                            if v is None and cur[k] is not None:
                                full = False
                                break
                    else:
                        full = False
                frame = buf[start:e]
                # the checksum: adler32's low half is 1 + the byte sum for up to 256 bytes (C speed)
                if (((adler32(frame) & 0xFFFF) if e - start <= 256 else sum(frame) + 1) - cksub[g[-1]]) & 0xFF:
                    break
                off = e
                number += 1
                n += 1
                wire += incl
                parts = [key]
                for v, k in zip(g, slots):
                    if v and v != cur[k]:
                        if cur[k] is None:
                            first = [vs[k]] if first is None else [*first, vs[k]]
                        cur[k] = v
                        changed(k)
                        parts += (rec[k], v)
                ts_app(sec | (frac * mult) << 32)  # (the packed time of a change chunk)
                num_app(number)
                rec_app(b"".join(parts))
                form = positional
                run += 1
                if full:
                    ts = sec * NS + frac * mult
                    full_app(ts)
                    last_full = number
                    sync[1] = ts
            if dirty:  # the table's texts, once a run
                for k in set(dirty):
                    vs[k].text = cur[k].decode("latin-1")
            if form is not None:
                t.named = not form
                if last_full is not None:
                    t.last_full_at, t.last_full_in = sync[1], last_full
            if first is not None:  # what the reference path notes of a first value, then build again
                if positional:
                    t.filled.update(i for i, v in enumerate(g[:-1]) if v)
                else:
                    sent = t.sent_names
                    for v, k in zip(g, slots):
                        if v is not None and vs[k].name not in sent:
                            sent[vs[k].name] = len(sent)
                compiled.build(h)  # (a new take: the caller looks it up again)
            return off, number, n, wire, first

        self.take = take


class _ColLane:
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

    def __init__(self, h: _Hot, hkey: tuple, stamp: tuple, key: bytes = b"") -> None:
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
            self.rx = _fullmatch(rx)


class DirCounts:
    """Counts only: what :meth:`Decoder.count` took of one direction's frames since the last
    batch (every one a good full or delta frame in the named form). ``layouts``: layout ->
    [frames, number and time of the last one] (of the frames :meth:`Decoder.count` took);
    ``held``: name -> values carried in the frames :meth:`Decoder.count_run` took; ``changed``:
    name -> the texts it changed to, in order; ``gaps``: the sync gaps of its full frames (ns);
    ``size``: the bytes of a full set's values now; ``stamps``: its frames' times in capture
    order (link health, analysis/health.py)."""

    __slots__ = ("conv", "src", "dst", "table", "first_ts", "last_ts", "frames", "bytes", "full", "late", "gaps",
                 "full_bytes", "layouts", "held", "changed", "size", "last_full", "stamps")

    def __init__(self, conv: tuple, src: str, dst: str, h: _Hot, ts: int, size: int) -> None:
        self.conv, self.src, self.dst, self.table = conv, src, dst, h.table
        self.first_ts = self.last_ts = ts
        self.frames = self.bytes = self.full = self.late = self.full_bytes = 0
        self.gaps: list[int] = []
        self.layouts: dict[_Layout, list[int]] = {}
        self.held: dict[str, int] = {}
        self.changed: dict[str, list[str]] = {}
        self.size = size
        self.last_full: tuple[int, int] | None = None
        self.stamps: list[int] = []

    @property
    def pair(self) -> str:
        return f"{self.src}>{self.dst}"

    def counts(self) -> dict[str, int]:
        """Values carried per name (each frame of a layout carries all its names)."""
        out = dict(self.held)
        for lay, (n, _number, _ts) in self.layouts.items():
            for name in lay.names:
                out[name] = out.get(name, 0) + n
        return out


class DirColumns:
    """Columns only: what :meth:`Decoder.column` took of one direction's frames since the last
    batch (every one a good full or delta frame in the named form), as per-column lists. Per
    frame: ``ordinal`` (its place among the batch's frames, all directions, capture order),
    ``number``, ``ts_ns``, ``raw``, ``kind`` ("full" or "delta"), ``late`` and ``nvalues`` (its
    value rows); per value row, frame after frame, as the frame's Updates with a text would say:
    ``name``, ``text``, ``type_code``, ``carried``, ``changed`` (the values it carries in its
    layout's order, then, when the decoder keeps carried values, the direction's other values
    that have one, in the table's order). The table is as the batch's last frame left it."""

    __slots__ = ("conv", "src", "dst", "table", "ordinal", "number", "ts_ns", "raw", "kind", "late", "nvalues",
                 "name", "text", "type_code", "carried", "changed", "layouts", "last_full")

    def __init__(self, conv: tuple, src: str, dst: str, table: VariableTable) -> None:
        self.conv, self.src, self.dst, self.table = conv, src, dst, table
        self.ordinal: list[int] = []
        self.number: list[int] = []
        self.ts_ns: list[int] = []
        self.raw: list[bytes] = []
        self.kind: list[str] = []
        self.late: list[bool] = []
        self.nvalues: list[int] = []
        self.name: list[str] = []
        self.text: list[str] = []
        self.type_code: list[int | None] = []
        self.carried: list[bool] = []
        self.changed: list[bool] = []
        self.layouts: dict[_Layout, list[int]] = {}  # layout -> [number, time] of its last frame
        self.last_full: tuple[int, int] | None = None

    @property
    def pair(self) -> str:
        return f"{self.src}>{self.dst}"


class Decoder(ReferenceDecoder):
    """The decoding core: every command that decodes SharedLink goes through it. Same results
    as :class:`ReferenceDecoder` (the tests compare them on generated streams built to catch a
    wrong reuse), fast by construction:

    * a datagram holding exactly one named ``N0`` frame with a good checksum, in a layout (types
      and names, in order) one of its direction's earlier good full or delta frames had, its
      variables still of those types, is decoded from one latin-1 string and one split, without
      building a :class:`~sharedlink.protocols.codec.Frame` (``Decoded.frame`` parses it if
      asked); unchanged carried values reuse the Update made for the previous frame;
    * so is a positional ``N0`` frame alone in a datagram with as many slots as its direction's
      last positional frame through the reference path, its slots named as that decoding named
      them (the naming rules stay in :mod:`sharedlink.protocols.state`);
    * everything else goes through the reference path; a frame there that changes the
      direction's state in another way forgets its layouts, a declaration forgets every layout,
      and any frame there forgets the Updates kept for reuse and the positional layouts;
    * :meth:`capture` reads a capture's plain Ethernet/IPv4/UDP records without the general
      packet decoder, the rest through :func:`sharedlink.capture.stream.iter_frames`' splitters.
    """

    def __init__(self, variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES, sync_interval: float = 1.0,
                 carried: bool = True) -> None:
        super().__init__(variables, sync_interval, carried)
        self._hot: dict[tuple, _Hot] = {}
        self.fast = 0  # frames decoded by the fast path
        self.batch: dict[_Hot, DirCounts] = {}  # counts only: what count() took, per direction
        self.rows: dict[_Hot, DirColumns] = {}  # columns only: what column() took, per direction
        self.taken = 0  # columns only: frames in ``rows``
        self._lanes: dict[bytes, _ColLane] = {}  # columns only: addresses, ports and letters -> run taker
        self._mode: str | None = None  # set by the first capture() or compiled() (see _use)
        self.splitter = FrameSplitter()

    def decode(self, sf: StreamFrame) -> Decoded:
        """One frame (``sf.frame`` parsed)."""
        d = self._try_fast(sf.number, sf.ts_ns, sf.conv, sf.raw)
        if d is None:
            d = ReferenceDecoder.decode(self, sf)
            self._learn(d)
        return d

    def decode_datagram(self, number: int, ts_ns: int, conv: tuple, data: bytes) -> Iterator[Decoded | StreamFrame]:
        """The frames of a UDP datagram, and its noise (a :class:`StreamFrame` with ``frame``
        None), each decoded when it is taken (so its ``table`` is the table as that frame leaves
        it). A datagram that is one hot frame is not parsed at all."""
        d = self._try_fast(number, ts_ns, conv, data)
        if d is not None:
            yield d
            return
        proto, src, sport, dst, dport = conv
        for sf in self.splitter.split(number, ts_ns, Datagram(proto, src, dst, sport, dport, data)):
            if sf.frame is None:
                yield from self.unframed(sf)
            else:
                d = ReferenceDecoder.decode(self, sf)
                self._learn(d)
                yield d

    def capture(self, path: str | Path, progress: Callable[[int, int], None] | None = None, counts: bool = False,
                columns: bool = False) -> Iterator[Decoded | StreamFrame | tuple[int, int] | Counted | Columns]:
        """Every item of a capture, as :func:`iter_decoded` gives them. ``progress(bytes, records)`` is
        called every few thousand records with (bytes of the file read so far, records).
        ``counts``: the frames the fast path takes come as :class:`Counted` batches instead of
        :class:`Decoded` frames (for callers that count: no per-frame objects). ``columns``: they
        come as :class:`Columns` batches, their values as rows appended to per-column lists
        (for callers that store rows: no Update, no Decoded)."""
        self._use("columns" if columns else "counts" if counts else "decoded")
        return _capture_items(self, path, progress, counts, columns)

    def _use(self, mode: str) -> None:
        """One mode a Decoder: the compiled layouts (changes only) hold texts that the other
        modes' fast paths move (and columns runs write) behind their back."""
        if self._mode != mode:
            if self._mode is not None:
                raise ValueError(f"a Decoder used in the {self._mode} mode cannot be used in the {mode} mode")
            self._mode = mode

    def datagram(self, dg) -> Iterator[Decoded | StreamFrame]:
        """:meth:`decode_datagram` of an object with ``number``, ``ts_ns``, ``conv`` and ``data``
        (the watch's received datagrams)."""
        return self.decode_datagram(dg.number, dg.ts_ns, dg.conv, dg.data)

    def _try_fast(self, number: int, ts: int, conv: tuple, raw: bytes) -> Decoded | None:
        found = self._match(conv, raw)
        if found is None:
            return self._try_positional(number, ts, conv, raw)
        h, lay, src, dst, values = found
        return self._fast(number, ts, conv, raw, h, lay, src, dst, values)

    def _try_positional(self, number: int, ts: int, conv: tuple, raw: bytes) -> Decoded | None:
        """A positional ``N0`` frame alone in a datagram, in a slot count its direction's last
        reference-path frame had, with a good checksum: decoded without a Frame."""
        m = _HOT_POS.fullmatch(raw.decode("latin-1"))
        if m is None:
            return None
        dst, src, body, cs = m.groups()
        h = self._hot.get((conv, src, dst))
        if h is None or not h.pos:
            return None
        values = body[2:].split("|D")
        lay = h.pos.get(len(values))
        if lay is None:
            return None
        if len(raw) <= 256:
            if ((adler32(raw) & 0xFFFF) - _CKSUB[cs]) & 0xFF:
                return None
        elif (sum(raw[1 : m.end(3) + 1]) & 0xFF) != _HEX[cs]:
            return None
        return self._fast_positional(number, ts, conv, raw, h, lay, src, dst, values)

    def _match(self, conv: tuple, raw: bytes) -> tuple[_Hot, _Layout, str, str, list[str]] | None:
        """The direction, layout, letters and values (``D`` fields) of a datagram the fast path
        takes, else None."""
        # measured choices: one latin-1 decode of the datagram, then str operations (the values
        # come out as str, no decode each); one split of the body gives the layout and values
        m = _HOT.fullmatch(raw.decode("latin-1"))
        if m is None:
            return None
        dst, src, body, cs = m.groups()
        h = self._hot.get((conv, src, dst))
        if h is None or (not body and h.table.named is not True):  # (a bare N0 takes the direction's form)
            return None
        parts = body.split("|")
        lay = h.layouts.get(_layout_key(parts))
        if lay is None:
            return None
        # the checksum: adler32's low half is 1 + the byte sum for up to 256 bytes (C speed)
        if len(raw) <= 256:
            if ((adler32(raw) & 0xFFFF) - _CKSUB[cs]) & 0xFF:
                return None
        elif (sum(raw[1 : m.end(3) + 1]) & 0xFF) != _HEX[cs]:
            return None
        if lay.checked != h.version:  # the types may have moved since: the layout's must still hold
            vars_ = h.table.vars
            for n, t in zip(lay.names, lay.types):
                if vars_[n].type_code != t:
                    return None
            lay.checked = h.version
        return h, lay, src, dst, parts[2::3]

    def count(self, number: int, ts: int, conv: tuple, raw: bytes) -> bool:
        """Counts only: take a datagram the fast path takes into :attr:`batch` (no
        :class:`Decoded`, no Updates) and return True; False when it is not one (decode it).
        Per value only a comparison; what every value of a layout shares (its count, the frame
        that last carried it) is kept per layout and written to the table by :meth:`take_batch`,
        which the caller calls before anything else is decoded."""
        found = self._match(conv, raw)
        if found is None:
            return False
        h, lay, src, dst, values = found
        c = self.batch.get(h)  # (by direction: one _Hot each)
        if c is None:
            c = self.batch[h] = DirCounts(conv, src, dst, h, ts, self._hot_size(h))
        vars_ = h.table.vars
        size = c.size
        for name, dval in zip(lay.names, values):
            v = vars_[name]
            text = dval[1:]
            old = v.text
            if old != text:
                texts = c.changed.get(name)
                if texts is None:
                    texts = c.changed[name] = []
                texts.append(text)
                size += len(text) - len(old) if old is not None else _named_size(name, v.type_code, text)
                v.text = text
        c.size = size
        seen = c.layouts.get(lay)
        if seen is None:
            c.layouts[lay] = [1, number, ts]
        else:
            seen[0] += 1
            seen[1], seen[2] = number, ts
        c.frames += 1
        c.stamps.append(ts)
        c.bytes += len(raw)
        if ts > c.last_ts:
            c.last_ts = ts
        elif ts < c.first_ts:
            c.first_ts = ts
        c.full_bytes += size + 14  # "[:AB|N0" ... "|CXX]" CR LF around the values
        if lay.full_at != h.version:
            lay.full_at = h.version
            self._layout_full(h.table, lay)
        sync = h.sync
        if lay.full:
            c.full += 1
            c.last_full = number, ts
            if sync[1] is not None:
                c.gaps.append(ts - sync[1])
            sync[1] = ts
        else:
            since = sync[1] if sync[1] is not None else sync[0]
            if ts - since > self.late_ns:
                c.late += 1
        return True

    def take_batch(self) -> dict[tuple, DirCounts]:
        """What :meth:`count` gathered since the last call (then empty), the tables brought up
        to date (which frame last set each value, the last full set, the form)."""
        b = {(c.conv, c.src, c.dst): c for c in self.batch.values()}
        self.batch = {}
        for c in b.values():
            table = c.table
            vars_ = table.vars
            for lay, (_n, number, ts) in sorted(c.layouts.items(), key=lambda kv: kv[1][1]):
                for name in lay.names:
                    v = vars_[name]
                    if v.set_in is None or number > v.set_in:  # (a run of count_run may have set it since)
                        v.set_in, v.set_at = number, ts
            if c.last_full is not None:
                table.last_full_at, table.last_full_in = c.last_full[1], c.last_full[0]
            table.named = True
            self.fast += c.frames
        return b

    def column(self, number: int, ts: int, conv: tuple, raw: bytes) -> bool:
        """Columns only: take a datagram the fast path takes into :attr:`rows` (its frame and
        value rows appended to its direction's :class:`DirColumns`, no :class:`Decoded`, no
        Updates) and return True; False when it is not one (decode it). The same values as
        :meth:`_fast` gives (the tests compare them); the frames that last set each value and
        the last full set are written to the table by :meth:`take_columns`, which the caller
        calls before anything else is decoded."""
        found = self._match(conv, raw)
        if found is None:
            return False
        h, lay, src, dst, values = found
        c = self.rows.get(h)  # (by direction: one _Hot each)
        if c is None:
            c = self.rows[h] = DirColumns(conv, src, dst, h.table)
        table = h.table
        vars_ = table.vars
        sent = table.sent_names
        stamp = (len(vars_), len(sent))
        if lay.stamp != stamp:  # as _fast: what the layout leaves out, and the kind before the frame
            present = lay.present
            lay.missing = tuple(n for n in sent if n not in present)
            lay.full = bool(present) and sum(1 for n in present if n in sent) == len(sent)
            lay.stamp = stamp
        cols = lay.cols
        key = (h.version, stamp)
        if not cols or cols[0] != key:
            miss = lay.missing
            cols = lay.cols = (key, any(n not in sent for n in lay.names), tuple(vars_[n].type_code for n in miss),
                               (True,) * len(miss), (False,) * len(miss), (False,) * len(lay.names))
        full = lay.full
        if cols[1]:  # a name sent for the first time takes the next index (as _fast)
            for name in lay.names:
                if name not in sent:
                    sent[name] = len(sent)
            lay.stamp = (-1, -1)
        c.ordinal.append(self.taken)
        self.taken += 1
        c.number.append(number)
        c.ts_ns.append(ts)
        c.raw.append(raw)
        texts = c.text
        changed = c.changed
        names = lay.names
        for name, dval in zip(names, values):
            text = dval[1:]
            v = vars_[name]
            if v.text != text:
                v.text = text
                changed.append(True)
            else:
                changed.append(False)
            texts.append(text)
        c.name += names
        c.type_code += lay.types
        c.carried += cols[5]
        k = len(names)
        if self.carried:
            miss = lay.missing
            if miss:
                carried = [vars_[n].text for n in miss]
                if None in carried:  # (a variable with no value yet: no row)
                    for n, text, tc in zip(miss, carried, cols[2]):
                        if text is not None:
                            c.name.append(n)
                            texts.append(text)
                            c.type_code.append(tc)
                            c.carried.append(True)
                            changed.append(False)
                            k += 1
                else:
                    c.name += miss
                    texts += carried
                    c.type_code += cols[2]
                    c.carried += cols[3]
                    changed += cols[4]
                    k += len(miss)
        c.nvalues.append(k)
        seen = c.layouts.get(lay)
        if seen is None:
            c.layouts[lay] = [number, ts]
        else:
            seen[0], seen[1] = number, ts
        sync = h.sync
        if full:
            c.last_full = number, ts
            sync[1] = ts
            c.kind.append("full")
            c.late.append(False)
        else:
            since = sync[1] if sync[1] is not None else sync[0]
            c.kind.append("delta")
            c.late.append(ts - since > self.late_ns)
        return True

    def _lane(self, buf: bytes, off: int) -> _ColLane | None:
        """The run taker of the direction of the record at ``off`` of a classic pcap block (its
        addresses, ports and letters, read where a plain Ethernet/IPv4/UDP frame has them), made
        again when the direction's state moved since; None when the direction has no fast state
        or no pattern (the record goes the usual way)."""
        if len(buf) < off + 62:
            return None
        start = off + 58
        key = buf[off + 42 : off + 54] + buf[start + 2 : start + 4]
        lane = self._lanes.get(key)
        # (the direction's state, checked at every run's start)
        if lane is None:
            a = key[:12]
            sport, dport = struct.unpack_from("!HH", a, 8)
            conv = ("udp", socket.inet_ntoa(a[:4]), sport, socket.inet_ntoa(a[4:8]), dport)
            letters = key[12:].decode("latin-1")
            hkey = (conv, letters[1], letters[0])
        else:
            hkey = lane.hkey
        h = self._hot.get(hkey)
        if h is None:
            return None
        t = h.table
        stamp = (h.version, len(t.vars), len(t.sent_names), t.named)
        if lane is None or lane.h is not h or lane.stamp != stamp:
            if len(self._lanes) >= MAX_CONVERSATIONS:
                self._lanes.clear()
            lane = self._lanes[key] = _ColLane(h, hkey, stamp, key)
        return lane if lane.rx is not None else None

    def column_run(self, buf: bytes, sbuf: str, off: int, number: int, mult: int) -> tuple[int, int, int, int] | None:
        """Columns only: take a run of a classic little-endian pcap block's Ethernet records
        (``buf`` from ``off``, ``sbuf`` the block as latin-1; ``number``: the last record's
        number; ``mult``: 1 for nanosecond times, 1000 for microseconds) into :attr:`rows`
        while each is a plain IPv4/UDP datagram of one direction holding one frame its
        :class:`_ColLane` pattern matches with a right checksum, at most until :attr:`taken`
        reaches :data:`BATCH_FRAMES`. The rows are those :meth:`column` makes (the tests compare
        them with the reference); the texts, the frames that set them and the sync state are
        written to the table at the end of the run. Returns ``(offset, number, frames taken,
        bytes)``, or None when the record at ``off`` is not one (decode it the usual way)."""
        lane = self._lane(buf, off)
        if lane is None:
            return None
        h = lane.h
        vs = lane.vs
        cur = [v.text for v in vs]
        rng = range(len(vs))
        unvalued = [i for i in rng if cur[i] is None]  # (a frame giving one a value: not taken)
        ordinal = self.taken
        off, groups, stamps, raws, wire = _walk(lane, buf, sbuf, off, BATCH_FRAMES - ordinal, mult, unvalued)
        if not groups:
            return None
        nvalued = len(vs) - len(unvalued)
        c = self.rows.get(h)
        if c is None:
            c = self.rows[h] = DirColumns(lane.conv, lane.src, lane.dst, h.table)
        names, types, carry = lane.names, lane.types, lane.carry
        setn = [v.set_in for v in vs]
        sett = [v.set_at for v in vs]
        carried_rows = self.carried
        sync = h.sync
        late_ns = self.late_ns
        o_app, n_app, t_app, r_app, k_app, l_app, v_app = (c.ordinal.append, c.number.append, c.ts_ns.append,
                                                           c.raw.append, c.kind.append, c.late.append,
                                                           c.nvalues.append)
        nm_app, tx_app, tc_app, ca_app, ch_app = (c.name.append, c.text.append, c.type_code.append,
                                                 c.carried.append, c.changed.append)
        last_full = None
        for n, (g, ts, raw) in enumerate(zip(groups, stamps, raws), ordinal):
            number += 1
            held = 0
            for i in rng:
                v = g[i]
                if v is None:
                    continue
                held += 1
                nm_app(names[i])
                tx_app(v)
                tc_app(types[i])
                ca_app(False)
                if v != cur[i]:
                    cur[i] = v
                    ch_app(True)
                else:
                    ch_app(False)
                setn[i] = number
                sett[i] = ts
            k = held
            if held == nvalued and held:  # every variable with a value (every sent name): a full set
                full = True
            else:
                full = False
                if carried_rows:
                    for i in carry:
                        if g[i] is None and cur[i] is not None:
                            nm_app(names[i])
                            tx_app(cur[i])
                            tc_app(types[i])
                            ca_app(True)
                            ch_app(False)
                    k = nvalued
            o_app(n)
            n_app(number)
            t_app(ts)
            r_app(raw)
            v_app(k)
            if full:
                last_full = number, ts
                sync[1] = ts
                k_app("full")
                l_app(False)
            else:
                since = sync[1] if sync[1] is not None else sync[0]
                k_app("delta")
                l_app(ts - since > late_ns)
        n = len(groups)
        self.taken = ordinal + n
        for v, text, sn, st in zip(vs, cur, setn, sett):
            v.text, v.set_in, v.set_at = text, sn, st
        if last_full is not None:
            c.last_full = last_full
        h.last.clear()
        return off, number, n, wire

    def count_run(self, buf: bytes, sbuf: str, off: int, number: int, mult: int) -> tuple[int, int, int, int] | None:
        """Counts only: take a run of a classic little-endian pcap block's Ethernet records into
        :attr:`batch` (arguments and result as :meth:`column_run`: the same records, the same
        :class:`_ColLane` pattern, at most :data:`BATCH_FRAMES` a run), the sums
        :meth:`count` makes of each frame. A frame costs one struct call, one match, its
        checksum and its sync clock; its values are kept as the match's groups and summed per
        variable once a run, at C speed (how many, which changed, to what, and the full-set size after each
        frame). The texts, the frames that last set them and the sync state are written to the
        table at the end of the run."""
        lane = self._lane(buf, off)
        if lane is None:
            return None
        h = lane.h
        vs = lane.vs
        nv = len(vs)
        cur = [v.text for v in vs]
        unvalued = [i for i in range(nv) if cur[i] is None]  # (a frame giving one a value: not taken)
        off, groups, stamps, _raws, wire = _walk(lane, buf, sbuf, off, BATCH_FRAMES, mult, unvalued)
        n = len(groups)
        if not n:
            return None
        # a full set holds every variable with a value (every sent name): its groups' Nones are
        # the variables without one (and a direction with no value has no full set)
        full_nones = len(unvalued) if len(unvalued) < nv else -1
        late_ns = self.late_ns
        sync = h.sync
        full_ts = sync[1]
        since = full_ts if full_ts is not None else sync[0]
        gaps: list[int] = []
        late = nfull = 0
        # (the Nones of each frame's groups counted at C speed, the clock walked after the run)
        nones = list(map(tuple.count, groups, repeat(None)))
        for k, ts in zip(nones, stamps):
            if k == full_nones:
                if full_ts is not None:
                    gaps.append(ts - full_ts)
                full_ts = since = ts
                nfull += 1
            elif ts - since > late_ns:
                late += 1
        last_full = n - 1 - nones[::-1].index(full_nones) if nfull else -1
        first = number + 1  # the run's records are numbered first, first + 1, ...
        number += n
        sync[1] = full_ts
        c = self.batch.get(h)
        if c is None:
            c = self.batch[h] = DirCounts(lane.conv, lane.src, lane.dst, h, stamps[0], self._hot_size(h))
        c.frames += n
        c.stamps += stamps
        c.bytes += wire - 42 * n  # (the frames: the records less their Ethernet, IP and UDP headers)
        c.full += nfull
        c.late += late
        c.gaps += gaps
        lo, hi = min(stamps), max(stamps)
        if lo < c.first_ts:
            c.first_ts = lo
        if hi > c.last_ts:
            c.last_ts = hi
        # per variable, over the run's frames: where it is present, its values, which of them
        # changed it; the full-set size after frame j is the size before the run plus the
        # length changes at frames <= j, so the run's sum of sizes takes each change
        # (n - where it happened) times
        size = c.size
        full_bytes = n * (size + 14)  # "[:AB|N0" ... "|CXX]" CR LF around the values
        held, changed = c.held, c.changed
        frames = range(n)
        for i, col in enumerate(zip(*groups)):
            if i == nv:
                break  # (the checksums)
            present = list(map(is_not, col, repeat(None)))
            at = list(compress(frames, present))
            if not at:
                continue
            v = vs[i]
            name = v.name
            vals = list(compress(col, present))
            held[name] = held.get(name, 0) + len(vals)
            old = cur[i]
            moved = list(map(ne, vals, [old, *vals[:-1]]))
            if True in moved:
                texts = list(compress(vals, moved))
                lens = list(map(len, texts))
                full_bytes += sum(map(mul, map(sub, lens, [len(old), *lens[:-1]]),  # type: ignore[arg-type]
                                      map(sub, repeat(n), compress(at, moved))))
                size += lens[-1] - len(old)  # type: ignore[arg-type]
                known = changed.get(name)
                if known is None:
                    changed[name] = texts
                else:
                    known += texts
                v.text = texts[-1]
            j = at[-1]
            v.set_in, v.set_at = first + j, stamps[j]
        c.size = size
        c.full_bytes += full_bytes
        if last_full >= 0:
            c.last_full = first + last_full, stamps[last_full]
        h.last.clear()  # (the Updates kept for reuse hold values the run replaced)
        return off, number, n, wire

    def take_columns(self) -> Columns:
        """What :meth:`column` gathered since the last call (then empty), the tables brought up
        to date (which frame last set each value, the last full set, the form)."""
        rows, frames = self.rows, self.taken
        self.rows, self.taken = {}, 0
        dirs = {}
        for h, c in rows.items():
            table = c.table
            vars_ = table.vars
            for lay, (number, ts) in sorted(c.layouts.items(), key=lambda kv: kv[1][0]):
                for name in lay.names:
                    v = vars_[name]
                    if v.set_in is None or number > v.set_in:  # (a run of column_run may have set it since)
                        v.set_in, v.set_at = number, ts
            if c.last_full is not None:
                table.last_full_at, table.last_full_in = c.last_full[1], c.last_full[0]
            table.named = True
            h.last.clear()  # (the Updates kept for reuse hold values the batch replaced)
            self.fast += len(c.number)
            dirs[(c.conv, c.src, c.dst)] = c
        return Columns(dirs, frames)

    @staticmethod
    def _hot_size(h: _Hot) -> int:
        """Bytes of the values of a full set of the direction (named form, without the frame's
        13 bytes and CR LF): :func:`sharedlink.analysis.stats.full_size`'s rule."""
        return sum(_named_size(n, v.type_code, v.text) for n, v in h.table.vars.items())

    @staticmethod
    def _layout_full(table: VariableTable, lay: _Layout) -> bool:
        stamp = (len(table.vars), len(table.sent_names))
        if lay.stamp != stamp:
            present = lay.present
            lay.missing = tuple(n for n in table.sent_names if n not in present)
            lay.full = bool(present) and sum(1 for n in present if n in table.sent_names) == len(table.sent_names)
            lay.stamp = stamp
        return lay.full

    # -- changes only (diff) ------------------------------------------------------------------

    def reference(self, sf: StreamFrame) -> Decoded:
        """One frame (``sf.frame`` parsed) through the reference path, the core's state following
        it: what :meth:`decode` does with a frame its fast path does not take. In the changes-only
        mode every frame :meth:`change_at` does not take comes here (one mode a Decoder: the
        Decoded fast path would move values under the compiled layouts)."""
        d = ReferenceDecoder.decode(self, sf)
        self._learn(d)
        return d

    def compiled(self, conv: tuple, src: str, dst: str) -> _Compiled | None:
        """Changes only: the compiled layouts of a direction whose frames the fast path takes
        (:class:`_Compiled`; its ``take`` decodes a frame), made or brought up to date from its
        table; None when it has none (its frames go to :meth:`reference`). Valid until the next
        frame through :meth:`reference`. One mode a Decoder: :meth:`decode` would move values
        under the compiled layouts."""
        self._use("changes")
        h = self._hot.get((conv, src, dst))
        if h is None:
            return None
        c = h.compiled
        if c is None:
            c = h.compiled = _Compiled(h, (dst + src).encode("latin-1", "replace"))
        elif c.version != h.version:
            c.build(h)
        return c if c.named is not None or c.pos is not None else None

    def _learn(self, d: Decoded) -> None:
        if d.kind == "declaration":
            self._hot.clear()
            return
        if d.checksum_ok is False:
            return  # changed nothing
        key = (d.conv, d.src, d.dst)
        text = d.raw.decode("latin-1")
        m = _HOT.fullmatch(text)
        sync = self._sync.get((conversation_key(d.conv), d.src, d.dst))
        named = d.table.named
        # (a bare N0 is named only in a direction already named, else it is read as positional)
        if m is None or named is not True:
            m = None
            mp = _HOT_POS.fullmatch(text) if named is False else None
        if (m is None and mp is None) or d.checksum_ok is not True or d.kind not in DATA_KINDS or sync is None:
            self._hot.pop(key, None)
            return
        h = self._hot.get(key)
        if h is None or h.table is not d.table or h.sync is not sync:
            if h is None and len(self._hot) >= MAX_CONVERSATIONS:
                return
            h = self._hot[key] = _Hot(d.table, sync)
        h.version += 1
        h.last.clear()  # the reference path may have moved a type, an index or a value
        h.pos.clear()  # slots are named as this frame's decoding says, not as an earlier one's
        if m is None:
            # a positional layout: the names the reference path gave the slots, in slot order
            ups = d.updates
            n = len(mp.group(3)[2:].split("|D"))
            vars_ = d.table.vars
            if len(ups) == n and all(u.index == i and u.name in vars_ for i, u in enumerate(ups)):
                names = tuple(u.name for u in ups)
                h.pos[n] = _Layout(names, (), tuple(vars_[x] for x in names))
            return
        parts = m.group(3).split("|")  # the body ends with its last "|": one more, empty part
        names = tuple(q[1:] for q in parts[1::3])
        if len(h.layouts) < MAX_LAYOUTS and all(n in d.table.vars for n in names):
            h.layouts[_layout_key(parts)] = _Layout(names, tuple(int(t[1:]) for t in parts[0:-1:3]))

    def _fast(self, number: int, ts: int, conv: tuple, raw: bytes, h: _Hot, lay: _Layout, src: str, dst: str,
              values: list[str]) -> Decoded:
        table = h.table
        vars_ = table.vars
        sent = table.sent_names
        last = h.last
        updates: list[Update] = []
        add = updates.append
        stamp = (len(vars_), len(sent))
        if h.stamp != stamp or table.named is not True:  # new names or another form: indexes may differ
            last.clear()
            h.stamp = stamp
        if lay.stamp != stamp:  # the direction's names changed: what the layout leaves out, again
            present = lay.present
            lay.missing = tuple(n for n in sent if n not in present)
            # the kind before the frame, as VariableTable.kind (a bare N0 is a delta)
            lay.full = bool(present) and sum(1 for n in present if n in sent) == len(sent)
            lay.stamp = stamp
        for name, dval in zip(lay.names, values):
            text = dval[1:]
            v = vars_[name]
            index = sent.get(name)
            if index is None:
                index = sent[name] = len(sent)
            changed = v.text != text
            v.text, v.set_in, v.set_at = text, number, ts
            u = last.get(name)
            if changed or u is None or u.changed or u.carried or u.index != index or u.text != text:
                u = last[name] = _update(v, index, False, None, changed)
            add(u)
        if len(sent) != stamp[1]:
            lay.stamp = (-1, -1)
        if self.carried:
            for name in lay.missing:
                v = vars_[name]
                text = v.text
                if text is None:
                    continue
                u = last.get(name)
                if u is None or not u.carried or u.carried_from != v.set_in or u.text != text:
                    u = last[name] = _update(v, sent.get(name, table._index(name)), True, v.set_in, False)
                add(u)
        table.named = True
        return self._fast_decoded(number, ts, conv, raw, h, lay.full, updates, src, dst)

    def _fast_positional(self, number: int, ts: int, conv: tuple, raw: bytes, h: _Hot, lay: _Layout, src: str,
                         dst: str, values: list[str]) -> Decoded:
        """A positional frame, as :meth:`VariableTable._positional` decodes it (a slot without a
        value: its variable carried; full when every slot that has held a value has one)."""
        table = h.table
        filled = table.filled
        n = len(values)
        last = h.last
        if table.named is not False:  # the named path's Updates index names by when they were sent
            last.clear()
        full = True
        for i in filled:  # the kind before the frame, as VariableTable.kind
            if i >= n or not values[i]:
                full = False
                break
        updates: list[Update] = []
        add = updates.append
        for i, (v, text) in enumerate(zip(lay.vars, values)):
            name = v.name
            u = last.get(name)
            if not text:
                t = v.text
                if u is None or not u.carried or u.index != i or u.carried_from != v.set_in or u.text != t:
                    u = last[name] = _update(v, i, True, v.set_in, False)
                add(u)
                continue
            if i not in filled:
                filled.add(i)
            changed = v.text != text
            v.text, v.set_in, v.set_at = text, number, ts
            if changed or u is None or u.changed or u.carried or u.index != i or u.text != text:
                u = last[name] = _update(v, i, False, None, changed)
            add(u)
        table.named = False
        return self._fast_decoded(number, ts, conv, raw, h, full, updates, src, dst)

    def _fast_decoded(self, number: int, ts: int, conv: tuple, raw: bytes, h: _Hot, full: bool, updates: list[Update],
                      src: str, dst: str) -> Decoded:
        """A fast frame's ending, named or positional: the sync clock (a full set resets it, a
        delta past the interval is late) and the :class:`Decoded`."""
        table = h.table
        sync = h.sync
        gap: int | None = None
        late = False
        if full:
            table.last_full_at, table.last_full_in = ts, number
            if sync[1] is not None:
                gap = ts - sync[1]
            sync[1] = ts
        else:
            since = sync[1] if sync[1] is not None else sync[0]
            late = ts - since > self.late_ns
        self.fast += 1
        ups = tuple(updates)
        return Decoded(number, ts, conv, raw, None, "full" if full else "delta", True, ups, table, late, gap, ups, None,
                       src, dst)


# -- captures ---------------------------------------------------------------------------------

#: Ethernet II, IPv4 without options (IHL 5), UDP: bytes 12..14 of the packet, and byte 23
_ETH_IPV4 = b"\x08\x00\x45"
_UDP = 17


def _walk(lane: _ColLane, buf: bytes, sbuf: str, off: int, room: int, mult: int, unvalued: list[int]
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
    unpack_x = _PCAP_UDP.unpack_from
    struct_error = struct.error
    swap = _SWAP16
    eth_ipv4 = _ETH_IPV4
    cksub = _CKSUB
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
        if (here != lane_addr or e > end or eth != eth_ipv4 or proto != 17 or frag & 0xFFBF or incl <= 50
                or incl > 65000 or tl != swap[incl - 14] or ul != swap[incl - 34]):
            break
        m = rx(sbuf, start, e)
        if m is None:
            break
        g = m.groups()
        if unvalued and any(g[i] is not None for i in unvalued):
            break
        raw = buf[start:e]
        # the checksum: adler32's low half is 1 + the byte sum for up to 256 bytes (C speed)
        if (((adler32(raw) & 0xFFFF) if e - start <= 256 else sum(raw) + 1) - cksub[g[-1]]) & 0xFF:
            break
        off = e
        wire += incl
        g_app(g)
        t_app(sec * NS + frac * mult)
        r_app(raw)
        n += 1
    return off, groups, stamps, raws, wire


class Counted(NamedTuple):
    """Counts only (:meth:`Decoder.capture` with ``counts``): the frames the fast path took since
    the previous item, per direction. It comes before the next item of any other kind, so
    callers see everything in capture order."""

    dirs: dict[tuple, DirCounts]


class Columns(NamedTuple):
    """Columns only (:meth:`Decoder.capture` with ``columns``): the frames the fast path took
    since the previous item, per direction (``frames`` in all: each direction's ``ordinal`` s
    number them 0 .. frames - 1 in capture order). It comes before the next item of any other
    kind, so callers see everything in capture order."""

    dirs: dict[tuple, DirColumns]
    frames: int


#: fast frames gathered into one :class:`Columns` at most, into one :class:`Counted` about (at
#: most twice as many: a run of :meth:`Decoder.count_run` takes up to as many)
BATCH_FRAMES = 512


def _capture_items(dec: Decoder, path: str | Path, progress: Callable[[int, int], None] | None, counting: bool = False,
                   columns: bool = False) -> Iterator[Decoded | StreamFrame | tuple[int, int] | Counted | Columns]:
    """The record loop of :meth:`Decoder.capture`: plain Ethernet/IPv4/UDP records (not
    fragments) go to :meth:`Decoder.decode_datagram` (``counting``: first to
    :meth:`Decoder.count`; ``columns``: to :meth:`Decoder.column`) straight from the record's bytes; every other record through the
    general reader's packet decoder and splitters (as :func:`~sharedlink.capture.stream.iter_frames`)."""
    serial = SerialSplitter()
    packets = PacketDecoder().decode  # IP fragments reassembled
    splitter = dec.splitter
    general = ReferenceDecoder.decode
    addrs: dict[bytes, tuple[str, str, int, str, int]] = {}
    datagram = dec.decode_datagram
    count = dec.column if columns else dec.count
    take_batch = dec.take_columns if columns else (lambda: Counted(dec.take_batch()))
    pending = (lambda: dec.rows) if columns else (lambda: dec.batch)
    runs = dec.column_run if columns else dec.count_run if counting else None
    counting = counting or columns
    taken = 0  # frames in dec.batch (dec.rows)
    unpack = _UDP_HEAD.unpack_from
    read = 24  # bytes of the file read, about (pcap's headers; pcapng's blocks are a little longer)
    try:
        for number, ts_ns, linktype, data, flags, interface in _records(path, runs):
            if linktype == _RUN:  # a run taker took ts_ns frames (flags: their bytes) into dec.rows (dec.batch)
                if progress is not None:
                    read += flags + 16 * ts_ns
                    if number >> 12 != (number - ts_ns) >> 12:
                        progress(read, number)
                taken = dec.taken if columns else taken + ts_ns
                if taken >= BATCH_FRAMES:
                    yield take_batch()
                    taken = 0
                continue
            if progress is not None:
                read += 16 + len(data)
                if not number & 4095:
                    progress(read, number)
            if linktype == LINKTYPE_ETHERNET and len(data) >= 42:
                eth, tlen, frag, proto, key, ulen = unpack(data, 12)
            else:
                eth = None
            if eth == _ETH_IPV4 and proto == _UDP:
                if not frag & 0x3FFF and tlen >= 20:
                    conv = addrs.get(key)
                    if conv is None:
                        if len(addrs) > MAX_CONVERSATIONS:
                            addrs.clear()
                        sport, dport = struct.unpack_from("!HH", key, 8)
                        conv = addrs[key] = ("udp", socket.inet_ntoa(key[:4]), sport, socket.inet_ntoa(key[4:8]), dport)
                    end = min(14 + tlen, len(data))
                    if end >= 42:  # (else the general decoder's verdict: not a UDP datagram)
                        stop = min(34 + ulen, end) if ulen >= 8 else end
                        if stop > 42:
                            payload = data[42:stop]
                            if counting:
                                if count(number, ts_ns, conv, payload):
                                    taken += 1
                                    if taken >= BATCH_FRAMES:
                                        yield take_batch()
                                        taken = 0
                                    continue
                                if taken:
                                    yield take_batch()
                                    taken = 0
                            yield from datagram(number, ts_ns, conv, payload)
                        continue
            if taken:
                yield take_batch()
                taken = 0
            if linktype in USER_LINKTYPES:
                for item in serial.feed(number, ts_ns, linktype, data, flags, interface):
                    yield from _decode_item(dec, general, item)
                continue
            dg = packets(linktype, data)
            if dg is None:
                yield number, ts_ns
                continue
            for sf in splitter.split(number, ts_ns, dg):
                yield from _decode_item(dec, general, sf)
    except CaptureError:
        if pending():
            yield take_batch()
        for item in serial.flush():
            yield from _decode_item(dec, general, item)
        raise
    if pending():
        yield take_batch()
    for item in serial.flush():
        yield from _decode_item(dec, general, item)


#: a classic little-endian pcap record header
_PCAP_REC = struct.Struct("<IIII")
#: bytes of a classic pcap file read at a time
PCAP_BLOCK = 1 << 20


#: the link type :func:`_records` gives a run ``fast`` took: ``(last number, frames, _RUN, b"", bytes, 0)``
_RUN = -1


def _records(path: str | Path, fast: Callable | None = None) -> Iterator[tuple[int, int, int, bytes, int, int]]:
    """``(number, ts_ns, link type, data, flags, interface)`` of every record: a regular classic
    little-endian pcap file read in blocks here (no Record object, one read a block), anything
    else through :func:`~sharedlink.capture.pcapio.read_records`. The same records and the
    same :class:`~sharedlink.capture.pcapio.CaptureError` s either way. ``fast``
    (:meth:`Decoder.column_run` or :meth:`Decoder.count_run`, for Ethernet pcap files): offered
    each record of a block first; a run it takes comes as one item with link type :data:`_RUN`."""
    p = str(path)
    fh = None
    if os.path.isfile(p):
        try:
            fh = open(p, "rb")  # noqa: SIM115 - closed below
        except OSError:
            fh = None  # read_records reports it
    if fh is None:
        for r in read_records(path):
            yield r.number, r.ts_ns, r.linktype, r.data, r.flags, r.interface
        return
    with fh:
        head = fh.read(24)
        magic = struct.unpack_from("<I", head)[0] if len(head) >= 4 else None
        if magic not in (PCAP_MAGIC_NS, PCAP_MAGIC_US) or len(head) < 24:
            fh.close()
            for r in read_records(path):
                yield r.number, r.ts_ns, r.linktype, r.data, r.flags, r.interface
            return
        name = shown_name(path)
        _endian, mult, linktype = pcap_header(name, head)
        unpack = _PCAP_REC.unpack_from
        number = 0
        rest = b""
        if linktype != LINKTYPE_ETHERNET:
            fast = None
        sbuf = ""
        skip = miss = 0  # records not offered to fast (after misses in a row: 0, 1, 3, 7 ... 63)
        while True:
            block = fh.read(PCAP_BLOCK)
            eof = not block
            buf = rest + block if rest else block
            block = b""  # (at most two blocks' worth held: this one's bytes and text)
            end = len(buf)
            off = 0
            if fast is not None:
                sbuf = buf.decode("latin-1")
            while off + 16 <= end:
                if fast is not None:
                    if skip:
                        skip -= 1
                    else:
                        run = fast(buf, sbuf, off, number, mult)
                        if run is not None:
                            miss = 0
                            off, number, taken, wire = run
                            yield number, taken, _RUN, b"", wire, 0
                            continue
                        skip = miss  # (a capture fast takes nothing of costs it a call in 64 records)
                        miss = min(2 * miss + 1, 63)
                sec, frac, incl, _orig = unpack(buf, off)
                if incl > 0x4000000:
                    raise CaptureError(name, number + 1, f"record length {incl} is implausible (damaged file)")
                e = off + 16 + incl
                if e > end:
                    break
                number += 1
                yield number, sec * NS + frac * mult, linktype, buf[off + 16 : e], 0, 0
                off = e
            rest = buf[off:]
            buf = b""
            sbuf = ""
            if eof:
                break
        if rest:
            if len(rest) < 16:
                raise CaptureError(name, number + 1, f"truncated record header ({len(rest)} of 16 bytes)")
            incl = _PCAP_REC.unpack_from(rest)[2]
            raise CaptureError(name, number + 1, f"truncated record ({len(rest) - 16} of {incl} bytes)")


def _decode_item(dec: Decoder, general: Callable, item: StreamFrame | tuple[int, int]
                 ) -> Iterator[Decoded | StreamFrame | tuple[int, int]]:
    if isinstance(item, StreamFrame):
        if item.frame is not None:
            d = general(dec, item)
            dec._learn(d)
            yield d
            return
        yield from dec.unframed(item)
        return
    yield item


#: from byte 12 of an Ethernet/IPv4 packet: the type and the IP version and header length (3
#: bytes), IP total length, flags and fragment offset, (TTL skipped) protocol, (checksum
#: skipped) the addresses and UDP ports (12 bytes: the conversation), UDP length
_UDP_HEAD = struct.Struct("!3sxHxxHxB2x12sH")


def iter_decoded(
    path: str | Path,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
    carried: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> Iterator[Decoded | StreamFrame | tuple[int, int]]:
    """Every item of a capture, through the core (:class:`Decoder`): :class:`Decoded` for
    frames, the noise :class:`StreamFrame` and ``(number, ts_ns)`` for other records unchanged.
    Raises :class:`~sharedlink.capture.pcapio.CaptureError` on damage, after everything before
    it. ``carried`` False: named frames' carried values are left out of ``updates``;
    ``progress(bytes read, records)`` is called now and then."""
    return Decoder(variables, sync_interval, carried).capture(path, progress)


def format_time(ts_ns: int) -> str:
    """UTC ISO 8601 with nanoseconds: ``2026-01-01T12:00:00.200000000Z``. Any year (past 9999
    it has more digits, as ISO 8601's expanded years; before year 1 a sign)."""
    global _last_second
    sec, frac = divmod(ts_ns, NS)
    last = _last_second  # (one tuple, replaced whole: safe between threads)
    if sec != last[0]:  # frames come several a second: the date and time once a second
        last = _last_second = (sec, _format_second(sec))
    return "%s.%09dZ" % (last[1], frac)


_last_second: tuple[int | None, str] = (None, "")


def _format_second(sec: int) -> str:
    days, rest = divmod(sec, 86400)
    y, m, d = _civil_from_days(days)
    year = "%04d" % y if 0 <= y <= 9999 else "%+05d" % y
    return "%s-%02d-%02dT%02d:%02d:%02d" % (year, m, d, rest // 3600, rest // 60 % 60, rest % 60)


def _civil_from_days(z: int) -> tuple[int, int, int]:
    """(year, month, day) of day ``z`` counted from 1970-01-01, proleptic Gregorian, any year
    (Howard Hinnant's ``civil_from_days``)."""
    z += 719468
    era = z // 146097
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    d = doy - (153 * mp + 2) // 5 + 1
    m = mp + 3 if mp < 10 else mp - 9
    return yoe + era * 400 + (m <= 2), m, d
