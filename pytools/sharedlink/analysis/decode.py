"""Decoded frames with the variable table after each: what stats, export and plot read.

:func:`iter_decoded` walks a capture with :func:`sharedlink.capture.stream.iter_frames` (streaming, TCP
reassembled, serial captures deframed per direction) and keeps a
:class:`~sharedlink.protocols.state.LinkState`, so every SharedLink frame comes out as a
:class:`Decoded`: its kind in stream context, its checksum verdict, the variables it set and the
direction's whole table as the frame leaves it. Noise and records that are neither UDP/TCP nor
serial SharedLink pass through unchanged (a :class:`~sharedlink.capture.stream.StreamFrame` with
``frame`` None, or a ``(number, ts_ns)`` tuple) so callers can count them.

Choices (shared with the dissector, see ``docs/protocol.md``):

* State is kept per conversation and direction, as the dissector keys it: UDP/TCP by
  addresses, ports and the source and destination letters, serial by capture direction and
  letters (:class:`~sharedlink.protocols.state.LinkState`). ``pair`` (``"B>A"``) is what
  reports group by.
* A frame whose checksum is wrong is counted, labelled and judged against the state before it,
  but does not touch the state: nothing is stored or carried from it, no list learnt, no sync
  clock reset. ``shown`` has its values as sent; ``updates`` is empty.
* ``late`` is the dissector's ``sharedlink.sync.late``: a data frame that is not a full set,
  seen more than the sync interval plus :data:`SYNC_SLACK_S` after the direction's last full
  set with a good (or no) checksum, or its first data frame before any.
* ``response_to``: a reply's query or declaration (the latest unanswered one the other way
  between the same ports whose names include the reply's).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from sharedlink.capture.pcapio import NS
from sharedlink.capture.stream import StreamFrame, iter_frames
from sharedlink.protocols.codec import Frame
from sharedlink.protocols.state import BEACON_VARIABLES, LinkState, Update, VariableTable, conversation_key
from sharedlink.protocols.state import parse_variables as parse_variables  # its home is state

#: seconds past the sync interval before a value frame counts as late (as in the dissector)
SYNC_SLACK_S = 0.5
#: kinds that carry values
VALUE_KINDS = ("full", "delta", "reply")
#: kinds that take part in sync tracking
DATA_KINDS = ("full", "delta")


@dataclass(frozen=True)
class Decoded:
    """One SharedLink frame in stream context.

    ``table`` is the live table of the frame's direction (it changes as later frames are
    decoded): read what you need from it before taking the next item.
    """

    number: int
    ts_ns: int
    conv: tuple[str, str, int, str, int]
    raw: bytes
    frame: Frame
    kind: str
    checksum_ok: bool | None  # None: the frame has no checksum field
    updates: tuple[Update, ...]  # empty when the checksum is bad
    table: VariableTable
    late: bool  # sync late (see the module doc)
    sync_gap_ns: int | None  # on a full frame: time since the direction's previous full one
    shown: tuple[Update, ...] = ()  # the values the frame shows: ``updates``, or as sent when bad
    response_to: int | None = None  # a reply: the number of its query or declaration

    @property
    def src(self) -> str:
        return self.frame.src

    @property
    def dst(self) -> str:
        return self.frame.dst

    @property
    def pair(self) -> str:
        """``"B>A"``: from B to A."""
        return f"{self.frame.src}>{self.frame.dst}"

    def changes(self) -> list[Update]:
        """The variables this frame gave a new value (carried values left out)."""
        return [u for u in self.updates if u.changed and not u.carried and u.text is not None]

    def present(self) -> list[Update]:
        """The values this frame carries itself (changed or not)."""
        return [u for u in self.updates if not u.carried and u.text is not None]


class Decoder:
    """Turns :class:`StreamFrame` s into :class:`Decoded` frames (one capture, in order)."""

    def __init__(self, variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES, sync_interval: float = 1.0) -> None:
        self.link = LinkState(default_list=list(variables))
        self.late_ns = round((sync_interval + SYNC_SLACK_S) * NS)
        self._sync: dict[tuple, list[int | None]] = {}  # table key -> [first data ts, last full ts]
        self._asks: list[tuple[tuple, frozenset[str], int]] = []  # unanswered (match key, names, number)

    def decode(self, sf: StreamFrame) -> Decoded:
        frame = sf.frame
        assert frame is not None
        conv = conversation_key(sf.conv)
        table = self.link.table(frame.src, frame.dst, conv)
        kind = table.kind(frame)
        ok = frame.checksum.ok if frame.checksum is not None else None
        late = False
        gap: int | None = None
        if ok is False:
            updates: tuple[Update, ...] = ()
            shown = tuple(table.preview(frame, sf.number, sf.ts_ns)) if kind in VALUE_KINDS else ()
        else:
            updates = shown = tuple(self.link.apply(frame, sf.number, sf.ts_ns, conv))
        if kind in DATA_KINDS:
            skey = (conv, frame.src, frame.dst)
            sync = self._sync.get(skey)
            if sync is None:
                sync = self._sync[skey] = [sf.ts_ns, None]
            if kind == "full" and ok is not False:
                if sync[1] is not None:
                    gap = sf.ts_ns - sync[1]
                sync[1] = sf.ts_ns
            elif kind != "full":
                since = sync[1] if sync[1] is not None else sync[0]
                late = sf.ts_ns - since > self.late_ns  # type: ignore[operator]
        response_to = self._link_response(sf, frame, kind) if kind in ("query", "declaration", "reply") else None
        return Decoded(
            sf.number, sf.ts_ns, sf.conv, sf.raw, frame, kind, ok, updates, table, late, gap, shown, response_to
        )

    def _link_response(self, sf: StreamFrame, frame: Frame, kind: str) -> int | None:
        """Remember a query or declaration; for a reply, the one it answers."""
        proto, _src, sport, _dst, dport = sf.conv
        ports = (proto, min(sport, dport), max(sport, dport))
        if kind != "reply":
            names = frozenset(f.text for f in frame.fields if f.letter == "Q")
            self._asks.append(((ports, frame.src, frame.dst), names, sf.number))
            if len(self._asks) > 4096:
                del self._asks[:1024]
            return None
        want = {f.text for f in frame.fields if f.letter == "R"}
        key = (ports, frame.dst, frame.src)
        for i in range(len(self._asks) - 1, -1, -1):
            k, names, number = self._asks[i]
            if k == key and want <= names:
                del self._asks[i]
                return number
        return None


def iter_decoded(
    path: str | Path,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
) -> Iterator[Decoded | StreamFrame | tuple[int, int]]:
    """Every item of a capture: :class:`Decoded` for frames, the noise :class:`StreamFrame`
    and ``(number, ts_ns)`` for other records unchanged. Raises
    :class:`~sharedlink.capture.pcapio.CaptureError` on damage, after everything before it."""
    dec = Decoder(variables, sync_interval)
    for item in iter_frames(path):
        if isinstance(item, StreamFrame) and item.frame is not None:
            yield dec.decode(item)
        else:
            yield item


def format_time(ts_ns: int) -> str:
    """UTC ISO 8601 with nanoseconds: ``2026-01-01T12:00:00.200000000Z``. Any year (past 9999
    it has more digits, as ISO 8601's expanded years; before year 1 a sign)."""
    sec, frac = divmod(ts_ns, NS)
    days, rest = divmod(sec, 86400)
    y, m, d = _civil_from_days(days)
    year = "%04d" % y if 0 <= y <= 9999 else "%+05d" % y
    return "%s-%02d-%02dT%02d:%02d:%02d.%09dZ" % (year, m, d, rest // 3600, rest // 60 % 60, rest % 60, frac)


def _civil_from_days(z: int) -> tuple[int, int, int]:
    """(year, month, day) of day ``z`` counted from 1970-01-01, proleptic Gregorian, any year
    (Howard Hinnant's ``civil_from_days``)."""
    z += 719468
    era = z // 146097
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    d = doy - (153 * mp + 2) // 5 + 1
    m = mp + 3 if mp < 10 else mp - 9
    return yoe + era * 400 + (m <= 2), m, d
