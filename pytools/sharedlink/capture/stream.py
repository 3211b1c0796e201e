"""Streaming over captures: records -> datagrams -> SharedLink frames -> value changes.

Both streaming (memory does not grow with the capture):

* :func:`iter_frames` — the general reader any command can use: every SharedLink frame of a
  capture with its record number, timestamp and conversation, TCP streams reassembled, serial
  captures (USER link types) deframed per direction with :mod:`serialcap`'s incremental
  deframer, noise reported. Built on :mod:`pcapio`, :mod:`packets`, :mod:`serialcap` and
  :mod:`codec`.
* the change records and chunks ``sharedlink diff`` reads (:class:`Chunk`, :class:`SideStats`,
  :func:`parse_record`, the timestamps' packing): its reader,
  :class:`sharedlink.analysis.changes.ChangeReader`, decodes through the decoding core.

Change records are bytes: the frame's destination and source letters, then for each changed
variable ``\\x1f`` name ``\\x1e`` value, in frame order (names and values escaped with
:func:`escape` so the separators cannot occur in them). Two captures carrying the same data
give equal records for equal frames, whatever form (named or positional, full or compressed)
carried them.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from sharedlink.capture.change_records import SEP_CHANGE as SEP_CHANGE
from sharedlink.capture.change_records import SEP_VALUE as SEP_VALUE
from sharedlink.capture.change_records import escape as escape
from sharedlink.capture.change_records import unescape as unescape
from sharedlink.capture.packets import Datagram, PacketDecoder
from sharedlink.capture.pcapio import NS, CaptureError, read_records
from sharedlink.capture.serial_format import DIRECTION_NAMES, GIVEN_UP, USER_LINKTYPES, Piece, StreamReader
from sharedlink.protocols.codec import Frame, iter_segments, unterminated_start
from sharedlink.protocols.limits import MAX_HELD_BYTES
from sharedlink.protocols.state import parse_variables


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


class FrameSplitter:
    """Cuts datagrams into frames; keeps a buffer per TCP conversation so frames split across
    segments are found (segments are taken in capture order; a retransmitted segment, one
    that starts before the data already seen, is skipped). An unterminated frame is held up to
    ``MAX_HELD_BYTES``; the segment that takes it past gives it out as noise with the reason
    :data:`~sharedlink.capture.serial_format.GIVEN_UP` (``stats`` counts it in ``limits.held``),
    where sharedlink.lua says "Limit exceeded: ... (max_held_bytes)"."""

    def __init__(self) -> None:
        self._tcp: dict[tuple[str, str, int, str, int], tuple[int, bytes]] = {}

    def split(self, number: int, ts_ns: int, dg: Datagram) -> list[StreamFrame]:
        conv = (dg.proto, dg.src, dg.sport, dg.dst, dg.dport)
        data = dg.payload
        if dg.proto == "tcp":
            nxt, buf = self._tcp.get(conv, (None, b""))
            if nxt is not None and data and ((dg.tcp_seq - nxt) & 0xFFFFFFFF) >= 0x80000000:
                return []  # retransmission of data already seen
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
                    start = unterminated_start(data, seg.start)
                    if start > seg.start:
                        out.append(StreamFrame(number, ts_ns, conv, data[seg.start : start], None, "noise between frames"))
                    if len(data) - start > _TCP_BUFFER_MAX:  # a '[' that never closes: given up as noise
                        out.append(StreamFrame(number, ts_ns, conv, data[start:], None, GIVEN_UP))
                    else:
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
        # interface -> {record number -> timestamp} for its records still held, pruned per interface
        # when it doubles (linear in the number of interfaces: issue 44)
        self._ts: dict[int, dict[int, int]] = {}
        self._prune_at: dict[int, int] = {}
        self._last = (0, 0)  # (number, ts_ns) of the last record fed

    def feed(
        self, number: int, ts_ns: int, linktype: int, data: bytes, flags: int = 0, interface: int = 0
    ) -> list[StreamFrame | tuple[int, int]]:
        reader = self._readers.get(interface)
        if reader is None:
            reader = self._readers[interface] = StreamReader("auto")
            self._ts[interface] = {}
        self._linktype[interface] = linktype
        self._last = (number, ts_ns)
        ts = self._ts[interface]
        ts[number] = ts_ns
        d = flags & 3
        out = self._convert(interface, d, reader.feed(d, data, number), number, ts_ns)
        if len(ts) >= self._prune_at.get(interface, 64):
            held = {r for df in reader.dirs.values() for r in df.pending_records}
            ts = self._ts[interface] = {r: t for r, t in ts.items() if r in held}
            self._prune_at[interface] = 2 * len(ts) + 64
        return out

    def flush(self) -> list[StreamFrame | tuple[int, int]]:
        """The pieces still held at the end of the capture (then the splitter is empty)."""
        out: list[StreamFrame | tuple[int, int]] = []
        for interface, reader in self._readers.items():
            for d, p in reader.flush():
                number = p.records[-1] if p.records else self._last[0]
                out += self._convert(interface, d, [p], number, self._ts[interface].get(number, self._last[1]))
        self._readers.clear()
        self._ts.clear()
        self._prune_at.clear()
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
                        out.append((r, self._ts[interface].get(r, ts_ns)))
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
