"""P2OS and blackboard messages of a capture, per session and side, in capture order.

:func:`iter_sessions` is the counterpart of :func:`sharedlink.analysis.decode.iter_decoded`
for the two binary-ish protocols: it reads UDP, TCP and serial (USER link type) records, keeps
one byte stream per side of each session (a TCP or UDP endpoint pair; a serial interface) and
gives out every message as a :class:`SessionMessage` when the record that completes it is read.

* A side's protocol is found by :class:`~sharedlink.capture.serial_format.Deframer` ("auto": the
  first good P2OS packet or blackboard message); SharedLink sides are left to ``iter_decoded``.
  A UDP or TCP session has one protocol (the first found, as a Wireshark conversation); on a
  serial line each direction has its own, as serial.lua has it (docs/serial-capture-format.md,
  "Protocol per direction": P2OS one way and blackboard the other is two protocols of one
  session; a direction with nothing of its own takes another's once it holds 64 bytes).
* P2OS, as the dissector decides: the side on TCP port 8101 is the robot; on serial, outbound
  bytes are the client's and inbound the robot's; else the side that sent a server packet (SIP,
  CONFIG, ENCODER, a SYNC2 echo with the robot's name) is the robot, and until one is seen each
  packet's direction is guessed from its payload (:func:`~sharedlink.protocols.p2os.guess_from_client`).
* Blackboard, per direction as ``blackboard.lua`` has it (docs/fields-p2os-blackboard.md,
  "Both directions"): either side may send ``:``/``;`` messages (the master of that exchange,
  "master" in :attr:`SessionMessage.side`); a good message makes the other side's next bytes its
  binary answer ("slave"), cut by the length the message implies (one checksum byte for a set,
  ``count`` + 1 for a request). A new message from the same side drops a pending one that was
  never answered (the master repeats after a timeout). Bytes with nothing pending go to the
  side's own deframer: messages, or noise (not reported); text from a type character that does
  not read as a good message is a malformed message (``message`` None, ``error`` why: "Malformed
  messages" in docs/fields-p2os-blackboard.md).
* Over UDP each datagram is read alone, P2OS as p2os.lua does and blackboard as blackboard.lua
  does (a packet, message or answer cut off at a datagram's end is noise, the next datagram
  starts afresh: docs/fields-p2os-blackboard.md, "Over UDP").
* TCP segments are taken in capture order; data the stream has already had (a retransmission)
  is skipped, as in :class:`~sharedlink.capture.stream.FrameSplitter`. Blackboard text a TCP
  stream still holds at the capture's end (no CR) is a malformed message of the last segment
  that brought its bytes (:meth:`SessionReader.finish`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Union

from sharedlink.capture.packets import decode_packet
from sharedlink.capture.pcapio import Record, read_records
from sharedlink.capture.serial_format import (
    DIR_IN,
    DIR_OUT,
    DIRECTION_NAMES,
    USER_LINKTYPES,
    Deframer,
    Piece,
    detect,
)
from sharedlink.protocols import blackboard, p2os

#: serial direction -> whether it is a P2OS client's (the dissector's p2p_dir rule)
_SERIAL_CLIENT = {DIR_OUT: True, DIR_IN: False}

#: what a session message carries
Payload = Union[p2os.Message, blackboard.Message, blackboard.ReadResponse, "Ack", None]


@dataclass(frozen=True)
class Ack:
    """A blackboard slave's one-byte acknowledgement of a set message."""

    crc: int
    expected: int

    @property
    def ok(self) -> bool:
        return self.crc == self.expected


@dataclass(slots=True)  # (not frozen: a frozen dataclass's __init__ costs about 1 us more a message)
class SessionMessage:
    """One P2OS packet or blackboard message (or slave answer) of a session."""

    number: int  # record that completed it
    ts_ns: int
    session: int  # 1, 2, ... in the order the sessions' first messages appear
    label: str  # "tcp 127.0.0.1:45678 - 127.0.0.1:8101", "serial interface 0"
    protocol: str  # "p2os" or "blackboard"
    side: str  # p2os: "client" / "robot"; blackboard: "master" / "slave"
    raw: bytes
    ok: bool | None  # checksum verdict (None: none to check)
    message: Payload  # the decoded message; None when a P2OS payload does not decode
    error: str = ""  # why the payload did not decode
    request: blackboard.Message | None = None  # blackboard answers: the message answered


@dataclass
class _Session:
    index: int
    label: str
    sides: dict[object, Deframer] = field(default_factory=dict)
    protocol: str | None = None
    robot: object = None  # p2os: the side that sent a server packet
    pending: dict[object, blackboard.Message] = field(default_factory=dict)  # blackboard: sender -> awaiting an answer
    answer: dict[object, bytes] = field(default_factory=dict)  # blackboard: answering side -> answer bytes so far
    tcp_next: dict[object, int] = field(default_factory=dict)
    serial: bool = False  # a serial line: each direction has its own protocol
    held_at: dict[object, tuple[int, int]] = field(default_factory=dict)  # TCP blackboard: side -> last record, ts
    answer_from: dict[object, int] = field(default_factory=dict)  # serial: side -> stream offset its answer starts at


#: the order serial.lua looks at another direction for its protocol (p2p_dir -1, 0, 1)
_SIDE_ORDER = {"unknown": 0, DIRECTION_NAMES[DIR_OUT]: 1, DIRECTION_NAMES[DIR_IN]: 2}


def _side_order(kv: tuple[object, Deframer]) -> int:
    return _SIDE_ORDER.get(kv[0], 3)  # type: ignore[call-overload]


def _whole_packets(data: bytes) -> list[int]:
    """The end offsets of the P2OS packets ``data`` is made of, or [] when it is not whole packets
    only (bytes between them, a bad count, a truncated last packet) or when the deframer may
    read it otherwise: a packet with an FA after its first byte and a bad checksum (an FA FB
    inside its span, or on its last byte with the FB in the next bytes, may resynchronise:
    :func:`~sharedlink.protocols.p2os.resync_at`)."""
    n = len(data)
    i = 0
    ends = []
    while i < n:
        if i + 5 > n or data[i] != 0xFA or data[i + 1] != 0xFB or data[i + 2] < 2:
            return []
        end = i + 3 + data[i + 2]
        if end <= n and data.find(b"\xfa", i + 1, end) >= 0 and p2os.checksum(data[i + 3 : end - 2]) != (
            data[end - 2] << 8 | data[end - 1]
        ):
            return []
        i = end
        ends.append(i)
    return ends if i == n else []


def _starts_message(s: _Session, side: object, data: bytes) -> bool:
    """Whether ``data``, with no answer bytes of ``side`` held, starts with a complete good
    blackboard message: a message, not the awaited answer (blackboard.lua's rule: the side
    talks instead of answering)."""
    return not s.answer.get(side) and _good_message_first(data)


def _good_message_first(data: bytes) -> bool:
    """Whether ``data`` starts with a complete good blackboard message."""
    if data[:1] not in (b":", b";"):
        return False
    cr = data.find(b"\r")
    if cr < 0:
        return False
    try:
        return bool(blackboard.parse_message(data[: cr + 1]).ok)
    except blackboard.BlackboardError:
        return False


def _good_message_at(buf: bytes, need: int) -> int:
    """Where a complete good blackboard message starts among the first ``need`` bytes of ``buf``
    (the answer's place), or -1."""
    for i in range(min(need, len(buf))):
        if buf[i] in b":;" and _good_message_first(buf[i:]):
            return i
    return -1


_HEX = frozenset(b"0123456789ABCDEFabcdef")


def _may_be_text(buf: bytes, need: int) -> bool:
    """serial.lua's wait: whether answer bytes ``buf`` end with text that may still become a
    message (a ``:`` or ``;`` inside the answer's ``need`` bytes and hex digits after it to the
    end, no CR yet)."""
    i = len(buf)
    while i > 0 and buf[i - 1] in _HEX:
        i -= 1
    return i > 0 and buf[i - 1] in b":;" and i - 1 < need


def _serial_detect(s: _Session, side: object, d: Deframer, data: bytes) -> tuple[bytes, bool, bytes]:
    """A serial direction of no protocol yet, a blackboard answer awaited from it: its protocol,
    as serial.lua finds it: the first good frame of its bytes (a P2OS packet is no answer; a
    message where the answer would be is that message: its frames first), else blackboard when
    its bytes (those held too) start with the right answer; else none yet (the bytes are held).
    Returns the bytes to read on (the held ones first once they are an answer), whether they
    may be read as the answer, and the held bytes from before the message answered."""
    both = bytes(d.buf) + data
    d.protocol = detect(both)
    if d.protocol is not None:
        return data, False, b""
    req = next((m for k, m in s.pending.items() if k != side), None)
    at = min(max(s.answer_from.get(side, 0) - d.base, 0), len(d.buf))  # (bytes held before the message: no answer)
    if req is not None and _answer_right(req, both[at:]):
        d.protocol = "blackboard"
        held = d.take()
        return held[at:] + data, True, held[:at]
    return data, False, b""


def _held_text_goes_on(joined: bytes) -> bool:
    """Whether text a serial direction holds (no CR yet) goes on in the bytes after it: a whole
    good message, or still a type character and hex digits (serial.lua: text wins, and waits)."""
    return _good_message_first(joined) or (joined[:1] in (b":", b";") and all(b in _HEX for b in joined[1:]))


def _answer_right(req: blackboard.Message, data: bytes) -> bool:
    """Whether ``data`` starts with the whole right answer to ``req`` (the set's checksum; a read
    response with a good checksum)."""
    if isinstance(req, blackboard.SetMessage):
        return data[:1] == bytes([req.checksum])
    need = req.count + 1
    return len(data) >= need and blackboard.parse_response(req, data[:need]).ok  # type: ignore[arg-type]


def malformed_split(data: bytes, at_end: bool) -> list[tuple[bytes, bool]]:
    """Blackboard bytes outside any good message, as ``blackboard.lua`` reads them with no answer
    awaited: (bytes, whether a message): a message from a type character (the last one before
    its CR) through its CR and an LF right after it, or, ``at_end`` (no message follows the
    bytes), to the end when no CR follows; the rest junk (text with no CR before a good message
    is cut short by it)."""
    out: list[tuple[bytes, bool]] = []
    n, pos = len(data), 0
    while pos < n:
        if data[pos] in b":;":
            cr = data.find(b"\r", pos + 1)
            if cr >= 0:
                start = blackboard.message_start(data, pos, cr)
                if start > pos:
                    out.append((data[pos:start], False))
                    pos = start
                    continue
                end = cr + 2 if data[cr + 1 : cr + 2] == b"\n" else cr + 1
            elif at_end:
                end = n
            else:
                out.append((data[pos:], False))
                break
            out.append((data[pos:end], True))
            pos = end
            continue
        nxt = [i for i in (data.find(b":", pos + 1), data.find(b";", pos + 1)) if i >= 0]
        end = min(nxt) if nxt else n
        out.append((data[pos:end], False))
        pos = end
    return out


def _text_checksum(raw: bytes) -> bool | None:
    """A malformed message's checksum verdict as ``blackboard.lua`` gives it: when its text up to
    the CR is at least 5 bytes of hex (a wrong count, no CR), whether they sum to 0 (mod 256);
    else None (no verdict)."""
    text = raw[1:].split(b"\r", 1)[0]
    if len(text) < 10 or len(text) % 2:
        return None
    try:
        return sum(bytes.fromhex(text.decode("latin-1"))) % 256 == 0
    except ValueError:
        return None


class SessionReader:
    """Byte streams in, :class:`SessionMessage` s out (see the module doc)."""

    def __init__(self) -> None:
        self.sessions: dict[object, _Session] = {}
        self.numbered = 0
        self.noise: dict[str, list[int]] = {}  # protocol -> [pieces, bytes] outside any packet (serial)

    def _session(self, key: object, label: str) -> _Session:
        s = self.sessions.get(key)
        if s is None:
            s = self.sessions[key] = _Session(0, label, serial=isinstance(key, tuple) and key[:1] == ("serial",))
        return s

    @staticmethod
    def _deframer(s: _Session) -> Deframer:
        """A new side's deframer: the session's protocol once it has one; on a serial line each
        direction finds its own (docs/serial-capture-format.md, "Protocol per direction"), one
        with nothing recognisable of its own taking another direction's once it holds
        ``ADOPT_AFTER`` bytes, as serial.lua does."""
        if s.serial:
            return Deframer("auto", lambda: next((o.protocol for _k, o in sorted(s.sides.items(), key=_side_order)
                                                  if o.protocol), None))
        return Deframer(s.protocol if s.protocol in ("p2os", "blackboard") else "auto")

    def claim(self, key: object, label: str, protocol: str) -> None:
        """Decide ``key``'s protocol before its first message (the core's robot links: a port or
        a heuristic said so); its sides' deframers then look for that protocol only."""
        s = self._session(key, label)
        if s.protocol is None:
            s.protocol = protocol
            self.numbered += 1
            s.index = self.numbered

    def feed(
        self, key: object, label: str, side: object, number: int, ts_ns: int, data: bytes, client: bool | None = None,
        datagram: bool = False,
    ) -> list[SessionMessage]:
        """The messages ``data`` completes. ``client``: whether ``side`` is a P2OS client (None: unknown).
        ``datagram``: ``data`` is a whole UDP datagram, read alone (a P2OS packet, a blackboard
        message or answer cut off at its end is noise, never joined with the next datagram's bytes)."""
        s = self._session(key, label)
        d = s.sides.get(side)
        if d is None:
            d = s.sides[side] = self._deframer(s)
        out, data = self._answers_first(s, side, d, number, ts_ns, data, datagram)
        if not data:
            return out
        if d.protocol == "p2os" and not d.buf and data[:2] == p2os.HEADER:
            ends = _whole_packets(data)
            if ends:  # whole packets and nothing else, nothing held: what the deframer gives, without it
                d.base += len(data)
                a = 0
                for e in ends:
                    payload = data[a + 3 : e - 2]
                    pkt = p2os.Packet(payload, data[e - 2] << 8 | data[e - 1], p2os.checksum(payload))
                    out.append(self._p2os(s, side, client, number, ts_ns, data[a:e], pkt))
                    a = e
                return out
        pieces = d.feed(data, number)
        if datagram and d.protocol in ("p2os", "blackboard"):
            pieces += d.flush()  # a datagram is all there is (docs/fields-p2os-blackboard.md, "Over UDP")
        elif d.buf and d.protocol == "blackboard" and not s.serial:
            s.held_at[side] = (number, ts_ns)  # (text waiting for its CR: finish)
        last = len(pieces) - 1
        for i, piece in enumerate(pieces):
            if piece.frame is None and piece.protocol == "blackboard" and (s.serial or s.protocol == "blackboard"):
                out += self._bb_rest(s, side, number, ts_ns, piece, datagram, i == last and not d.buf)
                continue
            if piece.frame is None or piece.protocol not in ("p2os", "blackboard"):
                if piece.protocol in ("p2os", "blackboard"):
                    n = self.noise.setdefault(piece.protocol, [0, 0])
                    n[0] += 1
                    n[1] += len(piece.data)
                continue
            if s.protocol is None:
                s.protocol = piece.protocol
                self.numbered += 1
                s.index = self.numbered
            if piece.protocol == "p2os":
                out.append(self._p2os(s, side, client, number, ts_ns, piece.data, piece.frame))  # type: ignore[arg-type]
            else:
                out.append(self._bb_message(s, side, number, ts_ns, piece.data, piece.frame))  # type: ignore[arg-type]
        return out

    def _answers_first(
        self, s: _Session, side: object, d: Deframer, number: int, ts_ns: int, data: bytes, datagram: bool
    ) -> tuple[list[SessionMessage], bytes]:
        """The answers ``data`` starts with when ``side`` owes one (a blackboard side, not
        starting with a message of its own; on a serial line a direction of no protocol yet
        first as serial.lua finds its protocol), and the bytes left for its deframer."""
        answers, before = True, b""
        if s.serial and d.protocol is None and s.pending:
            data, answers, before = _serial_detect(s, side, d, data)
        if answers and (d.protocol if s.serial else d.protocol or s.protocol) == "blackboard" and any(
                k != side for k in s.pending) and not _starts_message(s, side, data):
            if s.serial and d.buf:
                if _held_text_goes_on(bytes(d.buf) + data):
                    return [], data
                before = d.take()
            d.protocol = "blackboard"  # (a side that answers a blackboard message is blackboard's)
            out, data = self._answer(s, side, number, ts_ns, data, datagram)
            if before:  # what it held before the answer never ends: given up (serial.lua)
                out = self._bb_noise(s, number, ts_ns, before, True) + out
            return out, data
        return [], data

    def _bb_rest(
        self, s: _Session, side: object, number: int, ts_ns: int, piece: Piece, datagram: bool, at_end: bool
    ) -> list[SessionMessage]:
        """Blackboard bytes the deframer found no message in: the answer the side owes, if it owes
        one (it may talk first, then answer: blackboard.lua), then malformed messages and noise.
        On a serial line bytes the side held before the message it answers are no answer
        (serial.lua's framing)."""
        out: list[SessionMessage] = []
        data = piece.data
        if any(k != side for k in s.pending):
            cut = min(max(s.answer_from.get(side, 0) - piece.start, 0), len(data)) if s.serial else 0
            if cut:
                out += self._bb_noise(s, number, ts_ns, data[:cut], False)
            got, data = self._answer(s, side, number, ts_ns, data[cut:], datagram, waits=False)
            out += got
        if data:
            out += self._bb_noise(s, number, ts_ns, data, at_end)
        return out

    def _bb_message(self, s: _Session, side: object, number: int, ts_ns: int, raw: bytes,
                    msg: blackboard.Message) -> SessionMessage:
        """A master's message. A good one waits for its answer (replacing the side's last one);
        what the side owes stays owed; one with a bad checksum waits for none (blackboard.lua:
        "the last good message")."""
        if msg.ok:
            s.pending[side] = msg
            s.answer = {k: v for k, v in s.answer.items() if k == side}  # the other side answers afresh
            if s.serial:  # (serial.lua: the answer starts after what the other side holds now)
                s.answer_from = {k: o.base + len(o.buf) for k, o in s.sides.items() if k != side}
        return SessionMessage(number, ts_ns, s.index, s.label, "blackboard", "master", raw, msg.ok, msg)

    def finish(self) -> list[SessionMessage]:
        """The end of the capture: blackboard text a TCP stream still holds, its CR never come, is
        a malformed message (no CR) of the last segment that brought its bytes, as
        ``blackboard.lua`` shows it on a later pass (docs/fields-p2os-blackboard.md, "Malformed
        messages"). A serial line's held bytes stay held, as in ``serial.lua``."""
        out: list[SessionMessage] = []
        for s in self.sessions.values():
            for side, d in s.sides.items():
                at = s.held_at.get(side)
                if s.serial or at is None or not d.buf or d.protocol != "blackboard":
                    continue
                for piece in d.flush():
                    out += self._bb_noise(s, at[0], at[1], piece.data, True)
        return out

    def _bb_noise(self, s: _Session, number: int, ts_ns: int, data: bytes, at_end: bool) -> list[SessionMessage]:
        """Blackboard bytes no good message holds: their malformed messages (masters' messages
        of no kind: ``message`` None, ``error`` why; they wait for no answer), the rest noise
        (docs/fields-p2os-blackboard.md, "Malformed messages"). ``at_end``: nothing follows."""
        out = []
        junk = 0
        for raw, is_msg in malformed_split(data, at_end):
            if not is_msg:
                junk += len(raw)
                continue
            try:
                blackboard.parse_message(raw)
                error = "malformed"
            except blackboard.BlackboardError as exc:
                error = exc.reason
            out.append(SessionMessage(number, ts_ns, s.index, s.label, "blackboard", "master", raw,
                                      _text_checksum(raw), None, error))
        if junk:
            n = self.noise.setdefault("blackboard", [0, 0])
            n[0] += 1
            n[1] += junk
        return out

    def _p2os(
        self, s: _Session, side: object, client: bool | None, number: int, ts_ns: int, raw: bytes, pkt: p2os.Packet
    ) -> SessionMessage:
        if s.robot is None and not p2os.guess_from_client(pkt.payload):
            s.robot = side
        if client is not None:
            from_client = client
        else:
            from_client = p2os.guess_from_client(pkt.payload) if s.robot is None else side != s.robot
        msg: Payload = None
        error = ""
        try:
            msg = p2os.decode_payload(pkt.payload, from_client)
        except p2os.P2osError as exc:
            error = exc.reason
        return SessionMessage(number, ts_ns, s.index, s.label, "p2os", "client" if from_client else "robot", raw,
                              pkt.ok, msg, error)

    def _answer(
        self, s: _Session, side: object, number: int, ts_ns: int, data: bytes, datagram: bool = False,
        waits: bool = True,
    ) -> tuple[list[SessionMessage], bytes]:
        """The answers ``side``'s bytes give to the other side's pending message, and the bytes
        left over once nothing is pending (for ``side``'s own deframer). ``datagram``: an answer
        cut off at the datagram's end is the answer, truncated (blackboard.lua's
        ``blackboard.response.truncated``): noise here, the message answered, nothing held. On a
        serial line (``waits``: bytes the deframer has not called noise yet) a whole good message
        where the answer would be is that message, and answer bytes that may still become one
        wait for more, as serial.lua reads them."""
        out: list[SessionMessage] = []
        buf = s.answer.pop(side, b"") + data
        sender = next((k for k in s.pending if k != side), None)
        while sender is not None and buf:
            req = s.pending[sender]
            need = 1 if isinstance(req, blackboard.SetMessage) else req.count + 1
            if s.serial and waits and not datagram:  # (serial.lua: text wins, text that may become a message waits)
                at = _good_message_at(buf, need)
                if at >= 0:  # (the bytes before it are outside any message)
                    return out + self._bb_noise(s, number, ts_ns, buf[:at], False), buf[at:]
                if _may_be_text(buf, need) and not _answer_right(req, buf):
                    s.answer[side] = buf
                    return out, b""
            if len(buf) < need:
                if datagram:
                    del s.pending[sender]
                    n = self.noise.setdefault("blackboard", [0, 0])
                    n[0] += 1
                    n[1] += len(buf)
                else:
                    s.answer[side] = buf
                return out, b""
            chunk, buf = buf[:need], buf[need:]
            if isinstance(req, blackboard.SetMessage):
                ans: Payload = Ack(chunk[0], req.checksum)
            else:
                ans = blackboard.parse_response(req, chunk)
            del s.pending[sender]
            sender = None
            out.append(SessionMessage(number, ts_ns, s.index, s.label, "blackboard", "slave", chunk,
                                      ans.ok, ans, request=req))  # type: ignore[union-attr]
        return out, buf

    def tcp_new(self, key: object, side: object, seq: int, flags: int, length: int) -> bool:
        """Whether a TCP segment brings data the stream has not had (False: a retransmission)."""
        s = self.sessions[key]
        nxt = s.tcp_next.get(side)
        if nxt is not None and length and ((seq - nxt) & 0xFFFFFFFF) >= 0x80000000:
            return False
        if length or flags & 0x03:
            s.tcp_next[side] = (seq + length + (1 if flags & 0x03 else 0)) & 0xFFFFFFFF
        return True


def iter_sessions(path: str | Path) -> Iterator[SessionMessage]:
    """Every P2OS packet and blackboard message (and slave answer) of a capture, in order.
    Raises :class:`~sharedlink.capture.pcapio.CaptureError` on damage, after what came before."""
    reader = SessionReader()
    for rec in read_records(path):
        yield from record_sessions(reader, rec)
    yield from reader.finish()


def record_sessions(reader: SessionReader, rec: Record) -> Iterator[SessionMessage]:
    """What one capture record adds to :func:`iter_sessions` (``reader`` keeps the state between
    records): for a caller reading the records once for other things too (``watch -``)."""
    if rec.linktype in USER_LINKTYPES:
        key: object = ("serial", rec.interface)
        d = rec.flags & 3
        yield from reader.feed(key, f"serial interface {rec.interface}", DIRECTION_NAMES.get(d, "unknown"),
                               rec.number, rec.ts_ns, rec.data, _SERIAL_CLIENT.get(d))
        return
    dg = decode_packet(rec.linktype, rec.data)
    if dg is None:
        return
    a, b = (dg.src, dg.sport), (dg.dst, dg.dport)
    key = (dg.proto, *sorted((a, b)))
    lo, hi = key[1], key[2]  # type: ignore[index]
    label = f"{dg.proto} {lo[0]}:{lo[1]} - {hi[0]}:{hi[1]}"
    reader._session(key, label)
    if dg.proto == "tcp" and not reader.tcp_new(key, a, dg.tcp_seq, dg.tcp_flags, len(dg.payload)):
        return
    if dg.payload:
        client = True if dg.dport == p2os.MOBILESIM_PORT else False if dg.sport == p2os.MOBILESIM_PORT else None
        yield from reader.feed(key, label, a, rec.number, rec.ts_ns, dg.payload, client, dg.proto == "udp")
