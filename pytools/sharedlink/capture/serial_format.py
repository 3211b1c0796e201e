"""Serial links in pcapng: the capture format, its writer, and reading it back as frames.

The capture format (``docs/serial-capture-format.md``): pcapng, one interface with a USER link
type (default LINKTYPE_USER0, 147), one Enhanced Packet Block per chunk of bytes as it was read
from the line, nanosecond timestamps, and the direction in the EPB flags (bits 0-1: 1 inbound,
2 outbound, 0 unknown).

Reading a serial stream back into frames is incremental: :class:`Deframer` takes the bytes of
one direction chunk by chunk (``feed``) and returns the pieces (frames and the noise between
them) that are complete, holding back only an unfinished frame; :meth:`Deframer.flush` ends
the stream. The SharedLink deframer is built on :func:`sharedlink.protocols.codec.iter_segments`, the
P2OS one on :func:`sharedlink.protocols.p2os.iter_chunks`, the blackboard one on
:func:`sharedlink.protocols.blackboard.parse_message`. The Wireshark dispatcher ``dissector/serial.lua``
follows the same rules, so both find the same frames in a capture whatever the chunking.

Live capture of a port is in :mod:`sharedlink.capture.serial_port`.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, Callable, Union

from sharedlink.capture.pcapio import LINKTYPE_USER0, PcapngWriter, Record, read_records
from sharedlink.protocols import blackboard, p2os
from sharedlink.protocols.codec import Frame, iter_segments
from sharedlink.protocols.limits import MAX_HELD_BYTES

#: EPB flags direction values (pcapng spec, epb_flags bits 0-1)
DIR_UNKNOWN, DIR_IN, DIR_OUT = 0, 1, 2
DIRECTION_NAMES = {DIR_UNKNOWN: "unknown", DIR_IN: "inbound", DIR_OUT: "outbound"}
#: LINKTYPE_USER0 .. LINKTYPE_USER15
USER_LINKTYPES = range(LINKTYPE_USER0, LINKTYPE_USER0 + 16)
PROTOCOLS = ("sharedlink", "p2os", "blackboard")
#: an unfinished frame longer than this is given up as noise (bounds memory on garbage): the
#: issue-31 limit ``MAX_HELD_BYTES`` (``slserial.max_held_bytes`` in the dissector); old name
MAX_PENDING = MAX_HELD_BYTES
#: a direction whose protocol is not recognised yet holds at most this many bytes
MAX_UNDETECTED = 4096
UNDETECTED_KEEP = 512
#: an undecided direction holding this many bytes takes the other direction's protocol
ADOPT_AFTER = 64
#: the reason of the noise piece that ends an unfinished frame given up at MAX_HELD_BYTES
GIVEN_UP = f"an unfinished frame of over {MAX_HELD_BYTES} bytes given up (limit max_held_bytes)"
#: per protocol, the bytes that may end or restart the one unfinished frame a direction holds:
#: a record with none of them only lengthens it (appended, nothing scanned again)
_FINISHERS: dict[str, tuple[bytes, ...]] = {"sharedlink": (b"[", b"]"), "blackboard": (b"\r",)}
#: (bytes a held frame starts with, the byte that ends it) of those protocols
_HELD_FRAME: dict[str, tuple[bytes, bytes]] = {"sharedlink": (b"[", b"]"), "blackboard": (b":;", b"\r")}

Decoded = Union[Frame, p2os.Packet, blackboard.SetMessage, blackboard.RequestMessage]


def parse_linktype(text: str | int) -> int:
    """``147``, ``user0`` .. ``user15`` -> the link type number; ValueError otherwise."""
    t = str(text).strip().lower()
    if t.startswith("user") and t[4:].isdigit():
        n = LINKTYPE_USER0 + int(t[4:])
    else:
        try:
            n = int(t, 0)
        except ValueError:
            raise ValueError(f"link type {text!r} is not a number or user0..user15") from None
    if n not in USER_LINKTYPES:
        raise ValueError(f"link type {text!r} is not a USER link type (147..162, user0..user15)")
    return n


def direction_of(flags: int) -> int:
    return flags & 3


# -- pieces and deframers --------------------------------------------------------------------


@dataclass(frozen=True)
class Piece:
    """A frame or noise of one direction's byte stream. ``start``/``end`` are stream offsets
    (bytes of that direction since the capture began); ``frame`` is the decoded frame, None for
    noise (with ``reason``)."""

    start: int
    data: bytes
    frame: Decoded | None = None
    reason: str = ""
    protocol: str = ""
    records: tuple[int, ...] = field(default=(), compare=False)  # record numbers it came from

    @property
    def end(self) -> int:
        return self.start + len(self.data)

    @property
    def is_frame(self) -> bool:
        return self.frame is not None

    @property
    def good(self) -> bool:
        """A frame with a correct checksum (what protocol detection trusts)."""
        f = self.frame
        if isinstance(f, Frame):
            return f.checksum is not None and f.checksum.ok is True
        if isinstance(f, p2os.Packet):
            return bool(f.ok) and not f.ignored(p2os.guess_from_client(f.payload))  # 200: client commands only
        if f is not None:
            return f.ok is True
        return False


#: a scanner: (buffer, final) -> (pieces as (offset, length, frame|None, reason), hold offset)
Scan = Callable[[bytes, bool], "tuple[list[tuple[int, int, Decoded | None, str]], int]"]


def scan_sharedlink(buf: bytes, final: bool) -> tuple[list[tuple[int, int, Decoded | None, str]], int]:
    """SharedLink pieces of ``buf`` and where the unfinished tail starts (``len(buf)`` when
    nothing is held). Built on :func:`codec.iter_segments`: a frame that might still grow (no
    ``]`` yet, or ``]`` with its CR LF not yet seen) is held from its last ``[``."""
    segs = list(iter_segments(buf, restart_at_bracket=True))  # (serial.lua: any '[' restarts a frame)
    n = len(buf)
    hold = n
    if not final and segs:
        last = segs[-1]
        if not last.is_frame:
            tail = buf[last.start :]
            k = tail.rfind(b"[")
            if k >= 0 and tail.find(b"]", k) < 0:
                hold = last.start + k  # the last '[' with no ']' after it may start a frame
        # a frame at the very end without its CR LF: the CR LF may be in the next chunk
        frames = [s for s in segs if s.is_frame]
        if frames:
            f = frames[-1]
            after = buf[f.end : hold]
            if f.frame is not None and not f.frame.crlf and after in (b"", b"\r") and f.end + len(after) == n:
                hold = f.start
    over = n - hold > MAX_HELD_BYTES
    if over:
        hold = n
    out: list[tuple[int, int, Decoded | None, str]] = []
    for s in segs:
        if s.start >= hold:
            break
        end = min(s.end, hold)
        out.append((s.start, end - s.start, s.frame, "" if s.is_frame else (s.error.reason if s.error else "noise")))
    if over and out:
        o, ln, _f, _r = out[-1]
        out[-1] = (o, ln, None, GIVEN_UP)
    return out, hold


def scan_p2os(buf: bytes, final: bool) -> tuple[list[tuple[int, int, Decoded | None, str]], int]:
    """P2OS pieces (:func:`p2os.iter_chunks`); a truncated last packet, or a last byte FA that
    may start a header, is held."""
    out: list[tuple[int, int, Decoded | None, str]] = []
    n = len(buf)
    hold = n
    for c in p2os.iter_chunks(buf, final):
        if not final and c.packet is None and c.reason.startswith("truncated") and n - c.offset <= MAX_HELD_BYTES:
            hold = c.offset
            break
        out.append((c.offset, len(c.data), c.packet, c.reason))
    if not final and hold == n and out and buf[-1] == 0xFA:
        o, ln, f, r = out[-1]
        if f is None and o + ln == n:  # a last byte FA in noise may start a header
            hold = n - 1
            out[-1] = (o, ln - 1, f, r)
            if ln == 1:
                out.pop()
    return out, hold


def scan_blackboard(buf: bytes, final: bool) -> tuple[list[tuple[int, int, Decoded | None, str]], int]:
    """Blackboard messages: ``:`` or ``;`` through CR (and an LF right after it, when it came
    with the CR). A message starts at the last ``:``/``;`` before the CR; text that does not
    parse is noise."""
    out: list[tuple[int, int, Decoded | None, str]] = []
    n = len(buf)
    pos = noise = 0
    hold = n
    given_up = False
    while pos < n:
        o = _find_start(buf, pos)
        if o < 0:
            break
        cr = buf.find(b"\r", o + 1)
        if cr < 0:
            if not final and n - o <= MAX_HELD_BYTES:
                hold = o
            elif not final:
                given_up = True
            break
        o2 = blackboard.message_start(buf, o, cr)
        end = cr + 1  # a message ends at its CR: an LF still to come would be noise
        if end < n and buf[end] == 0x0A:
            end += 1
        try:
            msg = blackboard.parse_message(buf[o2:end])
        except blackboard.BlackboardError:
            pos = cr + 1
            continue
        if o2 > noise:
            out.append((noise, o2 - noise, None, "noise between messages"))
        out.append((o2, end - o2, msg, ""))
        noise = pos = end
    if noise < hold:
        out.append((noise, hold - noise, None, GIVEN_UP if given_up else "noise between messages"))
    return out, hold


def _find_start(buf: bytes, pos: int) -> int:
    a, b = buf.find(b":", pos), buf.find(b";", pos)
    if a < 0:
        return b
    return a if b < 0 else min(a, b)


SCANNERS: dict[str, Scan] = {"sharedlink": scan_sharedlink, "p2os": scan_p2os, "blackboard": scan_blackboard}


def detect(buf: bytes) -> str | None:
    """The protocol whose first good frame (correct checksum) starts earliest in ``buf``."""
    best: tuple[int, str] | None = None
    for name, scan in SCANNERS.items():
        pieces, _ = scan(buf, False)
        for off, _ln, frame, _r in pieces:
            if frame is not None and Piece(off, b"", frame).good:
                if best is None or off < best[0]:
                    best = (off, name)
                break
    return best[1] if best else None


class Deframer:
    """Incremental deframing of one direction: ``feed(chunk)`` returns the pieces completed so
    far, holding an unfinished frame back; ``flush()`` returns the rest at the end.

    ``protocol`` is "sharedlink", "p2os", "blackboard" or "auto" (the first protocol with a
    good frame in the bytes seen; until then the bytes are held, at most
    :data:`MAX_UNDETECTED` of them).

    Bounded and linear (issue 31): an unfinished frame is held up to :data:`MAX_HELD_BYTES`
    (``limits.MAX_HELD_BYTES``, the dissector's ``slserial.max_held_bytes``); past it the
    held bytes are given out as one noise piece (reason :data:`GIVEN_UP`), counted in
    ``given_up`` / ``given_up_bytes``, and nothing more is held for them. A chunk that only
    lengthens the held frame (no ``[`` or ``]`` for SharedLink, no CR for blackboard) is
    appended without scanning the held bytes again, as ``dissector/serial.lua`` does, so a
    frame sent byte by byte costs linear time.
    """

    def __init__(self, protocol: str = "sharedlink", fallback: Callable[[], str | None] | None = None) -> None:
        if protocol != "auto" and protocol not in SCANNERS:
            raise ValueError(f"unknown protocol {protocol!r} (auto, {', '.join(PROTOCOLS)})")
        self.protocol: str | None = None if protocol == "auto" else protocol
        self._fallback = fallback
        self.buf = bytearray()
        self.base = 0  # stream offset of buf[0]
        self._recs: list[tuple[int, int, int]] = []  # (record number, start, end) of buffered bytes
        self._finish: tuple[bytes, ...] = ()  # set: buf is one unfinished frame these bytes may end
        self.given_up = 0  # unfinished frames given up at MAX_HELD_BYTES
        self.given_up_bytes = 0  # the bytes of those frames (given out as noise)

    @property
    def pending(self) -> bytes:
        return bytes(self.buf)

    @property
    def pending_records(self) -> list[int]:
        """Record numbers of the bytes held back (oldest first)."""
        return [r for r, _s, _e in self._recs]

    def feed(self, chunk: bytes, record: int = 0) -> list[Piece]:
        if not chunk:
            return self._run(False) if self.buf and not self._finish else []
        end = self.base + len(self.buf) + len(chunk)
        self._recs.append((record, end - len(chunk), end))
        self.buf += chunk
        fin = self._finish
        if fin and len(self.buf) <= MAX_HELD_BYTES and not any(b in chunk for b in fin):
            return []  # it only lengthens the held frame: the scan would find what it found
        return self._run(False)

    def flush(self) -> list[Piece]:
        return self._run(True)

    def take(self) -> bytes:
        """The held bytes, taken out (the caller reads them otherwise: a blackboard answer)."""
        held = bytes(self.buf)
        self.base += len(held)
        self.buf, self._recs, self._finish = bytearray(), [], ()
        return held

    def _run(self, final: bool) -> list[Piece]:
        if not self.buf:
            return []
        buf = bytes(self.buf)
        if self.protocol is None:
            self.protocol = detect(buf)
            if self.protocol is None and self._fallback is not None and len(buf) >= ADOPT_AFTER:
                self.protocol = self._fallback()
            if self.protocol is None:
                if final or len(buf) > MAX_UNDETECTED:
                    cut = len(buf) if final else len(buf) - UNDETECTED_KEEP
                    return self._emit(buf, [(0, cut, None, "protocol not recognised")], cut)
                return []
        pieces, hold = SCANNERS[self.protocol](buf, final)
        return self._emit(buf, pieces, hold)

    def _emit(self, buf: bytes, pieces: Sequence[tuple[int, int, Decoded | None, str]], hold: int) -> list[Piece]:
        base, proto = self.base, self.protocol or ""
        out = []
        recs = self._recs
        i = 0
        for off, ln, frame, reason in pieces:
            if ln <= 0:
                continue
            s, e = base + off, base + off + ln
            while i < len(recs) and recs[i][2] <= s:  # pieces come in order: records before s are done
                i += 1
            numbers = []
            j = i
            while j < len(recs) and recs[j][1] < e:
                numbers.append(recs[j][0])
                j += 1
            if reason == GIVEN_UP:
                self.given_up += 1
                self.given_up_bytes += ln
            out.append(Piece(s, buf[off : off + ln], frame, reason, proto, tuple(numbers)))
        self.base = base + hold
        self.buf = bytearray(buf[hold:])
        k = 0
        while k < len(recs) and recs[k][2] <= self.base:
            k += 1
        self._recs = recs[k:]
        # the fast append holds when the held bytes are one frame's start and no end of it yet
        opens, ends = _HELD_FRAME.get(proto, (b"", b""))
        held = self.buf
        self._finish = _FINISHERS[proto] if held and opens and held[0] in opens and ends not in held else ()
        return out


class StreamReader:
    """Both directions of a serial capture: ``feed(direction, chunk)`` -> completed pieces.
    A direction with no recognisable frame of its own (protocol "auto"; e.g. the binary
    answers of a blackboard slave) takes the protocol of another direction once it holds
    :data:`ADOPT_AFTER` bytes."""

    def __init__(self, protocol: str = "auto") -> None:
        self.protocol = protocol
        self.dirs: dict[int, Deframer] = {}

    def deframer(self, direction: int) -> Deframer:
        d = self.dirs.get(direction)
        if d is None:
            d = self.dirs[direction] = Deframer(self.protocol, self._other_protocol)
        return d

    def _other_protocol(self) -> str | None:
        order = {DIR_UNKNOWN: 0, DIR_OUT: 1, DIR_IN: 2}  # as the dissector looks (p2p_dir -1, 0, 1)
        return next((o.protocol for _d, o in sorted(self.dirs.items(), key=lambda kv: order.get(kv[0], 3)) if o.protocol), None)

    def feed(self, direction: int, chunk: bytes, record: int = 0) -> list[Piece]:
        return self.deframer(direction).feed(chunk, record)

    @property
    def given_up(self) -> int:
        """Unfinished frames given up at MAX_HELD_BYTES, every direction's."""
        return sum(d.given_up for d in self.dirs.values())

    def flush(self) -> list[tuple[int, Piece]]:
        out: list[tuple[int, Piece]] = []
        for d in sorted(self.dirs):
            out += [(d, p) for p in self.deframer(d).flush()]
        return out


def read_pieces(
    records: Iterable[Record], protocol: str = "auto"
) -> Iterator[tuple[Record | None, int, Piece]]:
    """(record where the piece completed, direction, piece) for a serial capture's records,
    in order; the pieces left at the end come last with record None."""
    reader = StreamReader(protocol)
    for rec in records:
        d = direction_of(rec.flags)
        for p in reader.feed(d, rec.data, rec.number):
            yield rec, d, p
    for d, p in reader.flush():
        yield None, d, p


def read_capture(path: str | Path, protocol: str = "auto") -> Iterator[tuple[Record | None, int, Piece]]:
    """:func:`read_pieces` over a capture file (raises pcapio.CaptureError on damage, after
    yielding what came before it)."""
    return read_pieces(read_records(path), protocol)


# -- writing --------------------------------------------------------------------------------


class SerialCaptureWriter:
    """A serial capture being written: pcapng, one USER link type interface, one record per
    chunk with its direction; every record is flushed to the file as it is written."""

    def __init__(
        self,
        out: BinaryIO,
        linktype: int = LINKTYPE_USER0,
        if_name: str | None = None,
        if_description: str | None = None,
        comment: str | None = None,
        flush: bool = True,
    ) -> None:
        if linktype not in USER_LINKTYPES:
            raise ValueError(f"link type {linktype} is not a USER link type (147..162)")
        self.fh = out
        self.linktype = linktype
        self._w = PcapngWriter(out, linktype, 262144, if_name, if_description, comment)
        self._flush = flush
        self.records = 0
        self.bytes = 0
        self.last_ts = 0
        if flush:
            out.flush()

    def write(self, data: bytes, direction: int = DIR_IN, ts_ns: int | None = None) -> None:
        if not data:
            return
        if ts_ns is None:
            ts_ns = time.time_ns()
        self._w.write(ts_ns, bytes(data), direction & 3)
        self.records += 1
        self.bytes += len(data)
        self.last_ts = ts_ns
        if self._flush:
            self.fh.flush()
