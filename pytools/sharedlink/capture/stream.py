"""Streaming over captures: records -> datagrams -> SharedLink frames -> value changes.

Two layers, both streaming (memory does not grow with the capture):

* :func:`iter_frames` — the general reader any command can use: every SharedLink frame of a
  capture with its record number, timestamp and conversation, TCP streams reassembled, serial
  captures (USER link types) deframed per direction with :mod:`serialcap`'s incremental
  deframer, noise reported. Built on :mod:`pcapio`, :mod:`packets`, :mod:`serialcap` and
  :mod:`codec`.
* :class:`ChangeReader` — the hot path of ``sharedlink diff``: for each frame, the variables
  whose value it changed (the rebuilt value of every variable over time, as a stream of
  changes), in chunks of compact records. It walks classic pcap files in large blocks and
  recognises the common case — one frame per Ethernet/IPv4/UDP datagram, in the layout the
  stream has been using — with one compiled regular expression; everything else goes through
  the general reader and :class:`~sharedlink.protocols.state.LinkState`, so both paths give identical
  results (the tests check this on varied input). State is kept per conversation (addresses,
  ports and letters; serial: capture direction and letters), as the dissector keys it; change
  records carry the letters, which is what ``diff`` aligns on.

Change records are bytes: the frame's destination and source letters, then for each changed
variable ``\\x1f`` name ``\\x1e`` value, in frame order (names and values escaped with
:func:`escape` so the separators cannot occur in them). Two captures carrying the same data
give equal records for equal frames, whatever form (named or positional, full or compressed)
carried them.
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from sharedlink.capture.change_records import SEP_CHANGE as SEP_CHANGE
from sharedlink.capture.change_records import SEP_VALUE as SEP_VALUE
from sharedlink.capture.change_records import escape as escape
from sharedlink.capture.change_records import unescape as unescape
from sharedlink.capture.packets import Datagram, PacketDecoder
from sharedlink.capture.pcapio import (
    LINKTYPE_ETHERNET,
    NS,
    PCAP_MAGIC_NS,
    PCAP_MAGIC_US,
    CaptureError,
    Record,
    pcap_header,
    read_records,
    records_from,
)
from sharedlink.capture.serial_format import DIRECTION_NAMES, USER_LINKTYPES, Piece, StreamReader
from sharedlink.protocols.codec import (
    Frame,
    SharedLinkError,
    declared_list,
    frame_kind,
    iter_segments,
    positional_values,
)
from sharedlink.protocols.limits import MAX_HELD_BYTES, MAX_SLOTS
from sharedlink.protocols.state import (
    BEACON_VARIABLES,
    LinkState,
    parse_variables,
    reverse_conversation,
)

if TYPE_CHECKING:
    from sharedlink.capture import fast_blocks, fast_records
else:  # loaded by the first ChangeReader (the commands that only decode do not pay for their tables)
    fast_blocks: ModuleType | None = None
    fast_records: ModuleType | None = None


def parse_record(rec: bytes) -> tuple[bytes, list[tuple[bytes, bytes]]]:
    """A change record -> (key, [(name, value), ...]); key is destination + source letter."""
    if len(rec) <= 2:
        return rec, []
    out = []
    for part in rec[3:].split(SEP_CHANGE):
        name, _, value = part.partition(SEP_VALUE)
        out.append((name, value))
    return rec[:2], out


#: the old name of :func:`sharedlink.protocols.state.parse_variables`, the one ``--variables`` parser
parse_variable_list = parse_variables


def pack_ts(ts_ns: int) -> int:
    """A timestamp as change chunks carry it: seconds in the low 32 bits, nanoseconds in the
    high ones (for a nanosecond pcap, the record header's 8 bytes read as one integer)."""
    return (ts_ns // NS) | (ts_ns % NS) << 32


def unpack_ts(packed: int) -> int:
    return (packed & 0xFFFFFFFF) * NS + (packed >> 32)


def key_label(key: bytes) -> str:
    """``b"AB"`` (to A from B) -> ``"B>A"``."""
    k = key.decode("latin-1")
    return f"{k[1:2]}>{k[:1]}"


# -- the general reader ---------------------------------------------------------------------


@dataclass(frozen=True)
class StreamFrame:
    """One SharedLink frame (or a piece of noise) found in a capture."""

    number: int  # record number (1-based); for TCP and serial the record that completed the frame
    ts_ns: int
    #: (proto, src, sport, dst, dport); for serial captures (see :class:`SerialSplitter`)
    #: ``("serial", direction name, link type, "", interface id)``
    conv: tuple[str, str, int, str, int]
    raw: bytes  # the frame's bytes (CR LF included) or the noise
    frame: Frame | None  # None: noise that is not a frame
    error: str | None = None


_TCP_BUFFER_MAX = MAX_HELD_BYTES  # an unterminated frame held per TCP conversation, at most
#: frames that carry values: the ones a change stream has a record for
_VALUE_KINDS = ("full", "delta", "reply")


class FrameSplitter:
    """Cuts datagrams into frames; keeps a buffer per TCP conversation so frames split across
    segments are found (segments are taken in capture order; a retransmitted segment, one
    that starts before the data already seen, is skipped)."""

    def __init__(self) -> None:
        self._tcp: dict[tuple[str, str, int, str, int], tuple[int, bytes]] = {}

    def split(self, number: int, ts_ns: int, dg: Datagram) -> list[StreamFrame]:
        conv = (dg.proto, dg.src, dg.sport, dg.dst, dg.dport)
        data = dg.payload
        if dg.proto == "tcp":
            nxt, buf = self._tcp.get(conv, (None, b""))
            if nxt is not None and data and ((dg.tcp_seq - nxt) & 0xFFFFFFFF) >= 0x80000000:
                return []  # retransmission of data already seen
            if len(buf) > _TCP_BUFFER_MAX:  # a '[' that never closes: give up on it as noise
                buf = b""
            if data or dg.tcp_flags & 0x03:
                step = len(data) + (1 if dg.tcp_flags & 0x03 else 0)  # SYN and FIN count one
                nxt = (dg.tcp_seq + step) & 0xFFFFFFFF
            data = buf + data
            self._tcp[conv] = (nxt, b"")  # type: ignore[assignment]
        if not data:
            return []
        out: list[StreamFrame] = []
        for seg in iter_segments(data):
            if seg.frame is None and dg.proto == "tcp" and seg.end == len(data) and seg.error is not None:
                if seg.error.reason == "unterminated frame":
                    start = data.rfind(b"[", seg.start)
                    if start > seg.start:
                        out.append(StreamFrame(number, ts_ns, conv, data[seg.start : start], None, "noise between frames"))
                    self._tcp[conv] = (self._tcp[conv][0], data[start:])
                    break
            err = seg.error.reason if seg.error is not None else None
            out.append(StreamFrame(number, ts_ns, conv, data[seg.start : seg.end], seg.frame, err))
        return out


class SerialSplitter:
    """Serial records (USER link types, ``docs/serial-capture-format.md``) -> SharedLink
    frames and noise, with the incremental deframer of :mod:`sharedlink.capture.serial_format`: one
    :class:`~sharedlink.capture.serial_format.StreamReader` per interface (protocol "auto"), one byte
    stream per direction (EPB flags & 3; classic pcap has none: one stream).

    * A frame or noise is given out when the record that completes it is fed, with that
      record's number and timestamp; :meth:`flush` (end of the capture) gives the tails out,
      numbered and timed by the last record they came from.
    * ``conv`` is ``("serial", direction name, link type, "", interface id)``: the direction
      name ("inbound", "outbound" or "unknown") stands for the source, the link type for the
      source port; there is no destination address ("") and the interface id takes the
      destination port's place, so the tuple keeps the shape and types of the IP ones.
    * Bytes the auto-detection gave up on ("protocol not recognised") are noise, as
      non-SharedLink bytes in a UDP datagram are.
    * Directions carrying another protocol (P2OS, blackboard) are not SharedLink traffic:
      each of their records comes out once as ``(number, ts_ns)``, like a record that is not
      UDP/TCP (callers count those as other records, not as noise).
    """

    def __init__(self) -> None:
        self._readers: dict[int, StreamReader] = {}
        self._linktype: dict[int, int] = {}
        self._reported: dict[tuple[int, int], int] = {}  # (interface, direction) -> last record given out
        self._ts: dict[int, int] = {}  # record number -> timestamp, for records still held
        self._prune_at = 64
        self._last = (0, 0)  # (number, ts_ns) of the last record fed

    def feed(
        self, number: int, ts_ns: int, linktype: int, data: bytes, flags: int = 0, interface: int = 0
    ) -> list[StreamFrame | tuple[int, int]]:
        reader = self._readers.get(interface)
        if reader is None:
            reader = self._readers[interface] = StreamReader("auto")
        self._linktype[interface] = linktype
        self._last = (number, ts_ns)
        self._ts[number] = ts_ns
        d = flags & 3
        out = self._convert(interface, d, reader.feed(d, data, number), number, ts_ns)
        if len(self._ts) >= self._prune_at:
            held = {r for rd in self._readers.values() for df in rd.dirs.values() for r in df.pending_records}
            self._ts = {r: t for r, t in self._ts.items() if r in held}
            self._prune_at = 2 * len(self._ts) + 64
        return out

    def flush(self) -> list[StreamFrame | tuple[int, int]]:
        """The pieces still held at the end of the capture (then the splitter is empty)."""
        out: list[StreamFrame | tuple[int, int]] = []
        for interface, reader in self._readers.items():
            for d, p in reader.flush():
                number = p.records[-1] if p.records else self._last[0]
                out += self._convert(interface, d, [p], number, self._ts.get(number, self._last[1]))
        self._readers.clear()
        self._ts.clear()
        return out

    def _convert(
        self, interface: int, d: int, pieces: list[Piece], number: int, ts_ns: int
    ) -> list[StreamFrame | tuple[int, int]]:
        out: list[StreamFrame | tuple[int, int]] = []
        for p in pieces:
            if p.protocol in ("sharedlink", ""):
                conv = ("serial", DIRECTION_NAMES.get(d, "unknown"), self._linktype.get(interface, 0), "", interface)
                frame = p.frame if isinstance(p.frame, Frame) else None
                out.append(StreamFrame(number, ts_ns, conv, p.data, frame, None if frame is not None else (p.reason or "noise")))
            else:
                key = (interface, d)
                last = self._reported.get(key, 0)
                for r in p.records:
                    if r > last:
                        out.append((r, self._ts.get(r, ts_ns)))
                        last = r
                self._reported[key] = last
        return out


def iter_frames(path: str | Path) -> Iterator[StreamFrame | tuple[int, int]]:
    """Every SharedLink frame and noise segment of a capture, in order.

    Records that are not IPv4/IPv6 UDP or TCP, nor serial (USER link types), yield
    ``(number, ts_ns)`` so callers can count them. Serial records go through
    :class:`SerialSplitter` (frames come out with the record that completed them; records of
    a direction carrying P2OS or blackboard traffic yield ``(number, ts_ns)``). Raises
    :class:`~sharedlink.capture.pcapio.CaptureError` on a damaged file, after everything before the
    damage (the serial tails held at that point included).
    """
    splitter = FrameSplitter()
    serial = SerialSplitter()
    decode = PacketDecoder().decode  # IP fragments reassembled
    try:
        for rec in read_records(path):
            if rec.linktype in USER_LINKTYPES:
                yield from serial.feed(rec.number, rec.ts_ns, rec.linktype, rec.data, rec.flags, rec.interface)
                continue
            dg = decode(rec.linktype, rec.data)
            if dg is None:
                yield rec.number, rec.ts_ns
                continue
            yield from splitter.split(rec.number, rec.ts_ns, dg)
    except CaptureError:
        yield from serial.flush()
        raise
    yield from serial.flush()


# -- change records, fast ---------------------------------------------------------------------

@dataclass
class SideStats:
    """What one capture holds, as the change reader saw it."""

    path: str = ""
    records: int = 0  # capture records
    start_ns: int | None = None  # timestamp of the first record
    wire_bytes: int = 0  # captured bytes of all records
    frames: int = 0  # SharedLink frames
    value_frames: int = 0  # of those, frames that carry values (full, delta, reply): the ones aligned
    payload_bytes: int = 0  # bytes of those frames (CR LF included)
    full: int = 0  # full-sync frames (every known value present)
    sync_missed: int = 0  # sync intervals with no full frame
    checksum_failures: int = 0
    undecodable: int = 0  # noise: datagram bytes that are not a SharedLink frame
    other_packets: int = 0  # records that are not IPv4/IPv6 UDP or TCP
    error: str | None = None  # the capture is damaged here (everything before it was read)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Chunk:
    """A run of frames of one capture. ``start`` is the index of the first frame (counting
    from 0 over the capture); ``events`` name frames where a variable got its first value or
    a new type: ``(frame index, key, name, type code or None)``; ``snapshot`` is every
    variable's value after the last frame: ``(key, name, value)`` (None when several
    conversations share a key's letters: the records then say what the values are)."""

    start: int
    ts: bytes  # array('Q') of packed timestamps (see pack_ts), native byte order
    numbers: bytes  # array('q') of record numbers
    records: list[bytes]  # change records
    keys: list[bytes]  # the keys of this chunk's frames (each once)
    events: list[tuple[int, bytes, bytes, int | None]] = field(default_factory=list)
    snapshot: list[tuple[bytes, bytes, bytes]] | None = field(default_factory=list)
    read: int = 0  # bytes of the file read so far, about (0: not known, e.g. a pipe); for progress bars

    def as_tuple(self) -> tuple:
        return (self.start, self.ts, self.numbers, self.records, self.keys, self.events, self.snapshot, self.read)

    @classmethod
    def from_tuple(cls, t: Sequence) -> Chunk:
        return cls(*t)


class ChangeReader:
    """Reads one capture into :class:`Chunk` s of change records (see the module doc).

    ``variables`` is the a-priori outbound list positional frames are named by until a
    declaration says otherwise; ``sync_interval`` (seconds) is what "missed" full syncs are
    measured against: a gap between full frames of a direction that rounds to n >= 2
    intervals misses n - 1. ``fast=False`` sends every frame through the general path.

    Tiers, each with the same contract (take records, append the same change records, events
    and statistics, return how far they got), the tests checking they agree:

    * the reference path, readable on its own: :meth:`_walk_plain` hands every record to
      :meth:`_general` (datagrams -> :class:`FrameSplitter` / :class:`SerialSplitter` ->
      :class:`LinkState` -> :meth:`_frame`, which emits the record);
    * the per-record fast tier, :func:`sharedlink.capture.fast_records.walk`, for plain
      Ethernet/IPv4/UDP frames of a known layout (:class:`~sharedlink.capture.fast_records.FastKey`,
      made by :meth:`_frame`), everything else passed to :meth:`_general`;
    * the block tier, :func:`sharedlink.capture.fast_blocks.take`, for whole blocks of one
      direction with every value known.
    """

    def __init__(
        self,
        variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
        sync_interval: float = 1.0,
        fast: bool = True,
        block: int = 1 << 20,
    ) -> None:
        global fast_blocks, fast_records
        if fast_records is None:
            from sharedlink.capture import fast_blocks, fast_records
        self.link = LinkState(default_list=list(variables))
        self.sync_ns = max(1, round(sync_interval * NS))
        self.fast_enabled = fast
        self.block = block
        self.stats = SideStats()
        self._fast: dict[bytes, fast_records.FastKey] = {}  # hot key (letters, addresses, ports) -> fast view
        self._sync: dict[tuple, list] = {}  # table key -> [time of the last full frame, else of the first frame]
        self._hot: dict[bytes, tuple] = {}  # hot key -> FastKey.hot
        self._splitter = FrameSplitter()
        self._serial = SerialSplitter()
        self._packets = PacketDecoder()  # IP fragments reassembled
        self._base = 0  # index of the first frame of the chunk being built
        self._keys: set[bytes] = set()  # every key emitted so far
        self._bulk_backoff = 1  # blocks to leave to the per-record loop before trying the block tier
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
        """Classic little-endian pcap: walk records in large blocks."""
        mult = 1 if struct.unpack("<I", head[:4])[0] == PCAP_MAGIC_NS else 1000
        linktype = pcap_header(p, head)[2]
        rest = b""
        number = 0
        while True:
            data = fh.read(self.block)
            buf = rest + data if rest else data
            if not buf:
                break
            start = 0
            if mult == 1 and fast_blocks.ready(self, linktype):
                done = fast_blocks.take(self, buf, mult, number)
                if done is not None:
                    start, number = done
            off, number = self._walk(buf, linktype, mult, number, p, start)
            rest = buf[off:]
            if self._recs:
                yield self._chunk()
            if not data or self._damage is not None:
                break
        yield from self._serial_flush()
        if self._damage is not None:
            raise self._damage
        if rest:
            if len(rest) < 16:
                raise CaptureError(p, number + 1, f"truncated record header ({len(rest)} of 16 bytes)")
            incl = struct.unpack_from("<I", rest, 8)[0]
            raise CaptureError(p, number + 1, f"truncated record ({len(rest) - 16} of {incl} bytes)")

    def _generic(self, p: str, records: Iterator[Record]) -> Iterator[Chunk]:
        """Any other capture (pcapng, big-endian pcap): records via pcapio, re-packed in
        batches as nanosecond pcap records so the same loops take them."""
        batch: list[bytes] = []
        size = 0
        linktype = None
        number = 0  # the last record number handed on
        pack = _REC.pack

        def flush() -> Iterator[Chunk]:
            nonlocal number, size
            buf = b"".join(batch)
            batch.clear()
            size = 0
            start = 0
            if fast_blocks.ready(self, linktype):
                done = fast_blocks.take(self, buf, 1, number)
                if done is not None:
                    start, number = done
            off, number = self._walk(buf, linktype, 1, number, p, start)
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
            size += n
        if batch:
            yield from flush()
        yield from self._serial_flush()

    def _serial_flush(self) -> Iterator[Chunk]:
        """The end of the capture (or the damage): the serial tails, then the last chunk."""
        self._serial_items(self._serial.flush())
        if self._recs:
            yield self._chunk()

    def _walk(self, buf: bytes, linktype: int, mult: int, number: int, p: str, start: int = 0) -> tuple[int, int]:
        """The per-record tiers: the fast one (:func:`sharedlink.capture.fast_records.walk`) when
        enabled, else the reference path; both have the same contract."""
        if self.fast_enabled:
            return fast_records.walk(self, buf, linktype, mult, number, p, start)
        return self._walk_plain(buf, linktype, mult, number, p, start)

    def _walk_plain(self, buf: bytes, linktype: int, mult: int, number: int, p: str, start: int = 0) -> tuple[int, int]:
        """The reference path: every complete record in ``buf`` through :meth:`_general`;
        return (offset of the rest, last record number). The fast tier
        (:func:`sharedlink.capture.fast_records.walk`) has the same contract."""
        unpack = _REC.unpack_from
        end = len(buf)
        off = start
        st = self.stats
        if st.start_ns is None and end >= 16:
            sec, frac = unpack(buf, 0)[:2]
            st.start_ns = sec * NS + frac * mult
        while off + 16 <= end:
            sec, frac, incl, _orig = unpack(buf, off)
            d = off + 16
            e = d + incl
            if e > end:
                if incl > 0x4000000:  # reported by _pcap once this block's frames are out
                    self._damage = CaptureError(p, number + 1, f"record length {incl} is implausible (damaged file)")
                break
            off = e
            number += 1
            st.records += 1
            st.wire_bytes += incl
            self._general(number, sec * NS + frac * mult, linktype, buf[d:e])
        return off, number

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
        # the conversation as the hot loop sees it (plain Ethernet/IPv4/UDP only)
        addr = (
            data[26:38]
            if linktype == LINKTYPE_ETHERNET and dg.proto == "udp" and data[12:15] == b"\x08\x00\x45" and data[23] == 17
            else None
        )
        for sf in self._splitter.split(number, ts, dg):
            if sf.frame is None:
                self.stats.undecodable += 1
            else:
                self._frame(number, ts, sf.frame, len(sf.raw), sf.conv, addr)

    def _serial_items(self, items: list[StreamFrame | tuple[int, int]]) -> None:
        for item in items:
            if isinstance(item, tuple):  # a record of another protocol (P2OS, blackboard)
                self.stats.other_packets += 1
            elif item.frame is None:
                self.stats.undecodable += 1
            else:
                self._frame(item.number, item.ts_ns, item.frame, len(item.raw), item.conv, None)

    def _frame(
        self, number: int, ts: int, frame: Frame, size: int, conv: tuple, addr: bytes | None
    ) -> None:
        """One frame through the general path: :class:`LinkState` keyed by the conversation
        (``conv``); ``addr`` is the packet's addresses and ports when the fast path can take
        this conversation's later frames (plain Ethernet/IPv4/UDP), else None."""
        st = self.stats
        st.payload_bytes += size
        key = (frame.dst + frame.src).encode("latin-1", "replace")
        rkey = (frame.src + frame.dst).encode("latin-1", "replace")
        raddr = addr[4:8] + addr[:4] + addr[10:12] + addr[8:10] if addr is not None else None
        hk = key + addr if addr is not None and len(key) == 2 else None
        rhk = rkey + raddr if raddr is not None and len(rkey) == 2 else None
        value_frame = frame_kind(frame.fields) in _VALUE_KINDS
        if frame.checksum is not None and frame.checksum.ok is False:
            st.checksum_failures += 1
            if value_frame:
                self._emit(ts, number, key)
            else:
                st.frames += 1
            return
        sync = self._sync.get((conv, key))
        if sync is None:
            sync = self._sync[(conv, key)] = [ts]
        for k in (hk, rhk):
            fk = self._fast.get(k) if k is not None else None
            if fk is not None:
                fk.flush()
        table = self.link.table(frame.src, frame.dst, conv)
        decl = declared_list(frame.fields)
        if decl is not None:  # a list may change under other conversations too (issue 29: by receiver
            for fk in self._fast.values():  # address, by letter pair): every fast view goes, as the core's do
                fk.flush()
            self._fast.clear()
            self._hot.clear()
        target = self.link.table(frame.dst, frame.src, reverse_conversation(conv)) if decl is not None and decl[0] == "L" else table
        # what this frame can give a first value or a new type: the names it holds (linear in
        # the frame, not in the direction's table)
        tvars = target.vars
        touched = _touched_names(frame, target)
        before = {n: (v.text is not None, v.type_code) for n in touched if (v := tvars.get(n)) is not None}
        kind = table.kind(frame)
        updates = self.link.apply(frame, number, ts, conv, carried=False)
        parts = [key]
        idx = self._base + len(self._recs)
        for u in updates if kind != "reply" else ():  # a reply's values are never stored (issue 29)
            if u.changed and not u.carried and u.text is not None:
                parts += (SEP_CHANGE, escape(u.name), SEP_VALUE, escape(u.text))
        for n in touched:
            v = tvars.get(n)
            if v is not None and v.text is not None and before.get(n) != (True, v.type_code):
                tkey = key if target is table else rkey
                self._events.append((idx, tkey, escape(n), v.type_code))
        if kind == "full":
            st.full += 1
            st.sync_missed += self._missed(ts - sync[0])
            sync[0] = ts
        if value_frame:
            self._emit(ts, number, b"".join(parts))
        else:
            st.frames += 1
        self._keys.add(key)
        for k, t in ((hk, table), (rhk, target)):
            fk = self._fast.get(k) if k is not None else None
            if fk is not None and len(t.vars) > fast_records.MAX_FAST_VARS:
                del self._fast[k]  # a layout this wide is no steady state: the general path takes it
                self._hot.pop(k, None)  # type: ignore[arg-type]
            elif fk is not None:
                fk.refresh()
            elif k == hk and k is not None and self.fast_enabled and len(t.vars) <= fast_records.MAX_FAST_VARS:
                self._fast[k] = fast_records.FastKey(key, k, t, sync, self._hot)
            if target is table:
                break

    def _emit(self, ts: int, number: int, rec: bytes) -> None:
        self._keys.add(rec[:2])
        self._ts.append(pack_ts(ts))
        self._num.append(number)
        self._recs.append(rec)

    def _chunk(self) -> Chunk:
        for fk in self._fast.values():
            fk.flush()
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
        keys = sorted({r[:2] for r in self._recs}) if len(self._keys) > 1 else sorted(self._keys)
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


_REC = struct.Struct("<IIII")


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
    is how many bytes of the file are read at a time."""
    r = ChangeReader(variables, sync_interval, fast, block)
    try:
        yield from r.chunks(path)
    except CaptureError as exc:
        r.stats.error = str(exc)
    except SharedLinkError as exc:  # pragma: no cover - the codec reports, never raises here
        r.stats.error = f"{path}: {exc}"
    yield r.finish()
