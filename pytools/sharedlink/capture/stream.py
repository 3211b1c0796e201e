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

import re
import struct
import sys
import zlib
from array import array
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from itertools import chain, compress, repeat
from operator import add, and_, contains, ge, mul, ne, not_, sub
from pathlib import Path

from sharedlink.capture.packets import Datagram, decode_packet
from sharedlink.capture.pcapio import (
    LINKTYPE_ETHERNET,
    NS,
    PCAP_MAGIC_NS,
    PCAP_MAGIC_US,
    PCAPNG_SHB,
    CaptureError,
    read_records,
)
from sharedlink.capture.serial_format import DIRECTION_NAMES, USER_LINKTYPES, Piece, StreamReader
from sharedlink.protocols.codec import Frame, SharedLinkError, declared_list, frame_kind, iter_segments
from sharedlink.protocols.state import (
    BEACON_VARIABLES,
    LinkState,
    VariableTable,
    parse_variables,
    reverse_conversation,
)

#: Field separators of change records (ASCII unit/record separators); escaped in names/values.
SEP_CHANGE = b"\x1f"
SEP_VALUE = b"\x1e"
_ESC = b"\x1d"
_ESCAPES = ((b"\x1d", b"\x1d0"), (b"\x1e", b"\x1d1"), (b"\x1f", b"\x1d2"))


def escape(text: str) -> bytes:
    """A name or value as it appears in a change record (latin-1, separators escaped)."""
    b = text.encode("latin-1", "replace")
    if b"\x1d" in b or b"\x1e" in b or b"\x1f" in b:
        for raw, esc in _ESCAPES:
            b = b.replace(raw, esc)
    return b


def unescape(b: bytes) -> str:
    if _ESC in b:
        b = b.replace(b"\x1d2", b"\x1f").replace(b"\x1d1", b"\x1e").replace(b"\x1d0", b"\x1d")
    return b.decode("latin-1")


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


_TCP_BUFFER_MAX = 1 << 16
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
    try:
        for rec in read_records(path):
            if rec.linktype in USER_LINKTYPES:
                yield from serial.feed(rec.number, rec.ts_ns, rec.linktype, rec.data, rec.flags, rec.interface)
                continue
            dg = decode_packet(rec.linktype, rec.data)
            if dg is None:
                yield rec.number, rec.ts_ns
                continue
            yield from splitter.split(rec.number, rec.ts_ns, dg)
    except CaptureError:
        yield from serial.flush()
        raise
    yield from serial.flush()


# -- change records, fast ---------------------------------------------------------------------

#: a value as the fast path accepts it (the general path takes anything else)
_V = rb"[^|\x00-\x1f\[\]]"
#: Ethernet II, IPv4 without options, not fragmented, UDP: 42 bytes before the payload
_ETH_IP_UDP = rb"(?s).{12}\x08\x00\x45.{5}[\x00\x40]\x00.\x11.{18}"
#: the same with the pcap record header before it, for whole blocks of records of one
#: conversation (see ChangeReader._bulk): groups record header, IP total length, UDP length


def _bulk_head(addr: bytes) -> bytes:
    """The pattern of a record header and the packet headers of conversation ``addr`` (IPv4
    source and destination, UDP source and destination ports: 12 bytes)."""
    return rb"(?s)(.{16}).{12}\x08\x00\x45.(..)..[\x00\x40]\x00.\x11.." + re.escape(addr) + rb"(..).."
#: checksum digits -> what to subtract from (1 + byte sum of the whole payload) so that the
#: rest is the checksum's own sum: '[' (91), ']' CR LF (116), the two digits, the value
_CKADJ = {b"%02X" % i: 1 + 91 + 116 + (b"%02X" % i)[0] + (b"%02X" % i)[1] + i for i in range(256)}


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

    def as_tuple(self) -> tuple:
        return (self.start, self.ts, self.numbers, self.records, self.keys, self.events, self.snapshot)

    @classmethod
    def from_tuple(cls, t: Sequence) -> Chunk:
        return cls(*t)


class _FastKey:
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
            self.named = re.compile(_ETH_IP_UDP + head + body + tail).fullmatch
            self.bulk_named = re.compile(bulk_head + b"(" + head + body + tail + b")")
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
            self.pos = re.compile(_ETH_IP_UDP + head + body + tail).fullmatch
            self.bulk_pos = re.compile(bulk_head + b"(" + head + body + tail + b")")
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


class ChangeReader:
    """Reads one capture into :class:`Chunk` s of change records (see the module doc).

    ``variables`` is the a-priori outbound list positional frames are named by until a
    declaration says otherwise; ``sync_interval`` (seconds) is what "missed" full syncs are
    measured against: a gap between full frames of a direction that rounds to n >= 2
    intervals misses n - 1. ``fast=False`` sends every frame through the general path.
    """

    def __init__(
        self,
        variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
        sync_interval: float = 1.0,
        fast: bool = True,
        block: int = 1 << 20,
    ) -> None:
        self.link = LinkState(default_list=list(variables))
        self.sync_ns = max(1, round(sync_interval * NS))
        self.fast_enabled = fast
        self.block = block
        self.stats = SideStats()
        self._fast: dict[bytes, _FastKey] = {}  # hot key (letters, addresses, ports) -> fast view
        self._sync: dict[tuple, list] = {}  # table key -> [time of the last full frame, else of the first frame]
        self._hot: dict[bytes, tuple] = {}  # hot key -> _FastKey.hot
        self._splitter = FrameSplitter()
        self._serial = SerialSplitter()
        self._base = 0  # index of the first frame of the chunk being built
        self._keys: set[bytes] = set()  # every key emitted so far
        self._bulk_backoff = 1  # blocks to leave to the per-record loop before trying _bulk
        self._reset()
        self._last_ts = 0

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
        with fh:
            head = fh.read(24)
            magic = struct.unpack("<I", head[:4])[0] if len(head) >= 4 else None
            if magic in (PCAP_MAGIC_NS, PCAP_MAGIC_US) and len(head) == 24:
                yield from self._pcap(fh, p, head)
                return
        if magic == PCAPNG_SHB or magic is not None:
            yield from self._generic(p)
            return
        raise CaptureError(p, None, "file too short to be a capture" if head else "empty file")

    def _pcap(self, fh, p: str, head: bytes) -> Iterator[Chunk]:
        """Classic little-endian pcap: walk records in large blocks."""
        mult = 1 if struct.unpack("<I", head[:4])[0] == PCAP_MAGIC_NS else 1000
        linktype = struct.unpack("<I", head[20:24])[0] & 0x0FFFFFFF
        rest = b""
        number = 0
        while True:
            data = fh.read(self.block)
            buf = rest + data if rest else data
            if not buf:
                break
            start = 0
            if mult == 1 and self._bulk_ready(linktype):
                done = self._bulk(buf, mult, number)
                if done is not None:
                    start, number = done
            off, number = self._walk(buf, linktype, mult, number, p, start)
            rest = buf[off:]
            if self._recs:
                yield self._chunk()
            if not data:
                break
        yield from self._serial_flush()
        if rest:
            if len(rest) < 16:
                raise CaptureError(p, number + 1, f"truncated record header ({len(rest)} of 16 bytes)")
            incl = struct.unpack_from("<I", rest, 8)[0]
            raise CaptureError(p, number + 1, f"truncated record ({len(rest) - 16} of {incl} bytes)")

    def _generic(self, p: str) -> Iterator[Chunk]:
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
            if self._bulk_ready(linktype):
                done = self._bulk(buf, 1, number)
                if done is not None:
                    start, number = done
            off, number = self._walk(buf, linktype, 1, number, p, start)
            if self._recs:
                yield self._chunk()

        records = read_records(p)
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

    def _bulk_ready(self, linktype: int) -> bool:
        """Whole blocks at once: one direction so far, all its values known (no first-value
        events to report), and the last attempt did not fail."""
        if self._bulk_backoff:
            self._bulk_backoff -= 1
            return False
        if not self.fast_enabled or linktype != LINKTYPE_ETHERNET or len(self._fast) != 1:
            return False
        fk = next(iter(self._fast.values()))
        return None not in fk.cur

    def _bulk(self, buf: bytes, mult: int, number: int) -> tuple[int, int] | None:
        """Take a block where every record is one frame of the only direction in its current
        layout, all at once: one ``findall`` and C-level passes over its columns (no Python
        code per frame). Returns (bytes consumed, last record number), or None when the block
        does not qualify (then the per-record loop does it: the results are the same)."""
        fk = next(iter(self._fast.values()))
        positional = len(buf) > 66 and buf[66] == 68
        rx = fk.bulk_pos if positional else fk.bulk_named
        if rx is None:
            return None
        rows = rx.findall(buf)
        n = len(rows)
        if n < 64:
            self._bulk_backoff = 4
            return None
        cols = list(zip(*rows))
        hdrs, tls, uls, pays, cks = cols[0], cols[1], cols[2], cols[3], cols[-1]
        vals = cols[4:-1]
        sizes = list(map(len, pays))
        if max(sizes) > 256:  # the checksum shortcut below needs short frames
            return None
        total = 58 * n + sum(sizes)
        # the matches must tile the block from its start: then the last one ends at total
        m = rx.match(buf, total - 58 - sizes[-1])
        if m is None or m.end() != total:
            self._bulk_backoff = 4
            return None
        hdr = array("I")
        hdr.frombytes(b"".join(hdrs))
        lens = array("H")
        lens.frombytes(b"".join(tls))
        lens2 = array("H")
        lens2.frombytes(b"".join(uls))
        if sys.byteorder == "little":
            lens.byteswap()
            lens2.byteswap()
        else:  # pragma: no cover - big-endian hosts
            hdr.byteswap()
        incl = hdr[2::4]
        if (
            incl != array("I", map(add, sizes, repeat(42, n)))
            or lens != array("H", map(add, sizes, repeat(28, n)))
            or lens2 != array("H", map(add, sizes, repeat(8, n)))
        ):
            return None
        # checksums: adler32's low half is 1 + the byte sum for frames up to 256 bytes
        if any(map(and_, map(sub, map(zlib.adler32, pays), map(_CKADJ.__getitem__, cks)), repeat(255, n))):
            return None  # a bad checksum in the block: the per-record loop reports it
        secs, fracs = hdr[0::4], hdr[1::4]
        if max(fracs) >= NS:
            return None
        tsq = array("Q")
        tsq.frombytes(b"".join(hdrs))
        if sys.byteorder != "little":  # pragma: no cover - big-endian hosts
            tsq.byteswap()
        ts = tsq[0::2]  # the first 8 bytes of each record header: pack_ts for nanosecond pcaps
        # changes, column by column
        cur, pre = fk.cur, fk.pre
        slots = fk.pslots if positional else fk.nslots
        pieces = []
        dense = 0
        for col, k in zip(vals, slots):
            last = cur[k]
            if all(col):  # every frame carries it (a full stream)
                dense += 1
                changed = map(ne, col, chain((last,), col))
                pieces.append(list(map(mul, map(add, repeat(pre[k], n), col), changed)))
                cur[k] = col[-1]
            else:  # present in some frames (compressed): look at those only
                piece = [b""] * n
                p = pre[k]
                for i in compress(range(n), col):
                    v = col[i]
                    if v != last:
                        piece[i] = p + v
                        last = v
                cur[k] = last
                pieces.append(piece)
        key = fk.key
        records = list(map(b"".join, zip(repeat(key, n), *pieces)))
        # full frames: every value present (the block has no first values, so "every value
        # known" is "every value present"); findall gives b"" for an absent named triplet as
        # for an empty positional slot, and the other groups are never empty
        if dense == len(vals) and vals:
            fidx: Sequence[int] = range(n)
        elif vals:
            fidx = list(compress(range(n), map(not_, map(contains, rows, repeat(b"", n)))))
        else:
            fidx = []
        st = self.stats
        if fidx:
            sy = fk.sync
            limit = 2 * self.sync_ns - self.sync_ns // 2
            # only a gap of at least limit // NS whole seconds can reach the limit
            fsecs = [secs[i] for i in fidx] if not isinstance(fidx, range) else secs
            prev_sec = sy[0] // NS
            for j in compress(range(len(fidx)), map(ge, map(sub, fsecs, chain((prev_sec,), fsecs)), repeat(limit // NS))):
                i = fidx[j]
                t_ns = secs[i] * NS + fracs[i]
                p_ns = sy[0] if j == 0 else secs[fidx[j - 1]] * NS + fracs[fidx[j - 1]]
                if t_ns - p_ns >= limit:
                    st.sync_missed += self._missed(t_ns - p_ns)
            last = fidx[-1]
            sy[0] = secs[last] * NS + fracs[last]
        st.full += len(fidx)
        st.records += n
        st.wire_bytes += sum(incl)
        st.payload_bytes += total - 58 * n
        self._ts.extend(ts)
        self._num.extend(range(number + 1, number + n + 1))
        self._recs.extend(records)
        self._last_ts = secs[-1] * NS + fracs[-1]
        return total, number + n

    def _walk(self, buf: bytes, linktype: int, mult: int, number: int, p: str, start: int = 0) -> tuple[int, int]:
        """Process the complete records in ``buf``; return (offset of the rest, last number).

        The hot loop: everything it needs is in locals. One struct call reads the record
        header and, for an Ethernet/IPv4/UDP packet, the IP and UDP lengths, the frame's
        address letters and the letter after ``N0|``; one regular expression match checks
        the headers and the frame's layout and takes out its values."""
        unpack, unpack_x = _REC.unpack_from, _REC_X.unpack_from
        struct_error = struct.error
        hot = self._hot if (self.fast_enabled and linktype == LINKTYPE_ETHERNET) else {}
        hotget = hot.get
        swap = _SWAP16
        adler = zlib.adler32
        ckadj = _CKADJ
        ts_app, num_app, rec_app = self._ts.append, self._num.append, self._recs.append
        recs, events = self._recs, self._events
        join = b"".join
        general = self._general
        sync_ns = self.sync_ns
        half = sync_ns // 2
        limit = sync_ns + sync_ns - half  # a gap must round to 2 intervals to miss one
        end = len(buf)
        off = start
        if self.stats.start_ns is None and end >= 16:
            sec, frac = unpack(buf, 0)[:2]
            self.stats.start_ns = sec * NS + frac * mult
        nrec = wire = pbytes = nfull = missed = bad = 0
        base = self._base
        ts = self._last_ts
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
                if incl > 0x4000000:
                    raise CaptureError(p, number + 1, f"record length {incl} is implausible (damaged file)")
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
            st = self.stats
            st.payload_bytes += pbytes
            st.full += nfull
            st.sync_missed += missed
            st.checksum_failures += bad
            pbytes = nfull = missed = bad = 0
            general(number, ts, linktype, buf[d:e])
        st = self.stats
        st.records += nrec
        st.wire_bytes += wire
        st.payload_bytes += pbytes
        st.full += nfull
        st.sync_missed += missed
        st.checksum_failures += bad
        self._last_ts = ts
        return off, number

    # -- the general path ---------------------------------------------------------------

    def _general(self, number: int, ts: int, linktype: int, data: bytes, flags: int = 0, interface: int = 0) -> None:
        self._last_ts = ts
        if linktype in USER_LINKTYPES:  # serial: the same splitter as iter_frames
            self._serial_items(self._serial.feed(number, ts, linktype, data, flags, interface))
            return
        dg = decode_packet(linktype, data)
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
        target = self.link.table(frame.dst, frame.src, reverse_conversation(conv)) if decl is not None and decl[0] == "L" else table
        before = {n: (v.text is not None, v.type_code) for n, v in target.vars.items()}
        kind = table.kind(frame)
        updates = self.link.apply(frame, number, ts, conv)
        parts = [key]
        idx = self._base + len(self._recs)
        for u in updates:
            if u.changed and not u.carried and u.text is not None:
                parts += (SEP_CHANGE, escape(u.name), SEP_VALUE, escape(u.text))
        for n, v in target.vars.items():
            if v.text is not None and before.get(n) != (True, v.type_code):
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
            if fk is not None:
                fk.refresh()
            elif k == hk and k is not None and self.fast_enabled:
                self._fast[k] = _FastKey(key, k, t, sync, self._hot)
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
        )
        self.stats.frames += len(self._recs)
        self.stats.value_frames += len(self._recs)
        self._base += len(self._recs)
        self._reset()
        return c

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
#: the record header plus, at fixed offsets of an Ethernet/IPv4/UDP packet: IP total length,
#: IP addresses and UDP ports (12 bytes: the conversation), UDP length (both lengths read
#: little-endian: compared against _SWAP16), the frame's two address letters and the byte
#: after "[:AB|N0|"
_REC_X = struct.Struct("<IIII16xH8x12sH4x2s4xB")
_SWAP16 = [((x & 0xFF) << 8) | (x >> 8) for x in range(65536)]


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
