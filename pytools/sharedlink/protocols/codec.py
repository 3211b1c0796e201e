"""SharedLink frame codec: parse and build frames, compute and check checksums.

One module, used by every tool in the package. Protocol facts are in ``docs/protocol.md``.

A frame on the wire::

    [:AB|N0|T2|QAutoGpsLat|D38.34698779|...|CF8]\\r\\n

``parse_frame`` accepts what real peers send (lower-case or one-digit checksums, no CR LF,
empty fields, unknown field letters) and reports each deviation instead of failing. Input that
is not a frame at all raises :class:`SharedLinkError`, which carries the byte offset and the
reason. No other exception escapes the parsing functions, whatever the input.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

from sharedlink.errors import DecodeError
from sharedlink.protocols.limits import MAX_NUMBER_DIGITS, MAX_SLOTS

OPEN = ord("[")
CLOSE = ord("]")
SEP = b"|"
CRLF = b"\r\n"

#: Field letters the protocol defines, with their meaning.
FIELD_LETTERS: dict[str, str] = {
    "N": "start ordinal (outbound list)",
    "L": "start ordinal (inbound list)",
    "T": "type",
    "Q": "query / variable name",
    "R": "reply",
    "D": "data",
    "C": "checksum",
    "E": "command",
    "M": "mode",
    "P": "ping",
    "G": "pong",
}

#: Value type codes carried in ``T`` fields.
TYPE_LONG = 0
TYPE_DOUBLE = 2
TYPE_STRING = 4
TYPE_NAMES = {TYPE_LONG: "long", TYPE_DOUBLE: "double", TYPE_STRING: "string"}

ADDRESS_LETTERS = "ABCDEFGHIJKLMNOP"

#: Frame kinds: the one vocabulary of :func:`frame_kind`, the tools' reports and the dissector
#: (``docs/fields-sharedlink.md``, "Decoding rules"). ``other``: a well-formed frame whose
#: fields give it no other kind; ``malformed``: ``[:`` with a bad header or no ``]`` (noise to
#: the codec, a frame kind in reports).
KINDS = ("full", "delta", "query", "reply", "declaration", "command", "ping", "pong", "other", "malformed")

class SharedLinkError(DecodeError):
    """A byte sequence that is not a SharedLink frame. ``offset`` is relative to the input."""


@dataclass(frozen=True)
class Field:
    """One ``|``-separated field: its letter and the text after it (``letter`` is "" for an
    empty field)."""

    letter: str
    text: str = ""

    def encode(self) -> str:
        return self.letter + self.text


#: a checksum text the dissector reads: 1 to 8 hex digits (util.lua's checksum_value)
_CHECKSUM_TEXT = re.compile(r"[0-9A-Fa-f]{1,8}").fullmatch


@dataclass(frozen=True)
class Checksum:
    """What the checksum field said and what the bytes add up to."""

    text: str | None  # as written, None when the frame has no C field
    calculated: int  # the sum we computed (mod 256)

    @property
    def value(self) -> int | None:
        """The text's value: 1 to 8 hex digits, either case (as sharedlink.lua reads it: "00A5"
        is A5, no sign, space or "0x"); None otherwise."""
        t = self.text
        if t is None or not _CHECKSUM_TEXT(t):
            return None
        return int(t, 16)

    @property
    def ok(self) -> bool | None:
        """True good, False bad, None unverified (no checksum field)."""
        if self.text is None:
            return None
        return self.value == self.calculated


@dataclass(frozen=True)
class Frame:
    """A SharedLink frame. Equality compares what the frame says (addresses, fields, CR LF),
    not the checksum report or deviations that came with a parsed frame."""

    dst: str
    src: str
    fields: tuple[Field, ...] = ()
    crlf: bool = True
    checksum: Checksum | None = field(default=None, compare=False)
    deviations: tuple[str, ...] = field(default=(), compare=False)

    # -- addressing -------------------------------------------------------------------
    @property
    def dst_node(self) -> int | None:
        return address_node(self.dst)

    @property
    def src_node(self) -> int | None:
        return address_node(self.src)

    @property
    def kind(self) -> str:
        return frame_kind(self.fields)

    def encode(self) -> bytes:
        return build_frame(self)


def address_node(letter: str) -> int | None:
    """``A``..``P`` -> 1..16, anything else None."""
    i = ADDRESS_LETTERS.find(letter) if len(letter) == 1 else -1
    return i + 1 if i >= 0 else None


def checksum(data: bytes) -> int:
    """The SharedLink checksum of ``data``: the byte sum modulo 256. ``data`` runs from the
    header ``:`` through the ``C`` of the checksum field inclusive."""
    return sum(data) & 0xFF


def build_frame(frame: Frame, checksum_text: str | None = None) -> bytes:
    """Encode ``frame`` with a correct checksum (or ``checksum_text`` verbatim, for faults)."""
    body = ":" + frame.dst + frame.src
    for f in frame.fields:
        body += "|" + f.letter + f.text
    body += "|C"
    raw = body.encode("latin-1")
    if checksum_text is None:
        checksum_text = "%02X" % checksum(raw)
    out = b"[" + raw + checksum_text.encode("latin-1") + b"]"
    return out + CRLF if frame.crlf else out


def build_fields(frame_fields: Sequence[Field], dst: str = "A", src: str = "B", crlf: bool = True) -> bytes:
    return build_frame(Frame(dst, src, tuple(frame_fields), crlf))


def parse_frame(data: bytes) -> Frame:
    """Parse exactly one frame: ``[`` ... ``]`` with an optional CR LF after it.

    Raises :class:`SharedLinkError` (offset, reason) when ``data`` is not a frame.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise SharedLinkError(0, "input is not bytes")
    data = bytes(data)
    if not data:
        raise SharedLinkError(0, "empty input")
    if data[0] != OPEN:
        raise SharedLinkError(0, "frame does not start with '['")
    end = data.find(b"]", 1)
    if end < 0:
        raise SharedLinkError(len(data), "unterminated frame: no ']'")
    rest = data[end + 1 :]
    deviations: list[str] = []
    if rest == CRLF:
        crlf = True
    elif rest == b"":
        crlf = False
        deviations.append("no CR LF after ']'")
    else:
        raise SharedLinkError(end + 1, "bytes after ']' other than CR LF")
    return _parse_inner(data, 1, end, crlf, deviations)


def _parse_inner(data: bytes, start: int, end: int, crlf: bool, deviations: list[str]) -> Frame:
    """Parse ``data[start:end]``, the bytes between ``[`` and ``]``."""
    inner = data[start:end]
    if len(inner) < 3 or inner[0] != 0x3A:  # ':'
        raise SharedLinkError(start, "no ':' header after '['")
    try:
        text = inner.decode("latin-1")
    except Exception as exc:  # pragma: no cover - latin-1 decodes any bytes
        raise SharedLinkError(start, "undecodable bytes") from exc
    dst, src = text[1], text[2]
    if dst == "]" or src == "]":  # (a '|' is a letter, as sharedlink.lua reads the two bytes after ':')
        raise SharedLinkError(start + 1, "header too short: need destination and source letters")
    if address_node(dst) is None:
        deviations.append(f"destination {dst!r} is not a node letter A-P")
    if address_node(src) is None:
        deviations.append(f"source {src!r} is not a node letter A-P")
    after = text[3:]
    if after and after[0] != "|":
        raise SharedLinkError(start + 3, "header not followed by '|'")
    parts = after[1:].split("|") if after else []
    fields: list[Field] = []
    ck_text: str | None = None
    ck_end = None  # offset in inner just past the checksum 'C'
    for i, p in enumerate(parts):
        if i == len(parts) - 1 and p[:1] == "C":
            ck_text = p[1:]
            ck_end = len(inner) - len(ck_text)
            break
        if p == "":
            deviations.append(f"empty field at position {i + 1}")
            fields.append(Field("", ""))
        else:
            if p[0] not in FIELD_LETTERS or p[0] == "C":
                deviations.append(f"unknown field letter {p[0]!r}")
            fields.append(Field(p[0], p[1:]))
    if ck_text is None:
        deviations.append("no checksum field")
        calc = checksum(inner)
    else:
        calc = checksum(inner[:ck_end])
        if not (len(ck_text) == 2 and all(c in "0123456789ABCDEF" for c in ck_text)):
            deviations.append(f"checksum {ck_text!r} is not two upper-case hex digits")
    ck = Checksum(ck_text, calc)
    if ck.ok is False:
        deviations.append(f"checksum mismatch: frame says {ck_text!r}, bytes give {calc:02X}")
    return Frame(dst, src, tuple(fields), crlf, ck, tuple(deviations))


@dataclass(frozen=True)
class Segment:
    """A piece of a byte stream: a frame, or noise that is not one."""

    start: int
    end: int
    frame: Frame | None = None
    error: SharedLinkError | None = None

    @property
    def is_frame(self) -> bool:
        return self.frame is not None


def split_frames(data: bytes) -> list[Segment]:
    """Split a datagram or a buffer into frames and noise. Never raises."""
    return list(iter_segments(data))


def _frame_between(data: bytes, o: int, c: int) -> tuple[int, Frame]:
    """The frame of ``data[o:c + 1]`` (its ``[`` at ``o``, its ``]`` at ``c``) and where it ends:
    past the CR LF right after ``]``, when there is one. Raises :class:`SharedLinkError` when
    those bytes are no frame (both scanners of :func:`iter_segments` read frames this way)."""
    end = c + 1
    crlf = data[end : end + 2] == CRLF
    if crlf:
        end += 2
    devs: list[str] = [] if crlf else ["no CR LF after ']'"]
    return end, _parse_inner(data, o + 1, c, crlf, devs)


def iter_segments(data: bytes, restart_at_bracket: bool = False) -> Iterator[Segment]:
    """Yield frames and noise segments of ``data`` in order; linear in ``len(data)``.

    As sharedlink.lua's scan (docs/fields-sharedlink.md): a frame starts at ``[:`` and runs to
    the first ``]`` after it (a ``[`` inside a value is part of the value), taking a CR LF after
    it; a ``[:`` before that ``]`` means the first is unterminated: its bytes stay noise (a
    malformed frame to the decoding core, :mod:`sharedlink.analysis.malformed`). An
    unterminated tail (its last ``[:`` with no ``]`` after it, or a ``[`` at the very end) is
    reported as noise with the error "unterminated frame".

    ``restart_at_bracket``: the serial wrapper's rule (serial.lua, :mod:`sharedlink.capture.serial_format`):
    any ``[`` inside a would-be frame restarts the frame there (the earlier bytes become noise).
    """
    if restart_at_bracket:
        yield from _segments_restarting(bytes(data))
        return
    data = bytes(data)
    n = len(data)
    noise_start = 0
    o = data.find(b"[:")
    while o >= 0:
        c = data.find(b"]", o + 2)
        if c < 0:
            break
        na = data.find(b"[:", o + 2)  # (past this frame's end when it closes: the next one's start)
        if 0 <= na < c:
            o = na  # unterminated: the next '[:' starts again
            continue
        try:
            end, frame = _frame_between(data, o, c)
        except SharedLinkError:
            o = na  # not a frame: it stays part of the noise; scan on from the next '[:'
            continue
        if o > noise_start:
            yield Segment(noise_start, o, error=SharedLinkError(noise_start, "noise between frames"))
        yield Segment(o, end, frame=frame)
        noise_start = end
        o = na
    if noise_start < n:
        tail = data[noise_start:]
        k = tail.rfind(b"[:")
        open_tail = (k >= 0 and tail.find(b"]", k) < 0) or tail.endswith(b"[")
        reason = "unterminated frame" if open_tail else "noise between frames"
        yield Segment(noise_start, n, error=SharedLinkError(noise_start, reason))


def unterminated_start(data: bytes, start: int) -> int:
    """Where the unterminated frame of an "unterminated frame" tail ``data[start:]`` (from
    :func:`iter_segments`) starts: its last ``[:`` with no ``]`` after it, else the ``[`` at
    the very end (as sharedlink.lua holds a TCP tail for the next segment)."""
    k = data.rfind(b"[:", start)
    if k >= 0 and data.find(b"]", k) < 0:
        return k
    return len(data) - 1


def _segments_restarting(data: bytes) -> Iterator[Segment]:
    """:func:`iter_segments` with ``restart_at_bracket`` (the serial wrapper's rule)."""
    n = len(data)
    pos = 0
    noise_start = 0
    while pos < n:
        o = data.find(b"[", pos)
        if o < 0:
            break
        c = data.find(b"]", o + 1)
        if c < 0:
            break
        o2 = data.rfind(b"[", o, c)  # the last '[' before ']' starts the frame
        try:
            end, frame = _frame_between(data, o2, c)
        except SharedLinkError:
            pos = c + 1  # not a frame: it stays part of the noise; scan on after its ']'
            continue
        if o2 > noise_start:
            yield Segment(noise_start, o2, error=SharedLinkError(noise_start, "noise between frames"))
        yield Segment(o2, end, frame=frame)
        noise_start = pos = end
    if noise_start < n:
        tail = data[noise_start:]
        reason = "unterminated frame" if b"[" in tail else "noise between frames"
        yield Segment(noise_start, n, error=SharedLinkError(noise_start, reason))


# -- typed values ---------------------------------------------------------------------


_LONG_TEXT = re.compile(r"[+-]?[0-9]+")
_DOUBLE_TEXT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


def parse_typed(type_code: int | None, text: str) -> tuple[int | float | str, bool]:
    """``text`` as its ``T`` type: (value, fits). A long is optional sign and digits, a double a
    decimal number with an optional exponent (no ``nan``, ``inf``, ``_`` or spaces); text
    that does not fit its type stays text and ``fits`` is False (the dissector's
    ``sharedlink.var.badvalue``). Strings and untyped values are the text, and fit."""
    if type_code == TYPE_LONG:
        if _LONG_TEXT.fullmatch(text):
            try:
                return int(text), True
            except ValueError:  # more digits than Python converts (sys.get_int_max_str_digits)
                return text, False
        return text, False
    if type_code == TYPE_DOUBLE:
        if _DOUBLE_TEXT.fullmatch(text):
            return float(text), True
        return text, False
    return text, True


def typed_value(type_code: int | None, text: str) -> int | float | str:
    """Convert ``text`` by the ``T`` type code; text that does not convert stays text."""
    return parse_typed(type_code, text)[0]


def guess_value(text: str) -> int | float | str:
    """Type a positional value that came with no ``T``: long, then double, else string."""
    if _LONG_TEXT.fullmatch(text):
        try:
            return int(text)
        except ValueError:  # more digits than Python converts: stays text
            return text
    if _DOUBLE_TEXT.fullmatch(text):
        return float(text)
    return text


def parse_int(text: str) -> int | None:
    """A non-negative decimal ordinal or type code, else None. A number of more than
    :data:`~sharedlink.protocols.limits.MAX_NUMBER_DIGITS` digits is malformed: None (see
    :func:`oversized_numbers`)."""
    return int(text) if len(text) <= MAX_NUMBER_DIGITS and text.isascii() and text.isdigit() else None


def _ordinal(text: str) -> int:
    """An ordinal as the value forms use it: a number, 0 when it is none (``N?``), and
    :data:`~sharedlink.protocols.limits.MAX_SLOTS` (past every slot: what it names is dropped)
    when it has too many digits."""
    n = parse_int(text)
    if n is not None:
        return n
    return MAX_SLOTS if len(text) > MAX_NUMBER_DIGITS and text.isdigit() else 0


def oversized_numbers(fields: Sequence[Field]) -> int:
    """How many ``N``/``L`` fields of a frame hold an ordinal longer than
    :data:`~sharedlink.protocols.limits.MAX_NUMBER_DIGITS` digits (malformed: read as no number;
    a limit hit, as the dissector's "Limit exceeded: N has more than 9 digits"). A ``T`` that
    long is only a type that is not a number (no type; the dissector's "Type is not a
    number"), as is any ``T`` :func:`parse_int` does not read."""
    return sum(1 for f in fields if f.letter in ("N", "L") and len(f.text) > MAX_NUMBER_DIGITS and f.text.isdigit())


# -- frame semantics ------------------------------------------------------------------


def frame_kind(fields: Sequence[Field]) -> str:
    """Label a frame by its fields alone (one of :data:`KINDS` but ``malformed``).

    command (E or M), reply (R), ping (P), pong (G); with no ``D``: a declaration (an ``N``
    or ``L`` ordinal and at least one ``T``/``Q`` pair), a query (``Q`` names, or a list
    request ``L?``/``N?``: a non-numeric ordinal and no pairs), a bare ``N0`` (a delta with no
    change); any ``D``: a data frame, full when its ordinal is 0 or absent and no ``D`` is
    empty. Everything else is ``other``. Stream context refines full/delta:
    :meth:`sharedlink.protocols.state.VariableTable.kind`."""
    has = {f.letter for f in fields}
    if "E" in has or "M" in has:
        return "command"
    if "R" in has:
        return "reply"
    if "P" in has:
        return "ping"
    if "G" in has:
        return "pong"
    if "D" not in has:
        ord_field = next((f for f in fields if f.letter in ("N", "L")), None)
        if ord_field is not None:
            if "Q" in has:
                return "declaration"
            if parse_int(ord_field.text) is None:
                return "query"  # L? / N?: a list request
            return "delta" if ord_field.letter == "N" else "other"
        return "query" if "Q" in has else "other"
    ordinal = frame_ordinal(fields)
    empty_d = any(f.letter == "D" and f.text == "" for f in fields)
    return "full" if ordinal == 0 and not empty_d else "delta"


def frame_ordinal(fields: Sequence[Field]) -> int | None:
    """The start ordinal of a data frame: its first ``N`` (0 when it has none; None when
    the ``N`` is not a number)."""
    for f in fields:
        if f.letter == "N":
            return parse_int(f.text)
    return 0


#: the largest type code a ``T`` may hold (the dissector's ``valid_type``: 0 to 255)
MAX_TYPE_CODE = 255


def parse_type(text: str) -> int | None:
    """A ``T`` field's type code: a number 0 to :data:`MAX_TYPE_CODE`, else None (a type that is
    not a number: the dissector's "Type is not a number"; ten digits and more included)."""
    n = parse_int(text)
    return n if n is not None and n <= MAX_TYPE_CODE else None


@dataclass(frozen=True)
class NamedValue:
    name: str
    type_code: int | None
    text: str
    bad_type: bool = False  # a ``T`` came with it that is not a type (:func:`parse_type`): flagged bad

    @property
    def value(self) -> int | float | str:
        return typed_value(self.type_code, self.text)


def named_values(fields: Sequence[Field]) -> list[NamedValue]:
    """The ``[T t|] Q name|D value`` triplets and ``R name|D value`` replies of a frame.

    BUL-009 ("If it does not exist it is created with the previously defined type"): a name
    with no ``T`` of its own takes the type of the frame's last ``T`` before it (a ``T`` that
    is no type leaves it untyped, and only the name right after that ``T`` is flagged bad);
    with no ``T`` before it in the frame it is untyped (a reply's then typed by its direction's
    list). A ``T`` is a name's own when it comes after the previous variable (a value, or a
    name with no value, ended by the next ``T``, ``Q`` or ``R``), as sharedlink.lua's parser
    reads it (docs/fields-sharedlink.md, "Values")."""
    out: list[NamedValue] = []
    own: str | None = None  # the pending T's text: the next name's own T
    last: int | None = None  # the frame's last T's type (None: no T yet, or one that is no type)
    name: str | None = None
    for f in fields:
        letter = f.letter
        if letter == "T":
            name = None  # (a name pending here had no value: a declared name, it took the T before it)
            own = f.text
            last = parse_type(own)
        elif letter in ("Q", "R"):
            if name is not None:
                own = None  # the pending name (no value) took its own T
            name = f.text
        elif letter == "D":
            if name is not None:
                if own is None:
                    out.append(NamedValue(name, last, f.text))
                else:
                    tc = parse_type(own)
                    out.append(NamedValue(name, tc, f.text, tc is None))
            name, own = None, None
    return out


def positional_values(fields: Sequence[Field]) -> tuple[int, list[str | None]]:
    """For a positional frame: the start ordinal and one entry per ``D`` (None = elided)."""
    ordinal = 0
    values: list[str | None] = []
    for f in fields:
        if f.letter == "N":
            ordinal = _ordinal(f.text)
        elif f.letter == "D":
            values.append(f.text if f.text != "" else None)
    return ordinal, values


def stray_values(fields: Sequence[Field]) -> tuple[int, list[tuple[int, str | None]]]:
    """A frame with names: its ``D`` fields that follow no name (``N0|QZ|D1|D2|D3``: ``D2`` and
    ``D3``), each at its slot (None: empty, carried), and the frame's slot count as a positional
    frame's (its ordinal plus those ``D`` fields: what names them by an a-priori list).

    BUL-049 places a ``D`` at its position from the ``N`` ordinal: a slot is the ordinal plus the
    variables before it in the frame (a named value, a name with no value, a ``D``), as the
    dissector's parser counts them (parse.lua ``take_data``; docs/fields-sharedlink.md,
    "Values")."""
    ordinal: int | None = None
    idx, name = 0, False
    out: list[tuple[int, str | None]] = []
    for f in fields:
        letter = f.letter
        if letter == "N" and ordinal is None:
            ordinal = idx = _ordinal(f.text)
        elif letter in ("Q", "R"):
            idx += name  # a pending name with no value is a variable of its own
            name = True
        elif letter == "T":
            idx += name
            name = False
        elif letter == "D":
            if not name:
                out.append((idx, f.text if f.text != "" else None))
            idx += 1
            name = False
    return (ordinal or 0) + len(out), out


def declared_list(fields: Sequence[Field]) -> tuple[str, int, list[tuple[str, int | None]]] | None:
    """For a declaration frame: ("N" or "L", start ordinal, [(name, type)])."""
    if frame_kind(fields) != "declaration":
        return None
    which, ordinal = "N", 0
    out: list[tuple[str, int | None]] = []
    own: int | None = None  # the pending T's type: the next name's own
    last: int | None = None  # the frame's last T's (BUL-009: a name with no T of its own takes it)
    for f in fields:
        if f.letter in ("N", "L"):
            which, ordinal = f.letter, _ordinal(f.text)
        elif f.letter == "T":
            own = last = parse_type(f.text)
        elif f.letter == "Q":
            out.append((f.text, last if own is None else own))
            own = None
    return which, ordinal, out


# -- builders for common frames ----------------------------------------------------------


def named_fields(values: Sequence[tuple[str, int, str]], ordinal: int = 0) -> tuple[Field, ...]:
    """Fields of a named (beacon) frame from (name, type, text) triplets."""
    out = [Field("N", str(ordinal))]
    for name, type_code, text in values:
        out += [Field("T", str(type_code)), Field("Q", name), Field("D", text)]
    return tuple(out)


def positional_fields(values: Sequence[str | None], ordinal: int = 0) -> tuple[Field, ...]:
    """Fields of a positional frame; None stands for an elided (unchanged) value."""
    return (Field("N", str(ordinal)),) + tuple(Field("D", v or "") for v in values)


def declaration_fields(names: Sequence[tuple[str, int]], ordinal: int = 0, inbound: bool = False) -> tuple[Field, ...]:
    out = [Field("L" if inbound else "N", str(ordinal))]
    for name, type_code in names:
        out += [Field("T", str(type_code)), Field("Q", name)]
    return tuple(out)


def query_fields(name: str) -> tuple[Field, ...]:
    return (Field("Q", name),)


def reply_fields(name: str, text: str) -> tuple[Field, ...]:
    return (Field("R", name), Field("D", text))


# -- fast encoders (the generator's hot path; same bytes as build_frame) ------------------


def encode_named(dst: str, src: str, values: Sequence[tuple[str, int, str]], ordinal: int = 0, crlf: bool = True) -> bytes:
    """A named (beacon) frame from (name, type, text) triplets."""
    body = ":%s%s|N%d" % (dst, src, ordinal) + "".join("|T%d|Q%s|D%s" % (t, n, x) for n, t, x in values) + "|C"
    return _close(body.encode("latin-1"), crlf)


def encode_positional(dst: str, src: str, texts: Sequence[str | None], ordinal: int = 0, crlf: bool = True) -> bytes:
    """A positional frame; None is an elided (unchanged) value."""
    body = ":%s%s|N%d|D" % (dst, src, ordinal) + "|D".join(t or "" for t in texts) + "|C"
    return _close(body.encode("latin-1"), crlf)


_HEX2 = tuple(b"%02X" % i for i in range(256))


def _close(raw: bytes, crlf: bool) -> bytes:
    tail = b"]\r\n" if crlf else b"]"
    return b"[" + raw + _HEX2[sum(raw) & 0xFF] + tail
