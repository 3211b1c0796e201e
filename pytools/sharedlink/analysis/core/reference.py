"""The reference path: :class:`ReferenceDecoder`, frame by frame through
:class:`~sharedlink.protocols.state.LinkState` (the tests' oracle, and where the fast tiers hand
every frame they do not take)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from sharedlink.analysis.core.decoded import DATA_KINDS, NO_TABLE, SYNC_SLACK_S, VALUE_KINDS, Decoded
from sharedlink.analysis.core.direction import full_set, is_late
from sharedlink.analysis.malformed import PIECE, Unframed
from sharedlink.capture.pcapio import NS
from sharedlink.capture.stream import StreamFrame
from sharedlink.protocols.codec import Frame, oversized_numbers
from sharedlink.protocols.limits import MAX_CONVERSATIONS
from sharedlink.protocols.state import (
    BEACON_VARIABLES,
    LinkState,
    PendingAsks,
    Update,
    conversation_key,
    link_response,
)


class ReferenceDecoder:
    """The plain decoder, frame by frame through :class:`~sharedlink.protocols.state.LinkState`:
    obviously right, slow. The tests' oracle, and the path :class:`Decoder` hands every frame
    its fast path does not take; no command uses it on its own.

    ``carried`` False leaves a named frame's carried values out of ``updates`` (for callers that
    read only what frames carry: then a frame costs what it holds, not the direction's table)."""

    def __init__(self, variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES, sync_interval: float = 1.0,
                 carried: bool = True) -> None:
        self.link = LinkState(default_list=list(variables))
        self.limits = self.link.limits
        self.carried = carried
        self.late_ns = round((sync_interval + SYNC_SLACK_S) * NS)
        self._sync: dict[tuple, list[int | None]] = {}  # table key -> [first data ts, last full ts]
        self._asks = PendingAsks(self.limits)  # unanswered queries, list requests and declarations, per querier
        self._unframed = Unframed()  # malformed frames cut from the bytes that hold no frame

    def decode(self, sf: StreamFrame) -> Decoded:
        frame = sf.frame
        assert frame is not None
        conv = conversation_key(sf.conv)
        table = self.link.table(frame.src, frame.dst, conv)
        kind = table.kind(frame)
        ok = frame.checksum.ok if frame.checksum is not None else None
        self.limits.numbers += oversized_numbers(frame.fields)
        late, gap = False, None
        if ok is False:
            updates: tuple[Update, ...] = ()
            shown = tuple(table.preview(frame, sf.number, sf.ts_ns, self.carried)) if kind in VALUE_KINDS else ()
            dropped = table.dropped if kind in VALUE_KINDS else ()
        else:
            updates = shown = tuple(self.link.apply(frame, sf.number, sf.ts_ns, conv, self.carried))
            dropped = self.link.dropped
        if dropped:  # values past a limit: shown as the dissector shows them, in no update
            shown = (*shown, *dropped)
        if kind in DATA_KINDS:
            late, gap = self._clock(conv, frame, kind, ok, sf.ts_ns)
        response_to = self._link_response(sf, frame, kind) if kind in ("query", "declaration", "reply") else None
        return Decoded(
            sf.number, sf.ts_ns, sf.conv, sf.raw, frame, kind, ok, updates, table, late, gap, shown, response_to
        )

    def _clock(self, conv: tuple, frame: Frame, kind: str, ok: bool | None, ts: int) -> tuple[bool, int | None]:
        """The sync clock of a data frame's direction (made at its first data frame): ``(late,
        gap)`` (:func:`~sharedlink.analysis.core.direction.is_late`,
        :func:`~sharedlink.analysis.core.direction.full_set`; a bad full set changes nothing)."""
        skey = (conv, frame.src, frame.dst)
        sync = self._sync.get(skey)
        if sync is None:
            sync = [ts, None]
            if len(self._sync) < MAX_CONVERSATIONS:
                self._sync[skey] = sync
        if kind != "full":
            return is_late(sync, ts, self.late_ns), None
        return False, (full_set(sync, ts) if ok is not False else None)

    def _link_response(self, sf: StreamFrame, frame: Frame, kind: str) -> int | None:
        """Remember a query or declaration; for a reply (or a declaration answering a list
        request), the one it answers (:func:`sharedlink.protocols.state.link_response`)."""
        return link_response(self._asks, conversation_key(sf.conv), frame, kind, sf.number)

    def unframed(self, sf: StreamFrame) -> Iterator[Decoded | StreamFrame]:
        """Bytes that hold no well-formed frame (``sf.frame`` None): on UDP and TCP a
        :class:`Decoded` of kind ``malformed`` for each ``[:`` in them (its letters from its
        header, ``?`` for one it lacks; ``raw`` its bytes; ``checksum_ok`` False when its checksum
        is wrong, else None; no updates, an empty table, never late) and the noise between them
        (a :class:`~sharedlink.capture.stream.StreamFrame` of reason
        :data:`~sharedlink.analysis.malformed.PIECE`); ``sf`` itself when it is left whole
        (:meth:`sharedlink.analysis.malformed.Unframed.pieces`)."""
        pieces = self._unframed.pieces(sf)
        if pieces is None:
            yield sf
            return
        raw, number, ts, conv = sf.raw, sf.number, sf.ts_ns, sf.conv
        for src, dst, a, e, bad in pieces:
            if src is None:
                yield StreamFrame(number, ts, conv, raw[a:e], None, PIECE)
            else:
                yield Decoded(number, ts, conv, raw[a:e], None, "malformed", False if bad else None, (), NO_TABLE,
                              False, None, (), None, src, dst)

