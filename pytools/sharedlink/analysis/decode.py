"""Decoded frames with the variable table after each: what stats, export and plot read.

:func:`iter_decoded` walks a capture with :func:`sharedlink.capture.stream.iter_frames` (streaming, TCP
reassembled, serial captures deframed per direction) and keeps a
:class:`~sharedlink.protocols.state.LinkState`, so every SharedLink frame comes out as a
:class:`Decoded`: its kind in stream context, its checksum verdict, the variables it set and the
direction's whole table as the frame leaves it. Noise and records that are neither UDP/TCP nor
serial SharedLink pass through unchanged (a :class:`~sharedlink.capture.stream.StreamFrame` with
``frame`` None, or a ``(number, ts_ns)`` tuple) so callers can count them.

Choices (shared with the dissector, see ``docs/protocol.md``):

* State is kept per direction, keyed on the source and destination letters (as ``diff`` does).
* A frame whose checksum is wrong is counted and labelled but does not touch the state: its
  values are not trusted, so nothing is carried from it.
* ``late`` is the dissector's ``sharedlink.sync.late``: a value frame that is not a full set,
  seen more than the sync interval plus :data:`SYNC_SLACK_S` after the direction's last full
  set (or its first value frame, before any full set).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from sharedlink.capture.pcapio import NS
from sharedlink.capture.stream import StreamFrame, iter_frames
from sharedlink.protocols.codec import Frame
from sharedlink.protocols.state import BEACON_VARIABLES, LinkState, Update, VariableTable
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
        self._sync: dict[tuple[str, str], list[int | None]] = {}  # (src, dst) -> [first data ts, last full ts]

    def decode(self, sf: StreamFrame) -> Decoded:
        frame = sf.frame
        assert frame is not None
        table = self.link.table(frame.src, frame.dst)
        kind = table.kind(frame)
        ok = frame.checksum.ok if frame.checksum is not None else None
        late = False
        gap: int | None = None
        if ok is False:
            updates: tuple[Update, ...] = ()
        else:
            updates = tuple(self.link.apply(frame, sf.number, sf.ts_ns))
            if kind in DATA_KINDS:
                sync = self._sync.get((frame.src, frame.dst))
                if sync is None:
                    sync = self._sync[(frame.src, frame.dst)] = [sf.ts_ns, None]
                if kind == "full":
                    if sync[1] is not None:
                        gap = sf.ts_ns - sync[1]
                    sync[1] = sf.ts_ns
                else:
                    since = sync[1] if sync[1] is not None else sync[0]
                    late = sf.ts_ns - since > self.late_ns  # type: ignore[operator]
        return Decoded(sf.number, sf.ts_ns, sf.conv, sf.raw, frame, kind, ok, updates, table, late, gap)


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
    """UTC ISO 8601 with nanoseconds: ``2026-01-01T12:00:00.200000000Z``."""
    import datetime as _dt

    sec, frac = divmod(ts_ns, NS)
    d = _dt.datetime.fromtimestamp(sec, _dt.timezone.utc)
    return d.strftime("%Y-%m-%dT%H:%M:%S") + ".%09dZ" % frac
