"""Change records of a capture through the decoding core: what ``sharedlink diff`` reads.

:class:`ChangeReader` walks a capture's records (a classic pcap file in large blocks, anything
else through :mod:`sharedlink.capture.pcapio`) and hands every SharedLink frame to the core,
:class:`~sharedlink.analysis.decode.Decoder`, in its changes-only mode: a datagram that is one
frame of a direction the core follows goes to that direction's compiled layouts
(:meth:`~sharedlink.analysis.decode.Decoder.compiled`: no Decoded, no Updates), every other frame to
:meth:`~sharedlink.analysis.decode.Decoder.reference` (a Decoded, through the reference path).
It gives, for each value frame, the variables whose value it changed, as the change records of
:mod:`sharedlink.capture.change_records` in :class:`~sharedlink.capture.stream.Chunk` s, and the
capture's :class:`~sharedlink.capture.stream.SideStats`. ``fast=False`` decodes every frame with
:class:`~sharedlink.analysis.decode.ReferenceDecoder` (the tests' oracle: the same chunks).

State is kept per conversation (addresses, ports and letters; serial: capture direction and
letters), as the dissector keys it; change records carry the letters, which is what ``diff``
aligns on. Two captures carrying the same data give equal records for equal frames, whatever
form (named or positional, full or compressed) carried them.
"""

from __future__ import annotations

import socket
import struct
from array import array
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from sharedlink.analysis.core.patterns import plain_udp
from sharedlink.analysis.decode import VALUE_KINDS, Decoder, ReferenceDecoder
from sharedlink.capture.change_records import SEP_CHANGE, SEP_VALUE, escape
from sharedlink.capture.packets import PacketDecoder
from sharedlink.capture.pcap_blocks import MAX_RECORD, PcapBlocks, implausible
from sharedlink.capture.pcapio import (
    LINKTYPE_ETHERNET,
    NS,
    PCAP_MAGIC_NS,
    PCAP_MAGIC_US,
    CaptureError,
    Record,
    pcap_header,
    records_from,
)
from sharedlink.capture.serial_format import USER_LINKTYPES
from sharedlink.capture.stream import Chunk, FrameSplitter, SerialSplitter, SideStats, StreamFrame, pack_ts
from sharedlink.protocols.codec import Frame, SharedLinkError, declared_list, frame_kind, positional_values
from sharedlink.protocols.limits import MAX_CONVERSATIONS, MAX_SLOTS
from sharedlink.protocols.state import BEACON_VARIABLES, conversation_key, reverse_conversation

_REC = struct.Struct("<IIII")
#: the record header, then from byte 12 of an Ethernet packet as
#: :data:`~sharedlink.analysis.core.patterns.PCAP_UDP` reads it (tested by
#: :func:`~sharedlink.analysis.core.patterns.plain_udp`), and the frame's two letters ("[:AB")
_REC_X = struct.Struct("<IIII12x3sxHxxHxB2x12sH4x2s")


class ChangeReader:
    """Reads one capture into :class:`Chunk` s of change records (see the module doc).

    ``variables`` is the a-priori outbound list positional frames are named by until a
    declaration says otherwise; ``sync_interval`` (seconds) is what "missed" full syncs are
    measured against: a gap between full frames of a direction that rounds to n >= 2
    intervals misses n - 1. ``fast=False`` decodes every frame with the reference decoder.
    ``block``: bytes of the file read at a time (a chunk is given out after each)."""

    def __init__(
        self,
        variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
        sync_interval: float = 1.0,
        fast: bool = True,
        block: int = 1 << 20,
    ) -> None:
        self.dec: ReferenceDecoder = (Decoder if fast else ReferenceDecoder)(variables, sync_interval, carried=False)
        self.link = self.dec.link
        self.sync_ns = max(1, round(sync_interval * NS))
        self.fast_enabled = fast
        self.block = block
        self.stats = SideStats()
        self._sync: dict[tuple, list[int]] = {}  # (conv, key) -> [time of the last full frame, else of the first frame]
        #: the fast lane's directions: letters + addresses and ports as the packet holds them ->
        #: (the take of the core's compiled layouts, the sync entry); emptied after every
        #: reference-path frame and whenever the core makes a direction's layouts again
        self._lanes: dict[bytes, tuple[Any, list[int]]] = {}
        self._convs: dict[bytes, tuple[str, str, int, str, int]] = {}  # addresses and ports -> conversation
        self._splitter = FrameSplitter()
        self._serial = SerialSplitter()
        self._packets = PacketDecoder()  # IP fragments reassembled
        self._base = 0  # index of the first frame of the chunk being built
        self._reset()
        self._last_ts = 0
        self._damage: CaptureError | None = None  # a damaged record _walk stopped at
        self._fh: Any = None  # the capture being read

    def _reset(self) -> None:
        self._ts = array("Q")  # packed timestamps
        self._num = array("q")
        self._recs: list[bytes] = []
        self._events: list[tuple[int, bytes, bytes, int | None]] = []

    # -- reading ------------------------------------------------------------------------

    def chunks(self, path: str | Path) -> Iterator[Chunk]:
        """Yield the capture's chunks. Raises CaptureError (after all good chunks) on damage."""
        p = str(path)
        self.stats.path = p
        try:
            fh = open(p, "rb")  # noqa: SIM115 - closed below
        except OSError as exc:
            raise CaptureError(p, None, exc.strerror or str(exc)) from None
        self._fh = fh  # (its position: Chunk.read)
        with fh:  # opened once and read front to back: a pipe will do
            head = fh.read(24)
            magic = struct.unpack("<I", head[:4])[0] if len(head) >= 4 else None
            if magic in (PCAP_MAGIC_NS, PCAP_MAGIC_US):
                pcap_header(p, head)  # a garbage header is refused, as tshark does
                yield from self._pcap(fh, p, head)
                return
            if magic is not None:
                yield from self._generic(p, records_from(fh, p, head))
                return
        raise CaptureError(p, None, "file too short to be a capture" if head else "empty file")

    def _pcap(self, fh, p: str, head: bytes) -> Iterator[Chunk]:
        """Classic little-endian pcap: walk records in large blocks (the one block walker's)."""
        _endian, mult, linktype = pcap_header(p, head)
        blocks = PcapBlocks(fh, p, self.block)
        number = 0
        for buf in blocks:
            off, number = self._walk(buf, linktype, mult, number, p)
            blocks.keep(buf, off)
            if self._recs:
                yield self._chunk()
            if self._damage is not None:
                break
        yield from self._serial_flush()
        if self._damage is not None:
            raise self._damage
        blocks.end(number)

    def _generic(self, p: str, records: Iterator[Record]) -> Iterator[Chunk]:
        """Any other capture (pcapng, big-endian pcap): records via pcapio, re-packed in
        batches as nanosecond pcap records so the same loop takes them."""
        batch: list[bytes] = []
        linktype = None
        number = 0  # the last record number handed on
        pack = _REC.pack

        def flush() -> Iterator[Chunk]:
            nonlocal number
            buf = b"".join(batch)
            batch.clear()
            _off, number = self._walk(buf, linktype, 1, number, p)  # type: ignore[arg-type]
            if self._recs:
                yield self._chunk()

        while True:
            try:
                rec = next(records)
            except StopIteration:
                break
            except CaptureError:
                if batch:  # what came before the damage still counts
                    yield from flush()
                yield from self._serial_flush()
                raise
            if self.stats.start_ns is None:
                self.stats.start_ns = rec.ts_ns
            if rec.linktype != linktype or len(batch) >= 8192 or rec.number != number + len(batch) + 1:
                if batch:
                    yield from flush()
                linktype = rec.linktype
                number = rec.number - 1
            n = len(rec.data)
            sec, frac = divmod(rec.ts_ns, NS)
            # serial records (their direction is in the EPB flags, which the re-packed
            # records lose) and times beyond what a pcap header holds: one at a time
            if sec >= 1 << 32 or rec.linktype in USER_LINKTYPES:
                if batch:
                    yield from flush()
                self.stats.records += 1
                self.stats.wire_bytes += n
                self._general(rec.number, rec.ts_ns, rec.linktype, rec.data, rec.flags, rec.interface)
                number = rec.number
                if len(self._recs) >= 8192:
                    yield self._chunk()
                continue
            batch.append(pack(sec, frac, n, rec.orig_len) + rec.data)
        if batch:
            yield from flush()
        yield from self._serial_flush()

    def _serial_flush(self) -> Iterator[Chunk]:
        """The end of the capture (or the damage): the serial tails, then the last chunk."""
        self._serial_items(self._serial.flush())
        if self._recs:
            yield self._chunk()

    def _walk(self, buf: bytes, linktype: int, mult: int, number: int, p: str) -> tuple[int, int]:
        """Every complete record in ``buf``; return (offset of the rest, last record number).

        A record that is one frame alone in a plain Ethernet/IPv4/UDP datagram (not a fragment)
        of a direction the core has compiled layouts for goes to their ``take``
        (:meth:`~sharedlink.analysis.decode.Decoder.compiled`), which goes on with the records
        after it while they are that direction's; a record it does not take, and every other
        record, goes to :meth:`_general` (the reference path)."""
        unpack, unpack_x = _REC.unpack_from, _REC_X.unpack_from
        struct_error = struct.error
        fast = self.fast_enabled and linktype == LINKTYPE_ETHERNET
        lanes = self._lanes
        recs, tsarr = self._recs, self._ts
        fulls: list[int] = []
        out = (self._ts.append, self._num.append, recs.append, fulls.append)
        bulk = (self._ts.extend, self._num.extend, recs.extend, fulls.extend)  # (the block tier's)
        general = self._general
        st = self.stats
        end = len(buf)
        off = 0
        if st.start_ns is None and end >= 16:
            sec, frac = unpack(buf, 0)[:2]
            st.start_ns = sec * NS + frac * mult
        nrec = wire = twire = taken = 0
        ts = self._last_ts
        while True:
            try:
                sec, frac, incl, _orig, eth, tl, frag, proto, addr, ul, letters = unpack_x(buf, off)
            except struct_error:
                if off + 16 > end:
                    break
                sec, frac, incl, _orig = unpack(buf, off)
                eth = None
            if fast and eth is not None and plain_udp(eth, tl, frag, proto, incl, ul):
                lane = lanes.get(letters + addr)
                if lane is None:
                    lane = self._lane(letters, addr)
                if lane is not None:
                    off, number, n, w, first = lane[0](buf, off, number, mult, addr, out, bulk)
                    if n:
                        taken += n
                        twire += w
                        if first is not None or fulls:
                            self._after_take(lane[1], letters, first, fulls)
                        last = tsarr[-1]  # the last frame's time, packed
                        ts = (last & 0xFFFFFFFF) * NS + (last >> 32)
                        continue
            d = off + 16
            e = d + incl
            if e > end:
                if incl > MAX_RECORD:  # reported by _pcap once this block's frames are out
                    self._damage = implausible(p, number + 1, incl)
                break
            off = e
            number += 1
            nrec += 1
            wire += incl
            ts = sec * NS + frac * mult
            general(number, ts, linktype, buf[d:e])
        st.records += nrec + taken
        st.wire_bytes += wire + twire
        st.payload_bytes += twire - 42 * taken  # (the frames: the records less their Ethernet, IP and UDP headers)
        if taken:
            self.dec.fast += taken  # type: ignore[attr-defined]
        self._last_ts = ts
        return off, number

    def _after_take(self, sy: list[int], letters: bytes, first: list | None, fulls: list[int]) -> None:
        """After a run a direction's ``take`` took: the first values it reported (the core made the
        direction's layouts again: the lanes are looked up again) and the sync gaps of its full
        frames (``fulls``, emptied; ``sy``: the direction's sync entry)."""
        if first is not None:
            idx = self._base + len(self._recs) - 1
            self._events += ((idx, letters, escape(v.name), v.type_code) for v in first)
            self._lanes.clear()
        if not fulls:
            return
        sync_ns = self.sync_ns
        half = sync_ns // 2
        limit = sync_ns + sync_ns - half  # a gap must round to 2 intervals to miss one
        missed = 0
        prev = sy[0]
        for t in fulls:
            if t - prev >= limit:
                missed += (t - prev + half) // sync_ns - 1
            prev = t
        sy[0] = prev
        self.stats.full += len(fulls)
        self.stats.sync_missed += missed
        fulls.clear()

    def _lane(self, letters: bytes, addr: bytes) -> tuple[Any, list[int]] | None:
        """The fast lane of a direction (letters and the packet's addresses and ports): the
        ``take`` of the core's compiled layouts and the direction's sync entry; None while it
        has none."""
        conv = self._convs.get(addr)
        if conv is None:
            if len(self._convs) >= MAX_CONVERSATIONS:
                self._convs.clear()
            conv = self._convs[addr] = ("udp", socket.inet_ntoa(addr[:4]), int.from_bytes(addr[8:10], "big"),
                                        socket.inet_ntoa(addr[4:8]), int.from_bytes(addr[10:12], "big"))
        dst, src = letters.decode("latin-1")
        c = self.dec.compiled(conv, src, dst)  # type: ignore[attr-defined]
        sy = self._sync.get((conv, letters))
        if c is None or sy is None:  # (a direction the core follows has had a good frame: sy is there)
            return None
        if len(self._lanes) >= MAX_CONVERSATIONS:
            self._lanes.clear()
        lane = self._lanes[letters + addr] = (c.take, sy)
        return lane

    # -- the general path ---------------------------------------------------------------

    def _general(self, number: int, ts: int, linktype: int, data: bytes, flags: int = 0, interface: int = 0) -> None:
        self._last_ts = ts
        if linktype in USER_LINKTYPES:  # serial: the same splitter as iter_frames
            self._serial_items(self._serial.feed(number, ts, linktype, data, flags, interface))
            return
        dg = self._packets.decode(linktype, data)
        if dg is None:
            self.stats.other_packets += 1
            return
        for sf in self._splitter.split(number, ts, dg):
            if sf.frame is None:
                self._unframed(sf)
            else:
                self._frame(sf)

    def _unframed(self, sf: StreamFrame) -> None:
        """Bytes that hold no well-formed frame: the core's malformed frames (counted as frames
        that carry no values, a wrong checksum a failure: docs/fields-sharedlink.md, "Counts")
        and noise (:meth:`~sharedlink.analysis.decode.ReferenceDecoder.unframed`)."""
        st = self.stats
        for item in self.dec.unframed(sf):
            if isinstance(item, StreamFrame):
                st.undecodable += 1
                continue
            st.frames += 1
            st.payload_bytes += len(item.raw)
            if item.checksum_ok is False:
                st.checksum_failures += 1

    def _serial_items(self, items: list[StreamFrame | tuple[int, int]]) -> None:
        for item in items:
            if isinstance(item, tuple):  # a record of another protocol (P2OS, blackboard)
                self.stats.other_packets += 1
            elif item.frame is None:
                self.stats.undecodable += 1  # (a serial link's noise stays noise: serial.lua's wrapper cuts its frames)
            else:
                self._frame(item)

    def _frame(self, sf: StreamFrame) -> None:
        """One frame through the core's reference path (a :class:`Decoded`)."""
        frame = sf.frame
        assert frame is not None
        st = self.stats
        st.payload_bytes += len(sf.raw)
        key = (frame.dst + frame.src).encode("latin-1", "replace")
        value_frame = frame_kind(frame.fields) in VALUE_KINDS  # (frames that carry values: the ones a change stream has a record for)
        if frame.checksum is not None and frame.checksum.ok is False:
            st.checksum_failures += 1  # nothing is learnt from it
            if value_frame:
                self._emit(sf.ts_ns, sf.number, key)
            else:
                st.frames += 1
            return
        self._lanes.clear()  # the core's compiled layouts may change: the lanes are looked up again
        sk = (sf.conv, key)
        sync = self._sync.get(sk)
        if sync is None:
            sync = self._sync[sk] = [sf.ts_ns]
        conv = conversation_key(sf.conv)
        decl = declared_list(frame.fields)
        if decl is not None and decl[0] == "L":  # an inbound list: the reverse direction's names
            target = self.link.table(frame.dst, frame.src, reverse_conversation(conv))
            tkey = (frame.src + frame.dst).encode("latin-1", "replace")
        else:
            target = self.link.table(frame.src, frame.dst, conv)
            tkey = key
        # what this frame can give a first value or a new type: the names it holds (linear in
        # the frame, not in the direction's table)
        tvars = target.vars
        touched = _touched_names(frame, target)
        before = {n: (v.text is not None, v.type_code) for n in touched if (v := tvars.get(n)) is not None}
        dec = self.dec
        d = dec.reference(sf) if isinstance(dec, Decoder) else dec.decode(sf)
        parts = [key]
        for u in d.updates if d.kind != "reply" else ():  # a reply's values are never stored (issue 29)
            if u.changed and not u.carried and u.text is not None:
                parts += (SEP_CHANGE, escape(u.name), SEP_VALUE, escape(u.text))
        idx = self._base + len(self._recs)
        tvars = target.vars
        for n in touched:
            v = tvars.get(n)
            if v is not None and v.text is not None and before.get(n) != (True, v.type_code):
                self._events.append((idx, tkey, escape(n), v.type_code))
        if d.kind == "full":
            st.full += 1
            st.sync_missed += self._missed(sf.ts_ns - sync[0])
            sync[0] = sf.ts_ns
        if value_frame:
            self._emit(sf.ts_ns, sf.number, b"".join(parts))
        else:
            st.frames += 1

    def _emit(self, ts: int, number: int, rec: bytes) -> None:
        self._ts.append(pack_ts(ts))
        self._num.append(number)
        self._recs.append(rec)

    def _chunk(self) -> Chunk:
        snapshot: list[tuple[bytes, bytes, bytes]] | None = []
        seen: set[bytes] = set()
        for (_conv, src, dst), t in self.link.tables.items():
            key = (dst + src).encode("latin-1", "replace")
            if key in seen:  # two conversations with these letters: their records interleave
                snapshot = None
                break
            seen.add(key)
            for n, v in t.vars.items():
                if v.text is not None:
                    snapshot.append((key, escape(n), escape(v.text)))
        keys = sorted({r[:2] for r in self._recs})
        c = Chunk(
            self._base,
            self._ts.tobytes(),
            self._num.tobytes(),
            self._recs,
            keys,
            self._events,
            snapshot,
            self._position(),
        )
        self.stats.frames += len(self._recs)
        self.stats.value_frames += len(self._recs)
        self._base += len(self._recs)
        self._reset()
        return c

    def _position(self) -> int:
        """Bytes of the capture read so far (0 when not known: a pipe)."""
        try:
            return self._fh.tell() if self._fh is not None else 0
        except (OSError, ValueError):
            return 0

    def finish(self) -> SideStats:
        """Stats after the last chunk: the trailing sync gap (last full set to the end of the
        capture) is counted here."""
        end = self._last_ts
        for sync in self._sync.values():
            self.stats.sync_missed += self._missed(end - sync[0])
        return self.stats

    def _missed(self, gap: int) -> int:
        """Sync intervals missed in a gap between full frames: it rounds to n intervals."""
        n = (gap + self.sync_ns // 2) // self.sync_ns
        return n - 1 if n >= 2 else 0


def _touched_names(frame: Frame, table: object) -> list[str]:
    """The variables a frame can set or retype in ``table``: the names it holds (``Q``/``R``),
    and for a positional frame the names of its slots."""
    names = [f.text for f in frame.fields if f.letter in ("Q", "R")]
    if not names:
        ordinal, vals = positional_values(frame.fields)
        slot_name, n = table.slot_name, ordinal + len(vals)  # type: ignore[attr-defined]
        names = [slot_name(i, n) for i in range(ordinal, min(n, MAX_SLOTS))]  # (issue 29's naming rule)
    return list(dict.fromkeys(names))  # each once, in order


def read_changes(
    path: str | Path,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
    fast: bool = True,
    block: int = 1 << 20,
) -> Iterator[Chunk | SideStats]:
    """The chunks of one capture, then its :class:`SideStats` (with ``error`` set when the
    file is damaged or missing: everything before the damage has been yielded). ``block``
    is how many bytes of the file are read at a time; ``fast`` False decodes every frame with
    the reference decoder (the tests' oracle)."""
    r = ChangeReader(variables, sync_interval, fast, block)
    try:
        yield from r.chunks(path)
    except CaptureError as exc:
        r.stats.error = str(exc)
    except SharedLinkError as exc:  # pragma: no cover - the codec reports, never raises here
        r.stats.error = f"{path}: {exc}"
    yield r.finish()
