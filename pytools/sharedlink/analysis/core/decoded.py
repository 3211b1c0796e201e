"""What the core gives for one SharedLink frame: :class:`Decoded`, and the kinds' groups."""

from __future__ import annotations

from sharedlink.protocols.codec import Frame, parse_frame
from sharedlink.protocols.state import Update, VariableTable

#: seconds past the sync interval before a value frame counts as late (as in the dissector)
SYNC_SLACK_S = 0.5
#: kinds that carry values
VALUE_KINDS = ("full", "delta", "reply")
#: kinds that take part in sync tracking
DATA_KINDS = ("full", "delta")


class Decoded:
    """One SharedLink frame in stream context.

    ``table`` is the live table of the frame's direction (it changes as later frames are
    decoded): read what you need from it before taking the next item. ``frame`` is parsed
    from ``raw`` only when asked (the fast path never needs it).
    """

    __slots__ = ("number", "ts_ns", "conv", "raw", "kind", "checksum_ok", "updates", "table", "late", "sync_gap_ns",
                 "shown", "response_to", "src", "dst", "_frame")

    def __init__(
        self,
        number: int,
        ts_ns: int,
        conv: tuple[str, str, int, str, int],
        raw: bytes,
        frame: Frame | None,
        kind: str,
        checksum_ok: bool | None,  # None: the frame has no checksum field
        updates: tuple[Update, ...],  # empty when the checksum is bad
        table: VariableTable,
        late: bool,  # sync late (see the module doc)
        sync_gap_ns: int | None,  # on a full frame: time since the direction's previous full one
        shown: tuple[Update, ...] = (),  # the values the frame shows: ``updates``, or as sent when bad
        response_to: int | None = None,  # a reply: the number of its query or declaration
        src: str = "",  # the letters (taken from ``frame`` when it is given)
        dst: str = "",
    ) -> None:
        self.number, self.ts_ns, self.conv, self.raw, self._frame = number, ts_ns, conv, raw, frame
        self.kind, self.checksum_ok, self.updates, self.table = kind, checksum_ok, updates, table
        self.late, self.sync_gap_ns, self.shown, self.response_to = late, sync_gap_ns, shown, response_to
        if frame is not None:
            src, dst = frame.src, frame.dst
        self.src, self.dst = src, dst

    @property
    def frame(self) -> Frame:
        """The parsed frame; a ``malformed`` one's: its letters, no fields, no checksum field."""
        f = self._frame
        if f is None:
            if self.kind == "malformed":
                f = Frame(self.dst, self.src, (), self.raw.endswith(b"\r\n"), None, ("malformed",))
            else:
                f = parse_frame(self.raw)
            self._frame = f
        return f

    @property
    def pair(self) -> str:
        """``"B>A"``: from B to A."""
        return f"{self.src}>{self.dst}"

    def changes(self) -> list[Update]:
        """The variables this frame gave a new value (carried values left out)."""
        return [u for u in self.updates if u.changed and not u.carried and u.text is not None]

    def present(self) -> list[Update]:
        """The values this frame carries itself (changed or not)."""
        return [u for u in self.updates if not u.carried and u.text is not None]

    def __repr__(self) -> str:
        return f"Decoded(number={self.number}, pair={self.pair!r}, kind={self.kind!r}, checksum_ok={self.checksum_ok})"


#: the table a malformed frame shows: none (it sets nothing, shows no values)
NO_TABLE = VariableTable()
