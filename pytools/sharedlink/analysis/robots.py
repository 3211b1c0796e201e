"""P2OS and blackboard links inside the decoding core's record walk (issue 42).

The core (:func:`sharedlink.analysis.decode._capture_items`) offers every UDP and TCP datagram,
and in messages mode every serial record, to :class:`RobotLinks` before its SharedLink
splitters see them. A conversation is a robot link as the dissectors decide it:

Never on SharedLink's port 7013 (its dissector's port comes first in Wireshark), nor on a
conversation SharedLink's heuristic took first (:meth:`RobotLinks.sharedlink`: sharedlink.lua
sets ``pinfo.conversation`` too, and a conversation's dissector comes before any heuristic).

* P2OS: TCP port 8101 (p2os.lua's port preference, either side), or a segment that starts
  with a whole P2OS packet with a good checksum (p2os.lua's heuristic: ``FA FB``, a count of 2
  to 255, the packet present);
* blackboard: a segment that starts with a whole valid message with a good checksum
  (blackboard.lua's heuristic ``valid_text_at``).

Once a conversation is claimed every later segment of it (both directions) is the protocol's,
as ``pinfo.conversation`` makes it in Wireshark: a SharedLink scan never runs over a P2OS or
blackboard payload (issue 44: a SIP whose position bytes spell ``[:`` stays a P2OS packet).

Each claimed segment comes out as one noise :class:`~sharedlink.capture.stream.StreamFrame`
whose ``error`` is the protocol's name (what a SharedLink-only caller saw before: a whole
segment that is not SharedLink); in messages mode (``RobotLinks(messages=True)``, set as the
decoder's ``robots`` attribute before :meth:`~sharedlink.analysis.decode.Decoder.capture`) the
segments are only counted (``segments``: protocol -> [segments, bytes]) and the
:class:`~sharedlink.analysis.sessions.SessionMessage` s they complete come out, decoded by
:class:`~sharedlink.analysis.sessions.SessionReader` (the one P2OS/blackboard decoder: reassembly,
several packets a segment, direction, blackboard answers). Serial records (messages mode) are
decoded beside the core's :class:`~sharedlink.capture.stream.SerialSplitter`, which still reports
them as other records.
"""

from __future__ import annotations

import re

from sharedlink.analysis.sessions import SessionMessage, SessionReader
from sharedlink.capture.packets import Datagram
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT, DIRECTION_NAMES
from sharedlink.capture.stream import StreamFrame
from sharedlink.defaults import WATCH_DEFAULT_PORT
from sharedlink.protocols import blackboard, p2os

#: the protocols a claimed segment's StreamFrame names in ``error``
ROBOT_PROTOCOLS = frozenset(("p2os", "blackboard"))
#: first bytes a heuristic may claim a conversation on (FA: P2OS; ':' and ';': blackboard)
FIRST_BYTES = frozenset(b"\xfa:;")
#: the longest blackboard message: type, 2 * (5 + 255) hex digits, CR
_MAX_TEXT = 1 + 2 * (5 + 255) + 1
_SERIAL_CLIENT = {DIR_OUT: True, DIR_IN: False}
#: SharedLink's UDP port (sharedlink.lua's registration)
SHAREDLINK_PORT = WATCH_DEFAULT_PORT

Item = "StreamFrame | SessionMessage"


def p2os_heuristic(p: bytes) -> bool:
    """p2os.lua's heuristic: a whole P2OS packet with a good checksum at the start of ``p``."""
    if len(p) < 5 or p[0] != 0xFA or p[1] != 0xFB:
        return False
    count = p[2]
    if count < 2 or 3 + count > len(p):
        return False
    return p2os.checksum(p[3 : 1 + count]) == int.from_bytes(p[1 + count : 3 + count], "big")


def blackboard_heuristic(p: bytes) -> bool:
    """blackboard.lua's ``valid_text_at(0)``: a whole message with a good checksum at the start."""
    if p[:1] not in (b":", b";"):
        return False
    cr = p.find(b"\r", 1, _MAX_TEXT)
    if cr < 0:
        return False
    try:
        msg = blackboard.parse_message(p[: cr + 1])
    except blackboard.BlackboardError:
        return False
    return msg.ok is True


#: what sharedlink.lua's heuristic refuses before "]": control bytes other than TAB, LF, CR
_NOT_TEXT = re.compile(rb"[^\t\n\r\x20-\x7e]")
_HEAD = re.compile(rb"[\r\n]{0,2}\[:[A-P][A-P][|\]]")


def sharedlink_heuristic(p: bytes, tcp: bool) -> bool:
    """sharedlink.lua's heuristic (``looks_like_sharedlink``): up to two CR/LF, ``[:``, two
    letters A-P and ``|`` or ``]``; printable text (TAB, LF, CR too) up to the first ``]``
    after it, which the end, ``[``, LF or CR LF (a CR alone at the end) follows. TCP: also a
    frame not finished yet (no ``]``, no control byte, 8 bytes at least)."""
    n = len(p)
    m = _HEAD.match(p, 0, 8)
    if n < 5 or m is None:
        return False
    o = m.end() - 5  # (where "[:" is)
    close = p.find(b"]", o + 4)
    bad = _NOT_TEXT.search(p, o)
    if close < 0:
        return tcp and bad is None and n >= 8
    if bad is not None and bad.start() < close:
        return False
    after = p[close + 1 : close + 3]
    return after[:1] in (b"", b"[", b"\n") or after == b"\r\n" or (after == b"\r" and close + 2 == n)


def claim(proto: str, sport: int, dport: int, payload: bytes) -> str | None:
    """The robot protocol a conversation's segment makes it, or None. SharedLink's port is
    SharedLink's (sharedlink.lua's port registration comes before any heuristic)."""
    if proto == "tcp" and p2os.MOBILESIM_PORT in (sport, dport):
        return "p2os"
    if not payload or payload[0] not in FIRST_BYTES or SHAREDLINK_PORT in (sport, dport):
        return None
    if p2os_heuristic(payload):
        return "p2os"
    if blackboard_heuristic(payload):
        return "blackboard"
    return None


class RobotLinks:
    """The core's hook (see the module doc). ``claimed``: conversation (both directions alike)
    -> protocol."""

    def __init__(self, messages: bool = False) -> None:
        self.messages = messages
        self.reader = SessionReader()
        self.claimed: dict[tuple, str] = {}
        self.segments: dict[str, list[int]] = {}  # messages mode: protocol -> [segments, bytes]

    def sharedlink(self, conv: tuple, payload: bytes) -> None:
        """A datagram the core decodes as SharedLink: its conversation is SharedLink's from now on
        when it is off SharedLink's port and sharedlink.lua's heuristic would take it (no robot
        protocol claimed it before)."""
        proto, src, sport, dst, dport = conv
        if SHAREDLINK_PORT in (sport, dport) or not sharedlink_heuristic(payload, proto == "tcp"):
            return
        a, b = (src, sport), (dst, dport)
        self.claimed.setdefault((proto, a, b) if a <= b else (proto, b, a), "sharedlink")

    def udp(self, number: int, ts_ns: int, conv: tuple, payload: bytes) -> list | None:
        """A UDP datagram of the core's fast record loop: its items, or None (not a robot link)."""
        return self._segment(number, ts_ns, conv, payload, 0, 0)

    def datagram(self, number: int, ts_ns: int, dg: Datagram) -> list | None:
        """A UDP/TCP datagram of the general path: its items, or None (not a robot link)."""
        conv = (dg.proto, dg.src, dg.sport, dg.dst, dg.dport)
        return self._segment(number, ts_ns, conv, dg.payload, dg.tcp_seq, dg.tcp_flags)

    def _segment(self, number: int, ts_ns: int, conv: tuple, payload: bytes, seq: int, flags: int) -> list | None:
        proto, src, sport, dst, dport = conv
        a, b = (src, sport), (dst, dport)
        key = (proto, a, b) if a <= b else (proto, b, a)
        which = self.claimed.get(key)
        if which == "sharedlink":
            return None
        if which is None:
            which = claim(proto, sport, dport, payload)
            if which is None:
                return None
            self.claimed[key] = which
            lo, hi = key[1], key[2]
            self.reader.claim(key, f"{proto} {lo[0]}:{lo[1]} - {hi[0]}:{hi[1]}", which)
        reader = self.reader
        if proto == "tcp" and not reader.tcp_new(key, a, seq, flags, len(payload)):
            return []  # a retransmission: data the stream has had
        if not payload:
            return []
        if not self.messages:
            return [StreamFrame(number, ts_ns, conv, payload, None, which)]
        seg = self.segments.get(which)
        if seg is None:
            seg = self.segments[which] = [0, 0]
        seg[0] += 1
        seg[1] += len(payload)
        client = True if dport == p2os.MOBILESIM_PORT else False if sport == p2os.MOBILESIM_PORT else None
        return reader.feed(key, reader.sessions[key].label, a, number, ts_ns, payload, client, proto == "udp")

    def finish(self) -> list[SessionMessage]:
        """The capture's end (messages mode): blackboard text a TCP stream still holds, as a
        malformed message (:meth:`~sharedlink.analysis.sessions.SessionReader.finish`)."""
        return self.reader.finish() if self.messages else []

    def serial(self, number: int, ts_ns: int, data: bytes, flags: int, interface: int) -> list[SessionMessage]:
        """A serial record (messages mode): the P2OS packets and blackboard messages it completes.
        A direction found to carry SharedLink is no longer fed."""
        key = ("serial", interface)
        d = flags & 3
        side = DIRECTION_NAMES.get(d, "unknown")
        s = self.reader.sessions.get(key)
        if s is not None:
            deframer = s.sides.get(side)
            if deframer is not None and deframer.protocol == "sharedlink":
                return []
        return self.reader.feed(key, f"serial interface {interface}", side, number, ts_ns, data, _SERIAL_CLIENT.get(d))
