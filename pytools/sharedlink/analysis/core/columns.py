"""The columns sink (``ingest``, the MCAP export): the frames the fast tiers take as rows
appended to per-column lists, no Update, no Decoded.

:meth:`ColumnsSink.column` takes a datagram the fast path matches; :meth:`ColumnsSink.column_run`
a run of a classic pcap block's records of one direction
(:class:`~sharedlink.analysis.core.lanes.ColLane`). What they gather comes out as :class:`Columns`
batches (:meth:`ColumnsSink.take_columns`), the tables written back once a batch or run.
"""

from __future__ import annotations

from typing import NamedTuple

from sharedlink.analysis.core.direction import Direction, Layout, full_set, is_late, write_back
from sharedlink.analysis.core.lanes import BATCH_FRAMES, ColLane, lane_at, walk_run
from sharedlink.protocols.state import Variable, VariableTable

#: a column batch's per-frame lists, then its per-value-row lists (:class:`ColumnBatch`)
FRAME_COLUMNS = ("number", "ts_ns", "raw", "kind", "late", "nvalues")
VALUE_COLUMNS = ("name", "text", "type_code", "carried", "changed")


class ColumnBatch:
    """Frames and their value rows as per-column lists, the columns a direction's batch
    (:class:`DirColumns`) and an ingest partition (``fleet.parts.Part``) share. Per frame
    (:data:`FRAME_COLUMNS`): ``number`` (its record), ``ts_ns``, ``raw``, ``kind``, ``late`` and
    ``nvalues`` (its value rows); per value row, frame after frame, as the frame's Updates with a
    text would say (:data:`VALUE_COLUMNS`): ``name``, ``text``, ``type_code``, ``carried``,
    ``changed``."""

    __slots__ = FRAME_COLUMNS + VALUE_COLUMNS

    def __init__(self) -> None:
        self.number: list[int] = []
        self.ts_ns: list[int] = []
        self.raw: list[bytes] = []
        self.kind: list[str] = []
        self.late: list[bool] = []
        self.nvalues: list[int] = []
        self.name: list[str] = []
        self.text: list[str] = []
        self.type_code: list[int | None] = []
        self.carried: list[bool] = []
        self.changed: list[bool] = []

    def extend(self, other: ColumnBatch, frames: slice, values: slice) -> None:
        """``other``'s frames ``frames`` and value rows ``values`` (those frames' rows) appended."""
        for col in FRAME_COLUMNS:
            getattr(self, col).extend(getattr(other, col)[frames])
        for col in VALUE_COLUMNS:
            getattr(self, col).extend(getattr(other, col)[values])


class DirColumns(ColumnBatch):
    """Columns only: what :meth:`Decoder.column` took of one direction's frames since the last
    batch (every one a good full or delta frame in the named form), as per-column lists: those
    of :class:`ColumnBatch` (``kind`` "full" or "delta"; the value rows are the values it
    carries in its layout's order, then, when the decoder keeps carried values, the direction's
    other values that have one, in the table's order), and per frame ``ordinal`` (its place
    among the batch's frames, all directions, capture order). The table is as the batch's last
    frame left it."""

    __slots__ = ("conv", "src", "dst", "table", "ordinal", "layouts", "last_full")

    def __init__(self, conv: tuple, src: str, dst: str, table: VariableTable) -> None:
        super().__init__()
        self.conv, self.src, self.dst, self.table = conv, src, dst, table
        self.ordinal: list[int] = []
        self.layouts: dict[Layout, list[int]] = {}  # layout -> [number, time] of its last frame
        self.last_full: tuple[int, int] | None = None

    @property
    def pair(self) -> str:
        return f"{self.src}>{self.dst}"

    def add_values(self, lay: Layout, values: list[str], vars_: dict[str, Variable], present: tuple) -> int:
        """The value rows of a frame of ``lay`` (``values``: its ``D`` fields), the table's texts
        written; returns how many."""
        texts = self.text
        changed = self.changed
        names = lay.names
        for name, dval in zip(names, values):
            text = dval[1:]
            v = vars_[name]
            if v.text != text:
                v.text = text
                changed.append(True)
            else:
                changed.append(False)
            texts.append(text)
        self.name += names
        self.type_code += lay.types
        self.carried += present
        return len(names)

    def add_carried(self, miss: tuple[str, ...], vars_: dict[str, Variable], cols: tuple) -> int:
        """The rows of the values a frame carries (``miss``: the names its layout leaves out, in
        the order they were sent; ``cols``: the layout's :attr:`Layout.cols`); returns how many."""
        texts = self.text
        carried = [vars_[n].text for n in miss]
        if None not in carried:
            self.name += miss
            texts += carried
            self.type_code += cols[2]
            self.carried += cols[3]
            self.changed += cols[4]
            return len(miss)
        k = 0  # (a variable with no value yet: no row)
        for n, text, tc in zip(miss, carried, cols[2]):
            if text is not None:
                self.name.append(n)
                texts.append(text)
                self.type_code.append(tc)
                self.carried.append(True)
                self.changed.append(False)
                k += 1
        return k


class Columns(NamedTuple):
    """Columns only (:meth:`Decoder.capture` with ``columns``): the frames the fast path took
    since the previous item, per direction (``frames`` in all: each direction's ``ordinal`` s
    number them 0 .. frames - 1 in capture order). It comes before the next item of any other
    kind, so callers see everything in capture order."""

    dirs: dict[tuple, DirColumns]
    frames: int


class ColumnsSink:
    """The columns mode of :class:`~sharedlink.analysis.core.decoder.Decoder` (its attributes are
    the Decoder's: ``rows``, what :meth:`column` and :meth:`column_run` took, per direction;
    ``taken``, their frames)."""

    _hot: dict[tuple, Direction]
    _lanes: dict[bytes, ColLane]
    rows: dict[Direction, DirColumns]
    taken: int
    fast: int
    carried: bool
    late_ns: int

    def column(self, number: int, ts: int, conv: tuple, raw: bytes) -> bool:
        """Columns only: take a datagram the fast path takes into :attr:`rows` (its frame and
        value rows appended to its direction's :class:`DirColumns`, no :class:`Decoded`, no
        Updates) and return True; False when it is not one (decode it). The same values as
        :meth:`_fast` gives (the tests compare them); the frames that last set each value and
        the last full set are written to the table by :meth:`take_columns`, which the caller
        calls before anything else is decoded."""
        found = self._match(conv, raw)
        if found is None:
            return False
        h, lay, src, dst, values = found
        c = self.rows.get(h)  # (by direction: one Direction each)
        if c is None:
            c = self.rows[h] = DirColumns(conv, src, dst, h.table)
        vars_ = h.table.vars
        sent = h.table.sent_names
        stamp = (len(vars_), len(sent))
        full = lay.settle(sent, stamp)  # as _fast: what the layout leaves out, and the kind before the frame
        cols = lay.cols
        key = (h.version, stamp)
        if not cols or cols[0] != key:
            miss = lay.missing
            cols = lay.cols = (key, any(n not in sent for n in lay.names), tuple(vars_[n].type_code for n in miss),
                               (True,) * len(miss), (False,) * len(miss), (False,) * len(lay.names))
        if cols[1]:  # a name sent for the first time takes the next index (as _fast)
            for name in lay.names:
                if name not in sent:
                    sent[name] = len(sent)
            lay.stamp = (-1, -1)
        c.ordinal.append(self.taken)
        self.taken += 1
        c.number.append(number)
        c.ts_ns.append(ts)
        c.raw.append(raw)
        k = c.add_values(lay, values, vars_, cols[5])
        if self.carried and lay.missing:
            k += c.add_carried(lay.missing, vars_, cols)
        c.nvalues.append(k)
        seen = c.layouts.get(lay)
        if seen is None:
            c.layouts[lay] = [number, ts]
        else:
            seen[0], seen[1] = number, ts
        if full:
            c.last_full = number, ts
            full_set(h.sync, ts)
            c.kind.append("full")
            c.late.append(False)
        else:
            c.kind.append("delta")
            c.late.append(is_late(h.sync, ts, self.late_ns))
        return True

    def column_run(self, buf: bytes, sbuf: str, off: int, number: int, mult: int) -> tuple[int, int, int, int] | None:
        """Columns only: take a run of a classic little-endian pcap block's Ethernet records
        (``buf`` from ``off``, ``sbuf`` the block as latin-1; ``number``: the last record's
        number; ``mult``: 1 for nanosecond times, 1000 for microseconds) into :attr:`rows`
        while each is a plain IPv4/UDP datagram of one direction holding one frame its
        :class:`ColLane` pattern matches with a right checksum, at most until :attr:`taken`
        reaches :data:`BATCH_FRAMES`. The rows are those :meth:`column` makes (the tests compare
        them with the reference); the texts, the frames that set them and the sync state are
        written to the table at the end of the run. Returns ``(offset, number, frames taken,
        bytes)``, or None when the record at ``off`` is not one (decode it the usual way)."""
        lane = lane_at(self._hot, self._lanes, buf, off)
        if lane is None:
            return None
        h = lane.h
        vs = lane.vs
        cur = [v.text for v in vs]
        rng = range(len(vs))
        unvalued = [i for i in rng if cur[i] is None]  # (a frame giving one a value: not taken)
        ordinal = self.taken
        off, groups, stamps, raws, wire = walk_run(lane, buf, sbuf, off, BATCH_FRAMES - ordinal, mult, unvalued)
        if not groups:
            return None
        c = self.rows.get(h)
        if c is None:
            c = self.rows[h] = DirColumns(lane.conv, lane.src, lane.dst, h.table)
        setn = [v.set_in for v in vs]
        sett = [v.set_at for v in vs]
        last_full = _run_rows(c, lane, (groups, stamps, raws), ordinal, number, cur, (setn, sett),
                              len(vs) - len(unvalued), self.carried, self.late_ns)
        n = len(groups)
        number += n
        self.taken = ordinal + n
        for v, text, sn, st in zip(vs, cur, setn, sett):
            v.text, v.set_in, v.set_at = text, sn, st
        if last_full is not None:
            c.last_full = last_full
        h.last.clear()
        return off, number, n, wire

    def take_columns(self) -> Columns:
        """What :meth:`column` gathered since the last call (then empty), the tables brought up
        to date (which frame last set each value, the last full set, the form)."""
        rows, frames = self.rows, self.taken
        self.rows, self.taken = {}, 0
        dirs = {}
        for h, c in rows.items():
            write_back(c.table, ((lay, number, ts) for lay, (number, ts) in c.layouts.items()), c.last_full)
            h.last.clear()  # (the Updates kept for reuse hold values the batch replaced)
            self.fast += len(c.number)
            dirs[(c.conv, c.src, c.dst)] = c
        return Columns(dirs, frames)



def _run_rows(c: DirColumns, lane: ColLane, run: tuple[list, list, list], ordinal: int, number: int, cur: list,
              setby: tuple[list, list], nvalued: int, carried_rows: bool, late_ns: int) -> tuple[int, int] | None:
    """The rows of a run of :meth:`ColumnsSink.column_run` (``run``: each frame's match groups,
    time and bytes; its frames numbered from ``number + 1``, ordinals from ``ordinal``) appended
    to ``c``, ``cur`` (the texts) and ``setby`` (the frames that set them, and when) kept in
    step; returns the number and time of its last full set (None: none)."""
    names, types, carry = lane.names, lane.types, lane.carry
    setn, sett = setby
    sync = lane.h.sync
    rng = range(len(names))
    o_app, n_app, t_app, r_app, k_app, l_app, v_app = (c.ordinal.append, c.number.append, c.ts_ns.append,
                                                       c.raw.append, c.kind.append, c.late.append, c.nvalues.append)
    nm_app, tx_app, tc_app, ca_app, ch_app = (c.name.append, c.text.append, c.type_code.append,
                                             c.carried.append, c.changed.append)
    last_full = None
    for n, (g, ts, raw) in enumerate(zip(*run), ordinal):
        number += 1
        held = 0
        for i in rng:
            v = g[i]
            if v is None:
                continue
            held += 1
            nm_app(names[i])
            tx_app(v)
            tc_app(types[i])
            ca_app(False)
            ch_app(v != cur[i])
            cur[i] = v
            setn[i] = number
            sett[i] = ts
        o_app(n)
        n_app(number)
        t_app(ts)
        r_app(raw)
        if held == nvalued and held:  # every variable with a value (every sent name): a full set
            v_app(held)
            last_full = number, ts
            full_set(sync, ts)
            k_app("full")
            l_app(False)
            continue
        if carried_rows:
            for i in carry:
                if g[i] is None and cur[i] is not None:
                    nm_app(names[i])
                    tx_app(cur[i])
                    tc_app(types[i])
                    ca_app(True)
                    ch_app(False)
            held = nvalued
        v_app(held)
        k_app("delta")
        l_app(is_late(sync, ts, late_ns))
    return last_full
