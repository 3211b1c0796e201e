"""The decoding core, :class:`Decoder`: the reference path with the fast tiers in front."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from sharedlink.analysis.core.capture import capture_items
from sharedlink.analysis.core.columns import Columns, ColumnsSink, DirColumns
from sharedlink.analysis.core.compiled import Compiled
from sharedlink.analysis.core.counts import Counted, CountsSink, DirCounts
from sharedlink.analysis.core.decoded import Decoded
from sharedlink.analysis.core.direction import Direction
from sharedlink.analysis.core.fastpath import FastPath
from sharedlink.analysis.core.lanes import ColLane
from sharedlink.analysis.core.reference import ReferenceDecoder
from sharedlink.capture.packets import Datagram
from sharedlink.capture.stream import FrameSplitter, StreamFrame
from sharedlink.protocols.state import BEACON_VARIABLES


class Decoder(FastPath, CountsSink, ColumnsSink, ReferenceDecoder):
    """The decoding core: every command that decodes SharedLink goes through it. Same results
    as :class:`ReferenceDecoder` (the tests compare them on generated streams built to catch a
    wrong reuse), fast by construction:

    * a datagram holding exactly one named ``N0`` frame with a good checksum, in a layout (types
      and names, in order) one of its direction's earlier good full or delta frames had, its
      variables still of those types, is decoded from one latin-1 string and one split, without
      building a :class:`~sharedlink.protocols.codec.Frame` (``Decoded.frame`` parses it if
      asked); unchanged carried values reuse the Update made for the previous frame;
    * so is a positional ``N0`` frame alone in a datagram with as many slots as its direction's
      last positional frame through the reference path, its slots named as that decoding named
      them (the naming rules stay in :mod:`sharedlink.protocols.state`);
    * everything else goes through the reference path; a frame there that changes the
      direction's state in another way forgets its layouts, a declaration forgets every layout,
      and any frame there forgets the Updates kept for reuse and the positional layouts;
    * :meth:`capture` reads a capture's plain Ethernet/IPv4/UDP records without the general
      packet decoder, the rest through :func:`sharedlink.capture.stream.iter_frames`' splitters.

    Its parts: the reference path (:class:`ReferenceDecoder`), the fast path of Decoded frames
    (:class:`~sharedlink.analysis.core.fastpath.FastPath`), the counts and columns sinks
    (:class:`~sharedlink.analysis.core.counts.CountsSink`,
    :class:`~sharedlink.analysis.core.columns.ColumnsSink`) and the changes-only mode's compiled
    layouts (:meth:`compiled`, :class:`~sharedlink.analysis.core.compiled.Compiled`).
    """

    def __init__(self, variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES, sync_interval: float = 1.0,
                 carried: bool = True) -> None:
        super().__init__(variables, sync_interval, carried)
        self._hot: dict[tuple, Direction] = {}
        self.fast = 0  # frames decoded by the fast path
        self.batch: dict[Direction, DirCounts] = {}  # counts only: what count() took, per direction
        self.rows: dict[Direction, DirColumns] = {}  # columns only: what column() took, per direction
        self.taken = 0  # columns only: frames in ``rows``
        self._lanes: dict[bytes, ColLane] = {}  # columns only: addresses, ports and letters -> run taker
        self._mode: str | None = None  # set by the first capture() or compiled() (see _use)
        self.splitter = FrameSplitter()

    def decode(self, sf: StreamFrame) -> Decoded:
        """One frame (``sf.frame`` parsed)."""
        d = self._try_fast(sf.number, sf.ts_ns, sf.conv, sf.raw)
        if d is None:
            d = ReferenceDecoder.decode(self, sf)
            self._learn(d)
        return d

    def decode_datagram(self, number: int, ts_ns: int, conv: tuple, data: bytes) -> Iterator[Decoded | StreamFrame]:
        """The frames of a UDP datagram, and its noise (a :class:`StreamFrame` with ``frame``
        None), each decoded when it is taken (so its ``table`` is the table as that frame leaves
        it). A datagram that is one hot frame is not parsed at all."""
        d = self._try_fast(number, ts_ns, conv, data)
        if d is not None:
            yield d
            return
        proto, src, sport, dst, dport = conv
        for sf in self.splitter.split(number, ts_ns, Datagram(proto, src, dst, sport, dport, data)):
            if sf.frame is None:
                yield from self.unframed(sf)
            else:
                d = ReferenceDecoder.decode(self, sf)
                self._learn(d)
                yield d

    def capture(self, path: str | Path, progress: Callable[[int, int], None] | None = None, counts: bool = False,
                columns: bool = False) -> Iterator[Decoded | StreamFrame | tuple[int, int] | Counted | Columns]:
        """Every item of a capture, as :func:`iter_decoded` gives them. ``progress(bytes, records)`` is
        called every few thousand records with (bytes of the file read so far, records).
        ``counts``: the frames the fast path takes come as :class:`Counted` batches instead of
        :class:`Decoded` frames (for callers that count: no per-frame objects). ``columns``: they
        come as :class:`Columns` batches, their values as rows appended to per-column lists
        (for callers that store rows: no Update, no Decoded)."""
        self._use("columns" if columns else "counts" if counts else "decoded")
        return capture_items(self, path, progress, counts, columns)

    def _use(self, mode: str) -> None:
        """One mode a Decoder: the compiled layouts (changes only) hold texts that the other
        modes' fast paths move (and columns runs write) behind their back."""
        if self._mode != mode:
            if self._mode is not None:
                raise ValueError(f"a Decoder used in the {self._mode} mode cannot be used in the {mode} mode")
            self._mode = mode

    def datagram(self, dg) -> Iterator[Decoded | StreamFrame]:
        """:meth:`decode_datagram` of an object with ``number``, ``ts_ns``, ``conv`` and ``data``
        (the watch's received datagrams)."""
        return self.decode_datagram(dg.number, dg.ts_ns, dg.conv, dg.data)

    def reference(self, sf: StreamFrame) -> Decoded:
        """One frame (``sf.frame`` parsed) through the reference path, the core's state following
        it: what :meth:`decode` does with a frame its fast path does not take. In the changes-only
        mode every frame :meth:`change_at` does not take comes here (one mode a Decoder: the
        Decoded fast path would move values under the compiled layouts)."""
        d = ReferenceDecoder.decode(self, sf)
        self._learn(d)
        return d

    def compiled(self, conv: tuple, src: str, dst: str) -> Compiled | None:
        """Changes only: the compiled layouts of a direction whose frames the fast path takes
        (:class:`Compiled`; its ``take`` decodes a frame), made or brought up to date from its
        table; None when it has none (its frames go to :meth:`reference`). Valid until the next
        frame through :meth:`reference`. One mode a Decoder: :meth:`decode` would move values
        under the compiled layouts."""
        self._use("changes")
        h = self._hot.get((conv, src, dst))
        if h is None:
            return None
        c = h.compiled
        if c is None:
            c = h.compiled = Compiled(h, (dst + src).encode("latin-1", "replace"))
        elif c.version != h.version:
            c.build(h)
        return c if c.named is not None or c.pos is not None else None

