"""Compare the data two captures carry: the library behind ``sharedlink diff``.

Each capture is read into a stream of value changes (:mod:`sharedlink.capture.stream`: values carried
forward, lists learnt, positional and named forms alike), the two streams are aligned frame
by frame within each direction (by time within a window, or by sequence), and at every
matched pair the variables either side changed are compared (numbers as numbers when the
type says so). The report says where the data diverge, how stale one side ran, and what the
captures cost in frames and bytes.

It streams: memory does not grow with the captures. By default each capture is read in its
own process (:mod:`.diff_reader`); the parent aligns. When both sides carry equal change
records for a run of frames (the common case, e.g. a full stream against its compressed form)
the run is accepted with a few list comparisons instead of frame by frame.
"""

from __future__ import annotations

import gc
import math
from array import array
from collections import Counter, deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from statistics import median

from sharedlink.analysis.changes import read_changes
from sharedlink.analysis.diff_reader import read_remote, sparse_collector
from sharedlink.analysis.diff_reader import worker as _worker  # noqa: F401 - tests run the reader as diff._worker
from sharedlink.capture.stream import (
    Chunk,
    SideStats,
    key_label,
    parse_record,
    unescape,
    unpack_ts,
)
from sharedlink.protocols.codec import TYPE_DOUBLE, TYPE_LONG
from sharedlink.protocols.state import BEACON_VARIABLES

DEFAULT_WINDOW_NS = 100_000_000  # when the frame period cannot be measured
_FIRST_UNMATCHED = 5  # unmatched frames listed per side: the lowest frame numbers, in order
#: --by sequence: frames of a direction waiting for the other side's; beyond this many the
#: oldest are declared unmatched, so memory stays flat when a direction is on one side only
MAX_WAITING = 100_000


@dataclass
class DiffOptions:
    by: str = "time"  # "time" (within window) or "sequence"
    window_ms: float | None = None  # None: half the frame period, measured
    tolerance: float = 0.0  # for doubles
    sync_interval: float = 1.0  # seconds, for "sync intervals missed"
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES
    parallel: bool = True  # read each capture in its own process
    fast: bool = True  # the stream reader's fast path (False: general path only)
    bulk: bool = True  # the aligner's bulk tier, equal runs at once (False: frame by frame only)

    def validate(self) -> None:
        if self.by not in ("time", "sequence"):
            raise ValueError("--by must be time or sequence")
        if self.window_ms is not None and not (self.window_ms >= 0 and math.isfinite(self.window_ms)):
            raise ValueError("--window must be a non-negative number of milliseconds")
        if not (self.tolerance >= 0 and math.isfinite(self.tolerance)):
            raise ValueError("--tolerance must be a non-negative number")
        if not (self.sync_interval > 0 and math.isfinite(self.sync_interval)):
            raise ValueError("--sync-interval must be positive")


@dataclass
class Divergence:
    """Where a variable first differs: the matched frames and both values."""

    a_frame: int
    a_time_ns: int
    a_value: str | None
    b_frame: int
    b_time_ns: int
    b_value: str | None


@dataclass
class Staleness:
    """The longest time the two sides disagreed on a variable before agreeing again."""

    ms: float
    from_a_frame: int
    from_b_frame: int
    to_a_frame: int | None  # None: never caught up before the end
    to_b_frame: int | None
    late: str  # the side that lagged ("a" or "b"; "" when both sides changed to different values)


@dataclass
class VariableReport:
    stream: str  # "B>A": from B to A
    name: str
    type: int | None
    present: str  # "both", "a" or "b"
    samples: int  # matched frame pairs compared (from the variable's first value on)
    mismatches: int  # of those, how many disagreed
    first_divergence: Divergence | None = None
    worst_staleness: Staleness | None = None

    @property
    def agree(self) -> bool:
        return self.present == "both" and self.mismatches == 0


@dataclass
class UnmatchedFrame:
    frame: int
    time_ns: int
    stream: str


@dataclass
class DiffReport:
    a: SideStats
    b: SideStats
    by: str
    window_ms: float
    tolerance: float
    pairs: int = 0  # matched frame pairs
    unmatched_a: int = 0
    unmatched_b: int = 0
    first_unmatched_a: list[UnmatchedFrame] = field(default_factory=list)
    first_unmatched_b: list[UnmatchedFrame] = field(default_factory=list)
    variables: list[VariableReport] = field(default_factory=list)

    @property
    def errors(self) -> list[str]:
        return [s.error for s in (self.a, self.b) if s.error]

    @property
    def agree(self) -> bool:
        return not self.errors and not self.unmatched_a and not self.unmatched_b and all(v.agree for v in self.variables)

    @property
    def only_a(self) -> list[VariableReport]:
        return [v for v in self.variables if v.present == "a"]

    @property
    def only_b(self) -> list[VariableReport]:
        return [v for v in self.variables if v.present == "b"]

    @staticmethod
    def _saving(a: int, b: int) -> float | None:
        return None if a == 0 else 1.0 - b / a

    @property
    def saving_payload(self) -> float | None:
        """What B saves against A in SharedLink bytes (0.6 = B is 60% smaller)."""
        return self._saving(self.a.payload_bytes, self.b.payload_bytes)

    @property
    def saving_wire(self) -> float | None:
        """The same in captured bytes (headers included)."""
        return self._saving(self.a.wire_bytes, self.b.wire_bytes)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["agree"] = self.agree
        d["errors"] = self.errors
        d["saving_payload"] = self.saving_payload
        d["saving_wire"] = self.saving_wire
        d["only_a"] = [v.name for v in self.only_a]
        d["only_b"] = [v.name for v in self.only_b]
        for v in d["variables"]:
            v["agree"] = v["present"] == "both" and v["mismatches"] == 0
        return d


# -- reading the two sides (in a process each: diff_reader) ----------------------------------


def _source(path: str, opts: DiffOptions) -> Iterator[Chunk | SideStats]:
    if opts.parallel:
        return read_remote(path, opts.variables, opts.sync_interval, opts.fast)
    return read_changes(path, opts.variables, opts.sync_interval, opts.fast)


class _Side:
    """One capture's frames as they arrive: a buffer of the current chunk(s) and the values
    as of ``cur_pos`` (frames the fast path accepted are applied lazily)."""

    def __init__(self, index: int, source: Iterator[Chunk | SideStats],
                 on_chunk: Callable[[], None] | None = None) -> None:
        self.index = index
        self.on_chunk = on_chunk  # called after each chunk taken (progress)
        self.read = 0  # bytes of the capture its reader had read at the last chunk
        self.bit = 1 << index
        self.source = source
        self.ts = array("Q")  # packed timestamps (stream.pack_ts)
        self.num = array("q")
        self.recs: list[bytes] = []
        self.start = self.pos = self.end = 0
        self.done = False
        self.stats: SideStats | None = None
        self.events: deque = deque()
        self.snapshot: tuple[int, list] | None = None
        self.cur: dict[tuple[bytes, bytes], bytes] = {}
        self.cur_pos = 0
        self.last_ts = -(1 << 62)
        self.disordered = False  # a frame was stamped before the one read before it
        self.keys: set[bytes] = set()
        self.queues: dict[bytes, deque] = {}

    @property
    def has(self) -> bool:
        return self.pos < self.end

    @property
    def exhausted(self) -> bool:
        return self.done and self.pos >= self.end

    def next_event(self) -> int:
        return self.events[0][0] if self.events else 1 << 62

    def queued(self) -> bool:
        return any(self.queues.values())

    def fetch(self) -> None:
        """Take the next chunk (blocking); first drop what is no longer needed."""
        if self.cur_pos < self.pos:
            snap = self.snapshot
            if snap is not None and snap[0] == self.pos and not self.queued():
                self.cur = {(k, n): v for k, n, v in snap[1]}
                self.cur_pos = self.pos
            else:
                self.replay(self.pos)
        drop = self.cur_pos - self.start
        if drop > 0:
            del self.ts[:drop]
            del self.num[:drop]
            del self.recs[:drop]
            self.start += drop
        try:
            item = next(self.source)
        except StopIteration:
            item = SideStats(error="the reader ended without its statistics")
        if isinstance(item, SideStats):
            self.stats = item
            self.done = True
            if self.on_chunk is not None:
                self.on_chunk()
            return
        self.read = item.read
        self.ts.frombytes(item.ts)
        self.num.frombytes(item.numbers)
        self.recs.extend(item.records)
        self.end = item.start + len(item.records)
        self.events.extend(item.events)
        self.snapshot = (self.end, item.snapshot) if item.snapshot is not None else None
        self.keys.update(item.keys)
        if self.on_chunk is not None:
            self.on_chunk()

    def replay(self, upto: int) -> None:
        """Apply the records from ``cur_pos`` to ``upto`` to the values (no comparisons)."""
        cur = self.cur
        for rec in self.recs[self.cur_pos - self.start : upto - self.start]:
            if len(rec) > 2:
                key, changes = parse_record(rec)
                for name, value in changes:
                    cur[key, name] = value
        self.cur_pos = upto


class _Var:
    __slots__ = (
        "key", "name", "type_a", "type_b", "present", "first_pair", "chg", "bad_since", "bad_ts",
        "bad_from", "mismatches", "first", "worst", "worst_ns",
    )  # fmt: skip

    def __init__(self, key: bytes, name: bytes, first_pair: int) -> None:
        self.key, self.name = key, name
        self.type_a: int | None = None
        self.type_b: int | None = None
        self.present = 0
        self.first_pair = first_pair
        self.chg = 0
        self.bad_since: int | None = None
        self.bad_ts = 0
        self.bad_from: tuple[int, int, str] = (0, 0, "")
        self.mismatches = 0
        self.first: Divergence | None = None
        self.worst: Staleness | None = None
        self.worst_ns = -1

    @property
    def type(self) -> int | None:
        return self.type_a if self.type_a is not None else self.type_b


def values_equal(a: bytes | None, b: bytes | None, type_code: int | None, tolerance: float = 0.0) -> bool:
    """Two values (as in change records) by their type: doubles as floats (within
    ``tolerance``), longs as integers, anything else as text."""
    if a == b:
        return True
    if a is None or b is None:
        return False
    if type_code == TYPE_DOUBLE:
        try:
            x, y = float(a), float(b)
        except ValueError:
            return False
        return x == y or abs(x - y) <= tolerance
    if type_code == TYPE_LONG:
        try:
            return int(a) == int(b)
        except ValueError:
            return False
    return False


def _frame_period(side: _Side) -> int | None:
    """The median time between consecutive frames of a direction, early in the capture."""
    last: dict[bytes, int] = {}
    gaps = []
    n = min(len(side.recs), 4000)
    for i in range(n):
        k = side.recs[i][:2]
        t = unpack_ts(side.ts[i])
        if k in last and t > last[k]:
            gaps.append(t - last[k])
        last[k] = t
    return int(median(gaps)) if gaps else None


def _frame_of(u: UnmatchedFrame) -> int:
    return u.frame


class _Aligner:
    """The reference aligner: takes the two sides' frames one at a time (the earlier first),
    pairs them per direction (within the window, or by order) and compares the values each
    pair leaves. :class:`_BulkAligner` is the same with a bulk tier in front."""

    def __init__(self, a: _Side, b: _Side, opts: DiffOptions) -> None:
        self.sides = (a, b)
        self.opts = opts
        self.by_time = opts.by == "time"
        self.tol = opts.tolerance
        self.window = 0
        self.vars: dict[tuple[bytes, bytes], _Var] = {}
        self.pairs: Counter = Counter()
        self.dirty: dict[bytes, set] = {}
        self.pending: set[bytes] = set()
        self.bad_keys: Counter = Counter()  # key -> variables currently disagreeing
        self.unmatched = [0, 0]
        self.first_unmatched: tuple[list, list] = ([], [])
        #: per side, direction -> [frames still waiting before it starts, variable]
        self.starting: tuple[dict, dict] = ({}, {})
        self.total_pairs = 0
        self.end_ts = 0

    # -- main loop -------------------------------------------------------------------------

    def run(self) -> None:
        self._start()
        while self._refill():
            self._slow_step()
        self._finish()

    def _start(self) -> None:
        """The first chunks, and the window (measured unless given)."""
        a, b = self.sides
        for s in self.sides:
            s.fetch()
        if self.opts.window_ms is not None:
            self.window = int(self.opts.window_ms * 1_000_000)
        else:
            periods = [p for p in (_frame_period(a), _frame_period(b)) if p]
            self.window = min(periods) // 2 if periods else DEFAULT_WINDOW_NS

    def _refill(self) -> bool:
        """Fetch where a side ran dry; False when both sides are done."""
        for s in self.sides:
            while not s.has and not s.done:
                s.fetch()
        return self.sides[0].has or self.sides[1].has

    def _finish(self) -> None:
        for s in self.sides:
            self.end_ts = max(self.end_ts, s.last_ts)
        self._drain(final=True)

    def _slow_step(self) -> None:
        a, b = self.sides
        if self.by_time:
            if a.has and b.has:
                s = a if unpack_ts(a.ts[a.pos - a.start]) <= unpack_ts(b.ts[b.pos - b.start]) else b
            else:
                s = a if a.has else b
        else:
            s = a if a.has and (not b.has or a.pos <= b.pos) else b
        self._read(s)

    def _read(self, s: _Side) -> None:
        if s.cur_pos < s.pos:
            s.replay(s.pos)
        i = s.pos - s.start
        ts, num, rec = unpack_ts(s.ts[i]), s.num[i], s.recs[i]
        s.pos += 1
        s.cur_pos = s.pos
        if ts < s.last_ts:
            s.disordered = True
        s.last_ts = ts
        key = rec[:2]
        while s.events and s.events[0][0] < s.pos:
            _, ek, ename, etype = s.events.popleft()
            waiting = s.queues.get(ek)
            new = (ek, ename) not in self.vars
            v = self._var(ek, ename, self.pairs[ek])
            if new and waiting:
                # it starts with the pair of this frame, after the frames of its direction still
                # waiting on this side, which may yet pair or be given up: _started sets its
                # first pair when the last of them leaves
                self.starting[s.index].setdefault(ek, []).append([len(waiting), v])
            if s.index == 0:
                v.type_a = etype
            else:
                v.type_b = etype
            self.dirty.setdefault(ek, set()).add(v)
        q = s.queues.get(key)
        if q is None:
            q = s.queues[key] = deque()
        q.append((ts, num, rec))
        self.pending.add(key)
        self._match(key)
        self._drain()

    # -- matching --------------------------------------------------------------------------

    def _match(self, key: bytes) -> None:
        a, b = self.sides
        qa, qb = a.queues.get(key), b.queues.get(key)
        w = self.window
        while qa and qb:
            fa, fb = qa[0], qb[0]
            if not self.by_time or abs(fa[0] - fb[0]) <= w:
                qa.popleft()
                qb.popleft()
                self._pair(key, fa, fb)
            elif fa[0] < fb[0]:
                qa.popleft()
                self._unmatched(a, key, fa)
            else:
                qb.popleft()
                self._unmatched(b, key, fb)

    def _drain(self, final: bool = False) -> None:
        """Frames that can no longer find a partner are unmatched."""
        a, b = self.sides
        for key in list(self.pending):
            self._match(key)
            for s, o in ((a, b), (b, a)):
                q, oq = s.queues.get(key), o.queues.get(key)
                while q and not oq:
                    if (
                        final
                        or o.exhausted
                        # the other side is past it in time; only while both sides' times
                        # only went forward (records need not be in time order)
                        or (self.by_time and not (s.disordered or o.disordered) and q[0][0] + self.window < o.last_ts)
                        or len(q) > MAX_WAITING
                    ):
                        self._unmatched(s, key, q.popleft())
                    else:
                        break
            if not a.queues.get(key) and not b.queues.get(key):
                self.pending.discard(key)

    def _apply(self, s: _Side, rec: bytes, touched: set, first_pair: int) -> None:
        if len(rec) <= 2:
            return
        key, changes = parse_record(rec)
        cur, bit = s.cur, s.bit
        for name, value in changes:
            cur[key, name] = value
            v = self.vars.get((key, name))
            if v is None:
                v = self._var(key, name, first_pair)
            v.present |= bit
            v.chg |= bit
            touched.add(v)

    def _var(self, key: bytes, name: bytes, first_pair: int) -> _Var:
        v = self.vars.get((key, name))
        if v is None:
            v = self.vars[key, name] = _Var(key, name, first_pair)
        return v

    def _unmatched(self, s: _Side, key: bytes, f: tuple) -> None:
        self.unmatched[s.index] += 1
        lst = self.first_unmatched[s.index]
        if len(lst) < _FIRST_UNMATCHED or f[1] < lst[-1].frame:
            # frames are found unmatched in no fixed order (per direction, when the other side
            # is past them): keep the lowest frame numbers, so the bulk tier lists the same
            lst.append(UnmatchedFrame(f[1], f[0], key_label(key)))
            lst.sort(key=_frame_of)
            del lst[_FIRST_UNMATCHED:]
        touched = self.dirty.setdefault(key, set())
        self._apply(s, f[2], touched, self.pairs[key])
        if not touched:
            del self.dirty[key]
        if self.starting[s.index]:
            self._started(s.index, key)

    def _started(self, side: int, key: bytes) -> None:
        """A frame of ``key`` left ``side``'s queue (paired or given up): a variable learnt
        behind it starts with the next pair once no frame that was waiting is left."""
        lst = self.starting[side].get(key)
        if not lst:
            return
        for e in lst:
            e[0] -= 1
            if e[0] == 0:
                e[1].first_pair = self.pairs[key]
        lst[:] = [e for e in lst if e[0]]
        if not lst:
            del self.starting[side][key]

    def _pair(self, key: bytes, fa: tuple, fb: tuple) -> None:
        a, b = self.sides
        p = self.pairs[key]
        touched = self.dirty.pop(key, None) or set()
        self._apply(a, fa[2], touched, p)
        self._apply(b, fb[2], touched, p)
        self.pairs[key] = p + 1
        self.total_pairs += 1
        if self.starting[0] or self.starting[1]:
            self._started(0, key)
            self._started(1, key)
        if not touched:
            return
        t = max(fa[0], fb[0])
        ca, cb = a.cur, b.cur
        for v in touched:
            kv = (key, v.name)
            va, vb = ca.get(kv), cb.get(kv)
            if not values_equal(va, vb, v.type, self.tol):
                if v.bad_since is None:
                    # the side that changed moved ahead: the other one is late
                    v.bad_since, v.bad_ts, v.bad_from = p, t, (fa[1], fb[1], {1: "b", 2: "a"}.get(v.chg, ""))
                    self.bad_keys[key] += 1
                    if v.first is None:
                        v.first = Divergence(
                            fa[1], fa[0], None if va is None else unescape(va), fb[1], fb[0], None if vb is None else unescape(vb)
                        )
            elif v.bad_since is not None:
                v.mismatches += p - v.bad_since
                dur = t - v.bad_ts
                if dur > v.worst_ns:
                    v.worst_ns = dur
                    v.worst = Staleness(dur / 1e6, v.bad_from[0], v.bad_from[1], fa[1], fb[1], v.bad_from[2])
                v.bad_since = None
                self.bad_keys[key] -= 1
            v.chg = 0

    # -- the report ------------------------------------------------------------------------

    def report(self) -> DiffReport:
        a, b = self.sides
        r = DiffReport(
            a.stats or SideStats(),
            b.stats or SideStats(),
            self.opts.by,
            self.window / 1e6,
            self.tol,
            self.total_pairs,
            self.unmatched[0],
            self.unmatched[1],
            self.first_unmatched[0],
            self.first_unmatched[1],
        )
        for v in self.vars.values():
            if not v.present:
                continue
            pairs = self.pairs[v.key]
            mism = v.mismatches
            worst = v.worst
            if v.bad_since is not None:
                mism += pairs - v.bad_since
                dur = self.end_ts - v.bad_ts
                if dur > v.worst_ns:
                    worst = Staleness(dur / 1e6, v.bad_from[0], v.bad_from[1], None, None, v.bad_from[2])
            present = "both" if v.present == 3 else ("a" if v.present == 1 else "b")
            r.variables.append(
                VariableReport(
                    key_label(v.key), unescape(v.name), v.type, present, max(0, pairs - v.first_pair), mism, v.first, worst
                )
            )
        return r


class _BulkAligner(_Aligner):
    """The fast tier: where both sides carry equal change records (and equal times, aligning
    by time) for a direction in a quiet state, whole runs of them are accepted at once, without
    pairing or comparing frame by frame: equal records leave equal values, so the reference
    path would find nothing either. The values are caught up lazily (``_Side.replay``). The run
    length adapts (longer after a success, shorter after a miss); everything else is the
    reference path's. Same contract and the same report as :class:`_Aligner`."""

    def run(self) -> None:
        self._start()
        a, b = self.sides
        n_try = 64
        while self._refill():
            if a.has and b.has:
                n = self._try_fast(n_try)
                if n > 0:
                    n_try = min(n_try * 4, 1 << 16)
                    continue
                if n < 0 and n_try > 8:
                    n_try //= 4
                    continue
                n_try = 8
            self._slow_step()
        self._finish()

    def _try_fast(self, n_try: int) -> int:
        """Accept up to ``n_try`` frames at once when both sides carry equal change records
        (and equal times, aligning by time). Returns frames accepted, 0 when not possible
        here, -1 when the run was not equal."""
        a, b = self.sides
        n = min(a.end - a.pos, b.end - b.pos, n_try, a.next_event() - a.pos, b.next_event() - b.pos)
        if n <= 0:
            return 0
        single = len(a.keys) == 1 and a.keys == b.keys
        if single:
            k = next(iter(a.keys))
            if k in self.pending or k in self.dirty or self.bad_keys[k]:
                return 0
        ia, ib = a.pos - a.start, b.pos - b.start
        ra = a.recs[ia : ia + n]
        if ra != b.recs[ib : ib + n]:
            return -1
        if self.by_time and a.ts[ia : ia + n] != b.ts[ib : ib + n]:
            return -1
        if single:
            counts: dict[bytes, int] = {k: n}
        else:
            counts = Counter(r[:2] for r in ra)
            for k in counts:
                if k in self.pending or k in self.dirty or self.bad_keys[k]:
                    return 0
        for k, c in counts.items():
            self.pairs[k] += c
        self.total_pairs += n
        a.pos += n
        b.pos += n
        for s, i in ((a, ia), (b, ib)):
            if unpack_ts(s.ts[i]) < s.last_ts:
                s.disordered = True
            s.last_ts = unpack_ts(s.ts[i + n - 1])
        return n


def diff_captures(a: str | Path, b: str | Path, opts: DiffOptions | None = None,
                  progress: Callable[[int, int], None] | None = None) -> DiffReport:
    """Compare captures ``a`` and ``b``. A missing or damaged file is reported in the
    report's ``errors`` (with everything before the damage compared). ``progress(bytes,
    frames)`` is called as each chunk of either capture arrives (some ten thousand frames):
    the bytes both readers had read (about; 0 from a pipe) and the value frames they gave."""
    opts = opts or DiffOptions()
    opts.validate()
    thresholds = gc.get_threshold()
    sparse_collector()  # millions of short-lived objects, and the decoders' cycles: on, seldom
    sources = [_source(str(a), opts), _source(str(b), opts)]
    try:
        aligner = _BulkAligner if opts.bulk else _Aligner
        sides: list[_Side] = []

        def report() -> None:
            if progress is not None:
                progress(sides[0].read + sides[1].read, sides[0].end + sides[1].end)

        sides += [_Side(0, sources[0], report), _Side(1, sources[1], report)]
        al = aligner(sides[0], sides[1], opts)
        al.run()
        return al.report()
    finally:
        for src in sources:
            close = getattr(src, "close", None)
            if close is not None:
                close()
        gc.set_threshold(*thresholds)
