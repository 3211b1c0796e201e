"""Change records: the compact bytes :class:`~sharedlink.analysis.changes.ChangeReader` gives
for each value frame (destination and source letters, then ``\\x1f`` name ``\\x1e`` value per
changed variable, escaped so the separators cannot occur in names or values). Made by the
decoding core's changes-only mode (:meth:`sharedlink.analysis.decode.Decoder.change_at`) and by
the reader for the frames the core's reference path decodes."""

from __future__ import annotations

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
