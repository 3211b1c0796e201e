"""The counts sink (``stats``): the frames the fast tiers take summed per direction, no per-frame object.

:meth:`CountsSink.count` takes a datagram the fast path matches; :meth:`CountsSink.count_run` a run
of a classic pcap block's records of one direction (:class:`~sharedlink.analysis.core.lanes.ColLane`),
its values summed per variable at C speed. What they gather comes out as :class:`Counted` batches
(:meth:`CountsSink.take_batch`), the tables written back once a batch or run.
"""

from __future__ import annotations

from itertools import compress, repeat
from operator import is_not, mul, ne, sub
from typing import NamedTuple

from sharedlink.analysis.core.direction import Direction, Layout, full_set, is_late, named_size, write_back
from sharedlink.analysis.core.lanes import BATCH_FRAMES, ColLane, lane_at, walk_run


class DirCounts:
    """Counts only: what :meth:`Decoder.count` took of one direction's frames since the last
    batch (every one a good full or delta frame in the named form). ``layouts``: layout ->
    [frames, number and time of the last one] (of the frames :meth:`Decoder.count` took);
    ``held``: name -> values carried in the frames :meth:`Decoder.count_run` took; ``changed``:
    name -> the texts it changed to, in order; ``gaps``: the sync gaps of its full frames (ns);
    ``size``: the bytes of a full set's values now; ``stamps``: its frames' times in capture
    order (link health, analysis/health.py)."""

    __slots__ = ("conv", "src", "dst", "table", "first_ts", "last_ts", "frames", "bytes", "full", "late", "gaps",
                 "full_bytes", "layouts", "held", "changed", "size", "last_full", "stamps")

    def __init__(self, conv: tuple, src: str, dst: str, h: Direction, ts: int, size: int) -> None:
        self.conv, self.src, self.dst, self.table = conv, src, dst, h.table
        self.first_ts = self.last_ts = ts
        self.frames = self.bytes = self.full = self.late = self.full_bytes = 0
        self.gaps: list[int] = []
        self.layouts: dict[Layout, list[int]] = {}
        self.held: dict[str, int] = {}
        self.changed: dict[str, list[str]] = {}
        self.size = size
        self.last_full: tuple[int, int] | None = None
        self.stamps: list[int] = []

    @property
    def pair(self) -> str:
        return f"{self.src}>{self.dst}"

    def counts(self) -> dict[str, int]:
        """Values carried per name (each frame of a layout carries all its names)."""
        out = dict(self.held)
        for lay, (n, _number, _ts) in self.layouts.items():
            for name in lay.names:
                out[name] = out.get(name, 0) + n
        return out


class Counted(NamedTuple):
    """Counts only (:meth:`Decoder.capture` with ``counts``): the frames the fast path took since
    the previous item, per direction. It comes before the next item of any other kind, so
    callers see everything in capture order."""

    dirs: dict[tuple, DirCounts]


class CountsSink:
    """The counts mode of :class:`~sharedlink.analysis.core.decoder.Decoder` (its attributes are
    the Decoder's: ``batch``, what :meth:`count` and :meth:`count_run` took, per direction)."""

    _hot: dict[tuple, Direction]
    _lanes: dict[bytes, ColLane]
    batch: dict[Direction, DirCounts]
    fast: int
    late_ns: int

    def count(self, number: int, ts: int, conv: tuple, raw: bytes) -> bool:
        """Counts only: take a datagram the fast path takes into :attr:`batch` (no
        :class:`Decoded`, no Updates) and return True; False when it is not one (decode it).
        Per value only a comparison; what every value of a layout shares (its count, the frame
        that last carried it) is kept per layout and written to the table by :meth:`take_batch`,
        which the caller calls before anything else is decoded."""
        found = self._match(conv, raw)
        if found is None:
            return False
        h, lay, src, dst, values = found
        c = self.batch.get(h)  # (by direction: one Direction each)
        if c is None:
            c = self.batch[h] = DirCounts(conv, src, dst, h, ts, self._hot_size(h))
        vars_ = h.table.vars
        size = c.size
        for name, dval in zip(lay.names, values):
            v = vars_[name]
            text = dval[1:]
            old = v.text
            if old != text:
                texts = c.changed.get(name)
                if texts is None:
                    texts = c.changed[name] = []
                texts.append(text)
                size += len(text) - len(old) if old is not None else named_size(name, v.type_code, text)
                v.text = text
        c.size = size
        seen = c.layouts.get(lay)
        if seen is None:
            c.layouts[lay] = [1, number, ts]
        else:
            seen[0] += 1
            seen[1], seen[2] = number, ts
        c.frames += 1
        c.stamps.append(ts)
        c.bytes += len(raw)
        if ts > c.last_ts:
            c.last_ts = ts
        elif ts < c.first_ts:
            c.first_ts = ts
        c.full_bytes += size + 14  # "[:AB|N0" ... "|CXX]" CR LF around the values
        if lay.full_at != h.version:
            lay.full_at = h.version
            sent = h.table.sent_names
            lay.settle(sent, (len(vars_), len(sent)))
        if lay.full:
            c.full += 1
            c.last_full = number, ts
            gap = full_set(h.sync, ts)
            if gap is not None:
                c.gaps.append(gap)
        elif is_late(h.sync, ts, self.late_ns):
            c.late += 1
        return True

    def take_batch(self) -> dict[tuple, DirCounts]:
        """What :meth:`count` gathered since the last call (then empty), the tables brought up
        to date (which frame last set each value, the last full set, the form)."""
        b = {(c.conv, c.src, c.dst): c for c in self.batch.values()}
        self.batch = {}
        for c in b.values():
            write_back(c.table, ((lay, number, ts) for lay, (_n, number, ts) in c.layouts.items()), c.last_full)
            self.fast += c.frames
        return b

    def count_run(self, buf: bytes, sbuf: str, off: int, number: int, mult: int) -> tuple[int, int, int, int] | None:
        """Counts only: take a run of a classic little-endian pcap block's Ethernet records into
        :attr:`batch` (arguments and result as :meth:`column_run`: the same records, the same
        :class:`ColLane` pattern, at most :data:`BATCH_FRAMES` a run), the sums
        :meth:`count` makes of each frame. A frame costs one struct call, one match, its
        checksum and its sync clock; its values are kept as the match's groups and summed per
        variable once a run, at C speed (how many, which changed, to what, and the full-set size after each
        frame). The texts, the frames that last set them and the sync state are written to the
        table at the end of the run."""
        lane = lane_at(self._hot, self._lanes, buf, off)
        if lane is None:
            return None
        h = lane.h
        vs = lane.vs
        nv = len(vs)
        cur = [v.text for v in vs]
        unvalued = [i for i in range(nv) if cur[i] is None]  # (a frame giving one a value: not taken)
        off, groups, stamps, _raws, wire = walk_run(lane, buf, sbuf, off, BATCH_FRAMES, mult, unvalued)
        n = len(groups)
        if not n:
            return None
        c = self.batch.get(h)
        if c is None:
            c = self.batch[h] = DirCounts(lane.conv, lane.src, lane.dst, h, stamps[0], self._hot_size(h))
        # a full set holds every variable with a value (every sent name): its groups' Nones are
        # the variables without one (and a direction with no value has no full set)
        last_full = _run_clock(c, h.sync, groups, stamps, len(unvalued) if len(unvalued) < nv else -1, self.late_ns)
        first = number + 1  # the run's records are numbered first, first + 1, ...
        number += n
        c.frames += n
        c.stamps += stamps
        c.bytes += wire - 42 * n  # (the frames: the records less their Ethernet, IP and UDP headers)
        lo, hi = min(stamps), max(stamps)
        if lo < c.first_ts:
            c.first_ts = lo
        if hi > c.last_ts:
            c.last_ts = hi
        _run_values(c, vs, cur, groups, stamps, first)
        if last_full >= 0:
            c.last_full = first + last_full, stamps[last_full]
        h.last.clear()  # (the Updates kept for reuse hold values the run replaced)
        return off, number, n, wire

    @staticmethod
    def _hot_size(h: Direction) -> int:
        """Bytes of the values of a full set of the direction (named form, without the frame's
        13 bytes and CR LF): :func:`sharedlink.analysis.stats.full_size`'s rule."""
        return sum(named_size(n, v.type_code, v.text) for n, v in h.table.vars.items())


def _run_clock(c: DirCounts, sync: list, groups: list[tuple], stamps: list[int], full_nones: int, late_ns: int) -> int:
    """The sync clock over a run of :meth:`CountsSink.count_run` (a frame whose groups hold
    ``full_nones`` Nones is a full set): the full sets, gaps and late frames into ``c``; returns
    the index of the run's last full set (-1: none)."""
    gaps: list[int] = []
    late = nfull = 0
    # (the Nones of each frame's groups counted at C speed, the clock walked after the run)
    nones = list(map(tuple.count, groups, repeat(None)))
    for k, ts in zip(nones, stamps):
        if k == full_nones:
            gap = full_set(sync, ts)
            if gap is not None:
                gaps.append(gap)
            nfull += 1
        elif is_late(sync, ts, late_ns):
            late += 1
    c.full += nfull
    c.late += late
    c.gaps += gaps
    return len(nones) - 1 - nones[::-1].index(full_nones) if nfull else -1


def _run_values(c: DirCounts, vs: list, cur: list, groups: list[tuple], stamps: list[int], first: int) -> None:
    """The values of a run of :meth:`CountsSink.count_run` summed per variable into ``c`` (how
    many, which changed, to what, the full-set sizes), each variable's text and the frame that
    last set it written back."""
    n = len(groups)
    nv = len(vs)
    # per variable, over the run's frames: where it is present, its values, which of them
    # changed it; the full-set size after frame j is the size before the run plus the
    # length changes at frames <= j, so the run's sum of sizes takes each change
    # (n - where it happened) times
    size = c.size
    full_bytes = n * (size + 14)  # "[:AB|N0" ... "|CXX]" CR LF around the values
    held, changed = c.held, c.changed
    frames = range(n)
    for i, col in enumerate(zip(*groups)):
        if i == nv:
            break  # (the checksums)
        present = list(map(is_not, col, repeat(None)))
        at = list(compress(frames, present))
        if not at:
            continue
        v = vs[i]
        name = v.name
        vals = list(compress(col, present))
        held[name] = held.get(name, 0) + len(vals)
        old = cur[i]
        moved = list(map(ne, vals, [old, *vals[:-1]]))
        if True in moved:
            texts = list(compress(vals, moved))
            lens = list(map(len, texts))
            full_bytes += sum(map(mul, map(sub, lens, [len(old), *lens[:-1]]),  # type: ignore[arg-type]
                                  map(sub, repeat(n), compress(at, moved))))
            size += lens[-1] - len(old)  # type: ignore[arg-type]
            known = changed.get(name)
            if known is None:
                changed[name] = texts
            else:
                known += texts
            v.text = texts[-1]
        j = at[-1]
        v.set_in, v.set_at = first + j, stamps[j]
    c.size = size
    c.full_bytes += full_bytes
