"""Malformed frames: the ``[:`` of UDP/TCP bytes that hold no well-formed frame, cut and checked
as sharedlink.lua's scan cuts and checks them (docs/fields-sharedlink.md, "Counts").

The one place for the rule: the decoding core (:mod:`sharedlink.analysis.decode`) turns each such
piece into a :class:`~sharedlink.analysis.decode.Decoded` of kind ``malformed`` with
:class:`Unframed`, so every command that decodes (stats, export, ingest, diff, plot, watch)
counts it the same way; the rest of the bytes stay noise. On a serial link the wrapper
(serial.lua) decides what is a frame: its noise stays noise. A segment of a related protocol
(:func:`other_protocol`, or any unframed segment on a conversation that carried one) is left whole.
"""

from __future__ import annotations

import re
from collections.abc import Iterator

from sharedlink.capture.serial_format import GIVEN_UP
from sharedlink.capture.stream import StreamFrame
from sharedlink.protocols.limits import MAX_CONVERSATIONS

#: the reason a noise piece cut beside a malformed frame carries (its record was looked at whole)
PIECE = "noise beside a malformed frame"


def _line_end(raw: bytes, b: int) -> int:
    """The index just past a frame closed at ``raw[b]`` and its line end (CR LF, CR or LF)."""
    c = raw[b + 1 : b + 3]
    if c[:1] == b"\r":
        return b + 3 if c == b"\r\n" else b + 2
    return b + 2 if c[:1] == b"\n" else b + 1


def unframed_pieces(raw: bytes) -> Iterator[tuple[str | None, str, int, int, bool]]:
    """The pieces of UDP/TCP bytes that hold no well-formed frame, as sharedlink.lua's ``scan``
    cuts them (docs/fields-sharedlink.md, "Counts"): ``(src, dst, start, end, bad)`` for each ``[:``
    (``raw[start:end]`` its bytes), a frame of kind ``malformed`` running to the first ``]`` (and
    its line end) when no other ``[:`` comes first, else up to that ``[:`` (or the end); its
    letters from the two bytes after ``[:`` (destination, source; ``?`` for a byte it lacks),
    and ``bad`` when its checksum is wrong (:func:`malformed_checksum_bad`).
    ``(None, "", start, end, False)`` for the noise between them, bytes other than CR and LF (CR and
    LF alone are no noise, as in the dissector)."""
    n = len(raw)
    pos = 0
    b = 0  # the next "]" (searched again only once passed, as the dissector does: linear; -1: none left)
    while pos < n:
        a = raw.find(b"[:", pos)
        end = n if a < 0 else a
        if end > pos and raw[pos:end].strip(b"\r\n"):
            yield None, "", pos, end, False
        if a < 0:
            return
        if 0 <= b < a + 2:
            b = raw.find(b"]", a + 2)
        na = raw.find(b"[:", a + 2)
        if b >= 0 and (na < 0 or b < na):
            body, pos = raw[a:b], _line_end(raw, b)
        else:
            body = raw[a:na] if na >= 0 else raw[a:]
            pos = na if na >= 0 else n
        dst = chr(body[2]) if len(body) > 2 else "?"
        src = chr(body[3]) if len(body) > 3 else "?"
        yield src, dst, a, pos, malformed_checksum_bad(body)


_HEX_DIGITS = re.compile(rb"[0-9A-Fa-f]{1,8}").fullmatch


def malformed_checksum_bad(body: bytes) -> bool:
    """Whether sharedlink.lua finds a malformed frame's checksum wrong (``body``: its bytes from
    ``[`` on, without the closing ``]``): a last field starting with ``C``, after the first ``|``
    behind the letters, is checked as in a good frame (the byte sum from ``:`` to that ``C``,
    mod 256, against 1 to 8 hex digits); no such field, no verdict."""
    if len(body) < 5:
        return False  # no field at all
    p = 5 if body[4] == 0x7C else body.find(b"|", 5) + 1
    if p == 0:
        return False
    last = body[p:].rsplit(b"|", 1)[-1]
    if last[:1] != b"C":
        return False
    cpos = len(body) - len(last)
    text = last[1:]
    return not (_HEX_DIGITS(text) and int(text, 16) == sum(body[1 : cpos + 1]) % 256)


#: a Holland blackboard message (set ``:`` or request ``;``, ASCII hex, CR), as blackboard.lua's heuristic
_BLACKBOARD = re.compile(rb"[:;][0-9A-Fa-f]{8,}\r")


def other_protocol(raw: bytes) -> str | None:
    """The related robot protocol a segment that holds no SharedLink frame starts with, as the
    dissectors' heuristics see it: ``p2os`` (``FA FB``), ``blackboard`` (``:``/``;`` then hex and
    CR), else None (noise; :func:`~sharedlink.analysis.stats.capture_stats` also counts the
    binary replies on a conversation that carried one of these as that protocol)."""
    if raw.startswith(b"\xfa\xfb"):
        return "p2os"
    if _BLACKBOARD.match(raw):
        return "blackboard"
    return None


def talk_key(conv: tuple) -> tuple:
    """A conversation, both directions alike."""
    proto, src, sport, dst, dport = conv
    return (proto, *sorted(((src, sport), (dst, dport))))


class Unframed:
    """Cuts the unframed segments (noise :class:`StreamFrame` s) of UDP/TCP conversations into
    malformed frames and noise (:meth:`pieces`), remembering the conversations a related
    protocol was seen on (their segments are left whole, as ``stats`` counts them apart)."""

    def __init__(self) -> None:
        self.talks: dict[tuple, str] = {}

    def pieces(self, sf: StreamFrame) -> list[tuple[str | None, str, int, int, bool]] | None:
        """``sf`` (``frame`` None) as :func:`unframed_pieces`, or None when it is left whole:
        a serial link's noise, an unfinished frame given up, no ``[:`` in it, or a related
        protocol's segment."""
        conv = sf.conv
        if conv[0] == "serial":
            return None
        raw = sf.raw
        talks = self.talks
        if raw[:1] == b"\xfa" or raw[:1] in b":;":  # (a related protocol's first byte: the full test)
            other = other_protocol(raw)
            if other is not None:
                if len(talks) < MAX_CONVERSATIONS:
                    talks[talk_key(conv)] = other
                return None
        if b"[:" not in raw or sf.error == GIVEN_UP or (talks and talk_key(conv) in talks):
            return None
        return list(unframed_pieces(raw))
