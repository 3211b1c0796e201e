"""One capture's rows held per partition (UTC day, sender, receiver) until
:class:`~sharedlink.fleet.ingest._Rows` writes them: :class:`Part`, a partition's frames and
values as per-column lists; :class:`Batches`, the decoder's ``Columns`` batches (its fast path's
frames, per direction) into their partitions a direction at a time. The worker's loop,
:func:`sharedlink.fleet.ingest._decode_into`, puts the frames decoded the general way in one by
one (:meth:`Part.add_decoded`)."""

from __future__ import annotations

from sharedlink.analysis.core.columns import ColumnBatch
from sharedlink.analysis.decode import NS, Columns, Decoded, DirColumns

DAY_NS = 86_400 * NS


def day_of(ts_ns: int) -> str:
    """The UTC day of a time, ``YYYY-MM-DD`` (a partition's ``day``)."""
    import datetime as _dt

    return _dt.datetime.fromtimestamp(ts_ns // NS, _dt.timezone.utc).strftime("%Y-%m-%d")


class Part(ColumnBatch):
    """The rows of one partition (day, letters) not yet written, as per-column lists: those of
    :class:`~sharedlink.analysis.core.columns.ColumnBatch` (per frame record number, time,
    bytes, kind, late and how many value rows it has; per value row, frame after frame, name,
    text, type, carried, changed), and per frame its ordinal in the capture (``seq``), its
    conversation and its checksum verdict (``ok``)."""

    __slots__ = ("day", "src", "dst", "seq", "conv", "ok")

    def __init__(self, day: str, src: str, dst: str) -> None:
        super().__init__()
        self.day, self.src, self.dst = day, src, dst
        self.seq: list[int] = []
        self.conv: list[tuple] = []
        self.ok: list[bool | None] = []

    def held(self) -> int:
        return len(self.seq) + len(self.name)

    def add_decoded(self, d: Decoded, seq: int) -> int:
        """One frame decoded the general way; its value rows (its Updates with a text)."""
        self.seq.append(seq)
        self.number.append(d.number)
        self.ts_ns.append(d.ts_ns)
        self.conv.append(d.conv)
        self.raw.append(d.raw)
        self.kind.append(d.kind)
        self.ok.append(d.checksum_ok)
        self.late.append(d.late)
        k = 0
        for u in d.updates:
            if u.text is not None:
                self.name.append(u.name)
                self.text.append(u.text)
                self.type_code.append(u.type_code)
                self.carried.append(u.carried)
                self.changed.append(u.changed)
                k += 1
        self.nvalues.append(k)
        return k

    def add_columns(self, c: DirColumns, base: int, i: int | None = None) -> None:
        """A direction's frames of a batch (``base``: the ordinal before the batch's first), or
        its frame ``i`` alone."""
        n = len(c.number)
        if i is not None:
            at = sum(c.nvalues[:i])
            v = slice(at, at + c.nvalues[i])
            f = slice(i, i + 1)
            n = 1
        else:
            v = f = slice(None)
        self.extend(c, f, v)
        self.seq += [base + 1 + o for o in c.ordinal[f]]
        self.conv += [c.conv] * n
        self.ok += [True] * n


class Batches:
    """The ``Columns`` batches of one capture into their partitions, a direction at a time into
    the partition of its frames' UTC day (frame by frame when a direction's frames cross
    midnight); the highest record number met (``records``)."""

    __slots__ = ("parts", "day_start", "day_end", "day", "records")

    def __init__(self, parts: dict[tuple[str, str, str], Part]) -> None:
        self.parts = parts
        self.day_start = self.day_end = 0  # the UTC day of the last direction taken: [start, end) ns
        self.day = ""
        self.records = 0

    def add(self, batch: Columns, base: int, first_ns: int | None, last_ns: int | None
            ) -> tuple[int | None, int | None, int]:
        """Take ``batch`` (``base``: the ordinal of the frame before its first); the capture's
        first and last frame times after it (``first_ns``, ``last_ns``: before it), and the rows
        (frames and values) it added."""
        n = batch.frames
        added = 0
        for c in batch.dirs.values():
            ts = c.ts_ns
            if c.ordinal[0] == 0 and first_ns is None:
                first_ns = ts[0]
            if c.ordinal[-1] == n - 1:
                last_ns = ts[-1]
            if c.number[-1] > self.records:
                self.records = c.number[-1]
            lo, hi = min(ts), max(ts)
            if not (self.day_start <= lo and hi < self.day_end):
                self.day_start = lo - lo % DAY_NS
                self.day_end = self.day_start + DAY_NS
                self.day = day_of(lo)
            _add_columns(self.parts, c, base, self.day if hi < self.day_end else None)
            added += len(ts) + len(c.name)
        return first_ns, last_ns, added


def _add_columns(parts: dict[tuple[str, str, str], Part], c: DirColumns, base: int, day: str | None) -> None:
    """A direction's columns of a batch into the partition of ``day``, made if need be; a batch
    that crosses midnight (``day`` None) frame by frame into the partition of each frame's day."""
    if day is not None:
        part = parts.get((day, c.src, c.dst))
        if part is None:
            part = parts[(day, c.src, c.dst)] = Part(day, c.src, c.dst)
        part.add_columns(c, base)
        return
    for i, tsi in enumerate(c.ts_ns):
        d = day_of(tsi)
        part = parts.get((d, c.src, c.dst))
        if part is None:
            part = parts[(d, c.src, c.dst)] = Part(d, c.src, c.dst)
        part.add_columns(c, base, i)
