"""Blackboard message codec (Holland, *Designing Autonomous Mobile Robots*, figures 6.3 and 6.4).

Messages are ASCII hex, two characters per byte, ended by CR::

    :031F0001010203D7\\r     set data: count, base address (2, big-endian), destination node,
                             the data bytes, checksum
    ;05E000011A\\r           request data: count requested, base address, source node, checksum

The checksum is zero minus the 8-bit sum of the decoded bytes (type character and CR left
out), so the decoded bytes including the checksum add up to 0 modulo 256. Answers are binary:

- a set message is acknowledged with its checksum as one byte; with no answer the master
  repeats the message;
- a request is answered with the requested block followed by one checksum byte over the data
  and the request: zero minus the 8-bit sum of the data bytes and the request's count,
  address and node bytes (our reading: the request's own checksum byte is left out, it would
  cancel the request bytes out).

Parsing never raises anything but :class:`BlackboardError` (with the byte offset and reason).
Lower-case hex digits are accepted; we write upper case.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Union

from sharedlink.errors import DecodeError

SET = ord(":")
REQUEST = ord(";")
CR = 0x0D
HEXDIGITS = b"0123456789ABCDEFabcdef"
TYPE_NAMES = {SET: "set", REQUEST: "request"}


class BlackboardError(DecodeError):
    """Bytes that are not a blackboard message. ``offset`` is relative to the input."""


def checksum(data: bytes) -> int:
    """Zero minus the 8-bit sum of ``data``."""
    return -sum(data) & 0xFF


class _Checked:
    """What a set and a request share: the checksum of their body and whether the one received
    (``crc``) matches it (None: built, not received)."""

    crc: int | None

    @property
    def body(self) -> bytes:
        raise NotImplementedError

    @property
    def checksum(self) -> int:
        return checksum(self.body)

    @property
    def ok(self) -> bool | None:
        return None if self.crc is None else self.crc == self.checksum


@dataclass(frozen=True)
class SetMessage(_Checked):
    """``:`` set (write) ``data`` at ``address`` of node ``node``."""

    address: int
    node: int
    data: bytes
    crc: int | None = field(default=None, compare=False)  # checksum as received
    crlf: bool = field(default=False, compare=False)  # an LF followed the CR

    @property
    def body(self) -> bytes:
        return bytes((len(self.data), self.address >> 8 & 0xFF, self.address & 0xFF, self.node)) + self.data

    @property
    def ack(self) -> bytes:
        """The slave's one-byte acknowledgement."""
        return bytes((self.checksum,))

    def encode(self) -> bytes:
        return build_message(self)


@dataclass(frozen=True)
class RequestMessage(_Checked):
    """``;`` request ``count`` bytes from ``address``; ``node`` is the source computer."""

    address: int
    node: int
    count: int
    crc: int | None = field(default=None, compare=False)
    crlf: bool = field(default=False, compare=False)

    @property
    def body(self) -> bytes:
        return bytes((self.count, self.address >> 8 & 0xFF, self.address & 0xFF, self.node))

    def response(self, data: bytes) -> bytes:
        """The slave's binary answer: ``data`` (``count`` bytes) and its checksum."""
        if len(data) != self.count:
            raise BlackboardError(len(data), f"a response to this request carries {self.count} bytes, not {len(data)}")
        return bytes(data) + bytes((response_checksum(self, data),))

    def encode(self) -> bytes:
        return build_message(self)


Message = Union[SetMessage, RequestMessage]


def response_checksum(request: RequestMessage, data: bytes) -> int:
    return checksum(bytes(data) + request.body)


def build_message(msg: Message) -> bytes:
    """The message text, CR included."""
    if not 0 <= msg.address <= 0xFFFF or not 0 <= msg.node <= 0xFF:
        raise BlackboardError(0, "address must be 0..0xFFFF and node 0..255")
    if isinstance(msg, SetMessage):
        if len(msg.data) > 255:
            raise BlackboardError(1, "a set message carries at most 255 bytes")
        kind = b":"
    else:
        if not 0 <= msg.count <= 255:
            raise BlackboardError(1, "a request asks for 0..255 bytes")
        kind = b";"
    body = msg.body
    return kind + (body + bytes((checksum(body),))).hex().upper().encode() + b"\r"


def parse_message(data: bytes) -> Message:
    """One message: type character, hex, CR (an LF after the CR is tolerated, a missing CR is
    not). A bad checksum is reported through ``ok``; a non-hex character or a count that does
    not match the length raises :class:`BlackboardError`."""
    d = bytes(data)
    if not d:
        raise BlackboardError(0, "empty")
    kind = d[0]
    if kind not in (SET, REQUEST):
        raise BlackboardError(0, f"type character 0x{kind:02X} is neither ':' nor ';'")
    end = d.find(b"\r")
    if end < 0:
        raise BlackboardError(len(d), "no CR at the end")
    rest = d[end + 1 :]
    crlf = rest == b"\n"
    if rest and not crlf:
        raise BlackboardError(end + 1, f"{len(rest)} bytes after the CR")
    text = d[1:end]
    for i, c in enumerate(text):
        if c not in HEXDIGITS:
            raise BlackboardError(1 + i, f"non-hex character {chr(c)!r}")
    if len(text) % 2:
        raise BlackboardError(end, "odd number of hex digits")
    raw = bytes.fromhex(text.decode("ascii"))
    need = 5 if kind == REQUEST else None
    if len(raw) < 5:
        raise BlackboardError(end, f"{len(raw)} bytes decoded, a message has at least 5")
    count = raw[0]
    if kind == SET:
        need = 5 + count
    if len(raw) != need:
        raise BlackboardError(end, f"count {count} means {need} bytes, {len(raw)} decoded")
    address = raw[1] << 8 | raw[2]
    node = raw[3]
    if kind == SET:
        return SetMessage(address, node, raw[4:-1], raw[-1], crlf)
    return RequestMessage(address, node, count, raw[-1], crlf)


def message_start(buf: bytes, o: int, cr: int) -> int:
    """Where the message whose CR is at ``cr`` starts: the last ``:`` or ``;`` in ``buf[o:cr]``
    (``o`` holds one; the text before it is outside any message). The serial and session
    readers' rule, and dissector/robots/blackboard_rules.lua's ``B.message_start``
    (docs/fields-p2os-blackboard.md, "Noise")."""
    return max(buf.rfind(b":", o, cr), buf.rfind(b";", o, cr))


@dataclass(frozen=True)
class ReadResponse:
    """A binary response to a request."""

    data: bytes
    crc: int
    expected: int  # the checksum it should carry

    @property
    def ok(self) -> bool:
        return self.crc == self.expected


def parse_response(request: RequestMessage, data: bytes) -> ReadResponse:
    """The binary answer to ``request``: exactly ``count`` data bytes and the checksum."""
    d = bytes(data)
    if len(d) != request.count + 1:
        raise BlackboardError(min(len(d), request.count + 1), f"response of {len(d)} bytes, {request.count + 1} expected")
    return ReadResponse(d[:-1], d[-1], response_checksum(request, d[:-1]))


def ack_ok(message: SetMessage, data: bytes) -> bool:
    """Whether ``data`` is the right acknowledgement of ``message``."""
    return bytes(data) == message.ack
