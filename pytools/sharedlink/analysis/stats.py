"""Capture statistics: what ``sharedlink stats`` prints (and ``tshark -z sharedlink,stats``
mirrors from the dissector).

One streaming pass over :func:`sharedlink.analysis.decode.iter_decoded`; memory grows with the number of
node pairs and variables, never with the number of frames.

Definitions (the Lua tap ``dissector/sharedlink_stats.lua`` counts the same way):

* frames per kind and per node pair ``"B>A"`` (from B to A), bytes of the frames (CR LF
  included); a ``[:`` that starts no well-formed frame is a frame of kind ``malformed`` under the
  pair its header names, noise is never a frame (docs/fields-sharedlink.md, "Counts"; the core
  gives each as a ``Decoded``: :mod:`sharedlink.analysis.malformed`);
* checksum failures: frames whose checksum field does not match their bytes (their values are
  not used, see :mod:`sharedlink.analysis.decode`); frames with no checksum field are counted apart;
* per variable (and node pair): ``count`` values carried in frames with a good checksum (a
  value left out and carried forward is not counted), ``changes``, numeric ``min``/``max``,
  and the ``last`` value as written;
* sync: ``late`` frames as the dissector's ``sharedlink.sync.late`` expert (frames with a bad
  checksum included, as Expert Information and the tap count them); ``gaps``: full sets
  further apart than the sync interval plus the slack, and the longest such interval;
* compression: bytes of the value frames (full and delta) against the bytes the same frames
  would take as full sets in the same form; ``ratio`` = sent / full.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from sharedlink.analysis.decode import DATA_KINDS, NS, SYNC_SLACK_S, Counted, Decoded, Decoder
from sharedlink.analysis.health import Health, feed_counted, feed_decoded, health_dict, health_table
from sharedlink.analysis.malformed import PIECE, other_protocol, talk_key, unframed_pieces
from sharedlink.analysis.robot_health import feed_session
from sharedlink.analysis.robot_stats import RobotStats, robot_tables
from sharedlink.analysis.robots import ROBOT_PROTOCOLS, RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import CaptureError
from sharedlink.capture.serial_format import GIVEN_UP
from sharedlink.capture.stream import StreamFrame
from sharedlink.present import COUNT, DURATION, PROSE, REAL, TEXT, VALUE, Column, Table, plain
from sharedlink.present import formats as fmt
from sharedlink.present.formats import one_line as one_line  # (its home is present: tables escape every cell)
from sharedlink.protocols.codec import TYPE_DOUBLE, guess_value, typed_value
from sharedlink.protocols.limits import LimitCounts
from sharedlink.protocols.state import BEACON_VARIABLES, Update, VariableTable


@dataclass
class VarStats:
    pair: str
    name: str
    type_code: int | None = None
    count: int = 0
    changes: int = 0
    min: float | None = None
    max: float | None = None
    last: str | None = None
    last_frame: int | None = None

    @property
    def last_value(self) -> int | float | str | None:
        if self.last is None:
            return None
        return guess_value(self.last) if self.type_code is None else typed_value(self.type_code, self.last)

    def to_dict(self) -> dict:
        return {
            "pair": self.pair,
            "name": self.name,
            "type": self.type_code,
            "count": self.count,
            "changes": self.changes,
            "min": self.min,
            "max": self.max,
            "last": self.last,
            "last_value": self.last_value,
            "last_frame": self.last_frame,
        }


@dataclass
class PairStats:
    pair: str
    frames: int = 0
    bytes: int = 0
    kinds: dict[str, int] = field(default_factory=dict)
    checksum_failures: int = 0
    sync_late: int = 0
    sync_gaps: int = 0
    max_sync_gap_s: float | None = None
    first_ns: int | None = None
    last_ns: int | None = None

    @property
    def rate_hz(self) -> float | None:
        return _rate(self.frames, self.first_ns, self.last_ns)

    def to_dict(self) -> dict:
        src, _, dst = self.pair.partition(">")
        return {
            "pair": self.pair,
            "src": src,
            "dst": dst,
            "frames": self.frames,
            "bytes": self.bytes,
            "rate_hz": self.rate_hz,
            "kinds": dict(sorted(self.kinds.items())),
            "checksum_failures": self.checksum_failures,
            "sync_late": self.sync_late,
            "sync_gaps": self.sync_gaps,
            "max_sync_gap_s": self.max_sync_gap_s,
        }


def _rate(n: int, first: int | None, last: int | None) -> float | None:
    if n < 2 or first is None or last is None or last <= first:
        return None
    return (n - 1) * NS / (last - first)


@dataclass
class CaptureStats:
    path: str = ""
    sync_interval: float = 1.0
    frames: int = 0
    bytes: int = 0
    kinds: dict[str, int] = field(default_factory=dict)
    pairs: dict[str, PairStats] = field(default_factory=dict)
    variables: dict[tuple[str, str], VarStats] = field(default_factory=dict)
    checksum_failures: int = 0
    checksum_missing: int = 0
    sync_late: int = 0
    sync_gaps: int = 0
    noise_segments: int = 0
    noise_bytes: int = 0
    other_records: int = 0  # capture records that are not UDP/TCP over IP
    #: segments of the two related robot protocols on the same ports (P2OS, blackboard): not noise
    other_protocols: dict[str, list[int]] = field(default_factory=dict)  # name -> [segments, bytes]
    value_bytes: int = 0  # bytes of good full/delta frames
    full_bytes: int = 0  # what those frames would take as full sets
    first_ns: int | None = None  # the earliest and the latest frame time (not the first and last
    last_ns: int | None = None  # records: a capture's records need not be in time order)
    error: str | None = None  # the capture is damaged here (everything before it is counted)
    limits: LimitCounts = field(default_factory=LimitCounts)  # input dropped at a bound (limits.py)
    robots: RobotStats = field(default_factory=RobotStats, compare=False)  # P2OS, blackboard (robot_stats.py)
    health: Health = field(default_factory=Health)  # link health (analysis/health.py), fed by add and add_counts
    _full: dict[int, _FullSize] = field(default_factory=dict, repr=False, compare=False)  # per table

    @property
    def duration_s(self) -> float:
        if self.first_ns is None or self.last_ns is None:
            return 0.0
        return (self.last_ns - self.first_ns) / NS

    @property
    def rate_hz(self) -> float | None:
        return _rate(self.frames, self.first_ns, self.last_ns)

    @property
    def compression_ratio(self) -> float | None:
        """Bytes sent / bytes as full sets (1.0: no compression; 0.4: 60 % saved)."""
        return self.value_bytes / self.full_bytes if self.full_bytes else None

    def to_dict(self) -> dict:
        ratio = self.compression_ratio
        return {
            "path": self.path,
            "frames": self.frames,
            "bytes": self.bytes,
            "duration_s": self.duration_s,
            "rate_hz": self.rate_hz,
            "kinds": dict(sorted(self.kinds.items())),
            "checksum_failures": self.checksum_failures,
            "checksum_missing": self.checksum_missing,
            "sync_interval_s": self.sync_interval,
            "sync_late": self.sync_late,
            "sync_gaps": self.sync_gaps,
            "noise_segments": self.noise_segments,
            "noise_bytes": self.noise_bytes,
            "other_records": self.other_records,
            "other_protocols": {k: {"segments": n, "bytes": b} for k, (n, b) in sorted(self.other_protocols.items())},
            "compression": {
                "value_bytes": self.value_bytes,
                "full_bytes": self.full_bytes,
                "ratio": ratio,
                "saving": None if ratio is None else 1.0 - ratio,
            },
            "pairs": [p.to_dict() for _, p in sorted(self.pairs.items())],
            "variables": [v.to_dict() for _, v in sorted(self.variables.items())],
            "limits": self.limits.to_dict(),
            "error": self.error,
            **self.robots.to_dict(),  # "p2os", "blackboard": where present
            **health_dict(self.health.finish_once(self.last_ns)),
        }

    # -- accumulation --------------------------------------------------------------------

    def add(self, d: Decoded) -> None:
        size = len(d.raw)
        ts = d.ts_ns
        kind = d.kind
        feed_decoded(self.health, d)
        self.frames += 1
        self.bytes += size
        kinds = self.kinds
        kinds[kind] = kinds.get(kind, 0) + 1
        # the real time span: records are frames in file order, whatever their time stamps say
        if self.first_ns is None or ts < self.first_ns:
            self.first_ns = ts
        if self.last_ns is None or ts > self.last_ns:
            self.last_ns = ts
        pair = d.pair
        p = self.pairs.get(pair)
        if p is None:
            p = self.pairs[pair] = PairStats(pair, first_ns=ts, last_ns=ts)
        p.frames += 1
        p.bytes += size
        p.kinds[kind] = p.kinds.get(kind, 0) + 1
        if ts < p.first_ns:  # type: ignore[operator]
            p.first_ns = ts
        if ts > p.last_ns:  # type: ignore[operator]
            p.last_ns = ts
        if kind == "malformed":  # no state, no values, never late; a checksum verdict only when wrong
            if d.checksum_ok is False:
                self.checksum_failures += 1
                p.checksum_failures += 1
            return
        if d.late:  # whatever the checksum, as the dissector's expert and its tap count it
            self.sync_late += 1
            p.sync_late += 1
        if d.checksum_ok is False:
            self.checksum_failures += 1
            p.checksum_failures += 1
            return
        if d.checksum_ok is None:
            self.checksum_missing += 1
        if d.sync_gap_ns is not None:
            gap = d.sync_gap_ns / NS
            if gap > self.sync_interval + SYNC_SLACK_S:
                self.sync_gaps += 1
                p.sync_gaps += 1
            if p.max_sync_gap_s is None or gap > p.max_sync_gap_s:
                p.max_sync_gap_s = gap
        self._sizes(d, kind, size)
        self._values(d, pair)

    def _values(self, d: Decoded, pair: str) -> None:
        """:meth:`add`'s per-variable sums of a frame whose checksum is not wrong: each value it
        carries (not one carried forward) counted, its changes, numeric min and max, the last."""
        variables = self.variables
        for u in d.updates:
            if u.carried or u.text is None:
                continue
            v = variables.get((pair, u.name))
            if v is None:
                v = variables[(pair, u.name)] = VarStats(pair, u.name)
            tv = d.table.vars.get(u.name)
            if tv is not None and tv.type_code is not None:
                v.type_code = tv.type_code
            v.count += 1
            v.last, v.last_frame = u.text, d.number
            if not u.changed and v.count > 1:
                continue  # the same value again: min and max stand
            if u.changed:
                v.changes += 1
            x = guess_value(u.text) if v.type_code is None else typed_value(v.type_code, u.text)
            if isinstance(x, (int, float)) and x == x:  # numbers, NaN left out
                xf = float(x)
                if v.min is None or xf < v.min:
                    v.min = xf
                if v.max is None or xf > v.max:
                    v.max = xf


    def _sizes(self, d: Decoded, kind: str, size: int) -> None:
        """:meth:`add`'s size counts of a frame whose checksum is not wrong: the full set of its
        table follows its updates (a declaration starts them all again); a data frame's bytes go
        to ``value_bytes``, those of the full set it stands for to ``full_bytes``."""
        if kind == "declaration":
            self._full.clear()  # lists changed (here or, for L, the other way): sizes again
        full = self._full.get(id(d.table))
        if full is not None and (full.table is not d.table or not full.same(d.table)):
            full = None
            del self._full[id(d.table)]
        if full is not None and kind != "reply":  # a reply's values are shown, never stored (issue 29)
            full.update(d.updates)
        if kind in DATA_KINDS:
            if full is None:
                full = self._full[id(d.table)] = _FullSize(d.table)
            self.value_bytes += size
            self.full_bytes += full.size + (2 if d.raw.endswith(b"\r\n") else 0)

    def add_unframed(self, item: StreamFrame) -> None:
        """Bytes of a record that hold no well-formed frame (a noise :class:`StreamFrame`, as
        :func:`~sharedlink.capture.stream.iter_frames` gives them: the tests' plain path; the
        core cuts them itself, :meth:`~sharedlink.analysis.decode.ReferenceDecoder.unframed`): on
        UDP and TCP each ``[:`` in them is a frame of kind ``malformed``, as sharedlink.lua shows it
        (:func:`~sharedlink.analysis.malformed.unframed_pieces`), the rest noise (CR and LF alone
        are none); on a serial link all noise (serial.lua hands sharedlink.lua only the frames its
        deframer finds)."""
        raw = item.raw
        if item.error == GIVEN_UP:  # an unfinished frame past MAX_HELD_BYTES: given up as noise
            self.limits.held += 1
        serial = item.conv[0] == "serial"
        if serial or item.error == GIVEN_UP or b"[:" not in raw:
            if serial or raw.strip(b"\r\n"):  # (CR and LF alone are no noise to sharedlink.lua)
                self.noise_segments += 1
                self.noise_bytes += len(raw)
            return
        for src, dst, start, end, bad in unframed_pieces(raw):
            if src is None:
                self.noise_segments += 1
                self.noise_bytes += end - start
            else:
                self.add(Decoded(item.number, item.ts_ns, item.conv, raw[start:end], None, "malformed",
                                 False if bad else None, (), _NO_VALUES, False, None, src=src, dst=dst))

    def add_counts(self, batch: Counted) -> None:
        """Frames the decoder's fast path counted (:class:`~sharedlink.analysis.decode.Counted`):
        good full and delta frames in the named form, the same sums as :meth:`add` of each."""
        limit = self.sync_interval + SYNC_SLACK_S
        variables = self.variables
        feed_counted(self.health, batch)
        for c in batch.dirs.values():
            pair = c.pair
            self.frames += c.frames
            self.bytes += c.bytes
            p = self.pairs.get(pair)
            if p is None:
                p = self.pairs[pair] = PairStats(pair, first_ns=c.first_ts, last_ns=c.last_ts)
            p.frames += c.frames
            p.bytes += c.bytes
            for kind, n in (("full", c.full), ("delta", c.frames - c.full)):
                if n:
                    self.kinds[kind] = self.kinds.get(kind, 0) + n
                    p.kinds[kind] = p.kinds.get(kind, 0) + n
            if self.first_ns is None or c.first_ts < self.first_ns:
                self.first_ns = c.first_ts
            if self.last_ns is None or c.last_ts > self.last_ns:
                self.last_ns = c.last_ts
            p.first_ns = min(p.first_ns, c.first_ts)  # type: ignore[type-var]
            p.last_ns = max(p.last_ns, c.last_ts)  # type: ignore[type-var]
            self.sync_late += c.late
            p.sync_late += c.late
            for g in c.gaps:
                gap = g / NS
                if gap > limit:
                    self.sync_gaps += 1
                    p.sync_gaps += 1
                if p.max_sync_gap_s is None or gap > p.max_sync_gap_s:
                    p.max_sync_gap_s = gap
            self.value_bytes += c.bytes
            self.full_bytes += c.full_bytes
            self._full.pop(id(c.table), None)  # its values moved without an add(): size it again
            tvars = c.table.vars
            changed = c.changed
            for name, count in c.counts().items():
                v = variables.get((pair, name))
                if v is None:
                    v = variables[(pair, name)] = VarStats(pair, name)
                tv = tvars[name]
                if tv.type_code is not None:
                    v.type_code = tv.type_code
                v.count += count
                if v.last_frame is None or tv.set_in > v.last_frame:  # type: ignore[operator]
                    v.last, v.last_frame = tv.text, tv.set_in
                texts = changed.get(name)
                if texts:
                    v.changes += len(texts)
                    _min_max(v, set(texts))


#: the characters of a double's text as the protocol writes it (:data:`_DOUBLE_TEXT`)
_NUMBER_CHARS = re.compile(r"[0-9.eE+-]*").fullmatch


def _min_max(v: VarStats, texts: set[str]) -> None:
    """Take ``texts`` (values ``v`` took) into its min and max; numbers only, NaN left out."""
    tc = v.type_code
    # the common case, at C speed: doubles whose texts hold only the characters of the protocol's
    # numbers (one match over them all); float() then takes exactly the texts _DOUBLE_TEXT takes
    # (no space, "_", "inf" or "nan" left for it to read otherwise) and refuses the others
    xs = None
    if tc == TYPE_DOUBLE and _NUMBER_CHARS("".join(texts)):
        try:
            xs = list(map(float, texts))
        except ValueError:
            xs = None
    if xs is not None:
        lo, hi = min(xs), max(xs)
        if v.min is None or lo < v.min:
            v.min = lo
        if v.max is None or hi > v.max:
            v.max = hi
        return
    for text in texts:
        x = guess_value(text) if tc is None else typed_value(tc, text)
        if isinstance(x, (int, float)) and x == x:
            xf = float(x)
            if v.min is None or xf < v.min:
                v.min = xf
            if v.max is None or xf > v.max:
                v.max = xf


class _FullSize:
    """:func:`full_size` of one table (without CR LF), kept up to date from the values good
    frames carry, so a frame costs what it holds and not the direction's whole table; made
    again when the table's names, list or form change."""

    __slots__ = ("table", "stamp", "size", "parts", "counts")

    def __init__(self, table: VariableTable) -> None:
        self.table = table
        self.stamp = self._stamp(table)
        self.size = full_size(table, "", "", False)
        self.parts: dict[str, int] = {}  # named: a variable's bytes; positional: its text's length
        self.counts: dict[str, int] = {}  # positional: the slots a name has in the list
        if table.named is False:
            for name in table.names:
                self.counts[name] = self.counts.get(name, 0) + 1
            self.parts = {n: len(v.text or "") for n, v in table.vars.items() if n in self.counts}
        else:
            self.parts = {n: _named_size(n, v.type_code, v.text) for n, v in table.vars.items() if v.text is not None}

    @staticmethod
    def _stamp(table: VariableTable) -> tuple:
        # new names of a named table come with the values that add them (update); a positional
        # table's size follows its list
        return (len(table.names), table.named) if table.named is False else (table.named,)

    def same(self, table: VariableTable) -> bool:
        return self._stamp(table) == self.stamp

    def update(self, updates: Sequence[Update]) -> None:
        parts = self.parts
        if self.table.named is False:
            counts = self.counts
            for u in updates:
                if not u.carried and u.text is not None and u.name in counts:
                    n = len(u.text)
                    self.size += counts[u.name] * (n - parts.get(u.name, 0))
                    parts[u.name] = n
            return
        vars_ = self.table.vars
        for u in updates:
            if not u.carried and u.text is not None:
                # the variable's type as the table keeps it (a value sent with no T keeps its
                # variable's type: full_size's rule, and the counts mode's)
                v = vars_.get(u.name)
                n = _named_size(u.name, v.type_code if v is not None else u.type_code, u.text)
                self.size += n - parts.get(u.name, 0)
                parts[u.name] = n


def _named_size(name: str, type_code: int | None, text: str | None) -> int:
    """Bytes of one value in a named full set: ``|T t|Q name|D text``."""
    if text is None:
        return 0
    return 4 + len(name) + len(text) + (2 + len(str(type_code)) if type_code is not None else 0)


def full_size(table: VariableTable, dst: str, src: str, crlf: bool = True) -> int:
    """Bytes of a full set of ``table`` 's values in the table's form (named or positional)."""
    n = 7 + 5 + (2 if crlf else 0)  # "[:AB|N0" ... "|CXX]" CR LF
    if table.named is False:
        vars_ = table.vars
        for name in table.names:
            v = vars_.get(name)
            n += 2 + (len(v.text) if v is not None and v.text is not None else 0)
        return n
    for name, v in table.vars.items():
        if v.text is None:
            continue
        n += 4 + len(name) + len(v.text)  # "|Q" name "|D" text
        if v.type_code is not None:
            n += 2 + len(str(v.type_code))
    return n


def capture_stats(
    path: str | Path,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
    progress: Callable[[int, int], None] | None = None,
    outage_after: float | None = None,
) -> CaptureStats:
    """Statistics of one capture (``progress(bytes read, records)`` is called now and then). A damaged file gives the statistics of everything before
    the damage with ``error`` set; a missing or unreadable one raises CaptureError. ``outage_after``:
    link health's fixed outage threshold in seconds (None: learnt from each link's rate)."""
    st = CaptureStats(path=str(path), sync_interval=sync_interval, health=Health(outage_after))
    dec = Decoder(variables, sync_interval, carried=False)  # stats reads only what frames carry
    st.limits = dec.limits
    dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]  # P2OS and blackboard too
    it = dec.capture(path, progress, counts=True)
    talks: dict[tuple, str] = {}  # conversations (both directions) a related protocol was seen on
    try:
        for item in it:
            if isinstance(item, Decoded):
                st.add(item)
            elif isinstance(item, Counted):
                st.add_counts(item)
            elif isinstance(item, tuple):
                st.other_records += 1
            elif type(item) is SessionMessage:
                st.robots.add(item)
                feed_session(st.health, item)  # (P2OS, blackboard links: analysis/robot_health.py)
            elif item.error == PIECE:  # noise beside a malformed frame the core cut
                st.noise_segments += 1
                st.noise_bytes += len(item.raw)
            else:
                key = talk_key(item.conv)
                other = item.error if item.error in ROBOT_PROTOCOLS else other_protocol(item.raw)
                if other is not None:
                    talks[key] = other
                else:  # its binary replies (a blackboard ack or read response) on the same conversation
                    other = talks.get(key)
                if other is not None:
                    counts = st.other_protocols.setdefault(other, [0, 0])
                    counts[0] += 1
                    counts[1] += len(item.raw)
                    continue
                st.add_unframed(item)
    except CaptureError as exc:
        if exc.record is None and st.frames == 0 and st.other_records == 0 and st.noise_segments == 0:
            raise
        st.error = str(exc)
    st.robots.noise(dec.robots.reader.noise)  # type: ignore[attr-defined]
    for name, (n, b) in dec.robots.segments.items():  # type: ignore[attr-defined]  # (claimed: counted there)
        counts = st.other_protocols.setdefault(name, [0, 0])
        counts[0] += n
        counts[1] += b
    st.health.finish_once()  # (the latest frame or robot message)
    return st


#: a malformed frame's table: none (it sets nothing)
_NO_VALUES = VariableTable()


def tables(st: CaptureStats) -> list[Table]:
    """The statistics as :class:`~sharedlink.present.Table` s (raw values, one format per
    kind: :mod:`sharedlink.present.formats`), for terminals and plain text."""
    ratio = st.compression_ratio
    summary = Table(f"SharedLink statistics: {st.path}", [Column("", PROSE), Column("", VALUE)], header=False)
    for row in (
        ["frames", fmt.count(st.frames)],
        ["bytes", fmt.count(st.bytes)],
        ["first frame", fmt.timestamp(st.first_ns)],
        ["last frame", fmt.timestamp(st.last_ns)],
        ["duration", fmt.duration(st.duration_s)],
        ["rate", "" if st.rate_hz is None else f"{fmt.real(st.rate_hz)} Hz"],
        ["checksum failures", fmt.count(st.checksum_failures)],
        ["no checksum", fmt.count(st.checksum_missing)],
        ["sync late frames", fmt.count(st.sync_late)],
        ["late full sets (> %s apart)" % fmt.duration(st.sync_interval + SYNC_SLACK_S), fmt.count(st.sync_gaps)],
        ["compression ratio", "" if ratio is None else "%.3f (%.1f %% saved)" % (ratio, 100 * (1 - ratio))],
        ["noise", f"{fmt.count(st.noise_segments)} segments, {fmt.count(st.noise_bytes)} bytes"],
        ["other records", fmt.count(st.other_records)],
    ):
        summary.add(*row)
    for name, (n, b) in sorted(st.other_protocols.items()):
        summary.add(f"{name} (not SharedLink)", f"{fmt.count(n)} segments, {fmt.count(b)} bytes")
    if st.limits.total:
        summary.add("dropped at limits", ", ".join(f"{k} {fmt.count(n)}" for k, n in st.limits.to_dict().items() if n))
    kinds = Table("Frames per kind", [Column("kind"), Column("frames", COUNT)])
    for k, n in sorted(st.kinds.items()):
        kinds.add(k, n)
    pairs = Table("Frames per node pair", [
        Column("pair"), Column("frames", COUNT), Column("bytes", COUNT, drop=3), Column("rate Hz", REAL, drop=4),
        Column("kinds", PROSE, drop=5), Column("bad checksum", COUNT), Column("sync late", COUNT, drop=1),
        Column("late full sets", COUNT, drop=2), Column("longest full-set interval", DURATION, drop=0)], more="--json has every column")
    for _, p in sorted(st.pairs.items()):
        pairs.add(p.pair, p.frames, p.bytes, p.rate_hz, " ".join(f"{k}={fmt.count(n)}" for k, n in sorted(p.kinds.items())),
                  p.checksum_failures, p.sync_late, p.sync_gaps, p.max_sync_gap_s)
    # the last values: numbers (never cut, right-aligned) when every one is, else text (cut to fit)
    numbers = all(isinstance(v.last_value, (int, float)) for v in st.variables.values())
    variables = Table("Variables", [
        Column("pair", drop=3), Column("name"), Column("count", COUNT), Column("changes", COUNT, drop=1),
        Column("min", VALUE), Column("max", VALUE), Column("last", VALUE if numbers else TEXT, cut=not numbers, drop=2)],
        more="--json has every column")
    for _, v in sorted(st.variables.items()):
        integral = None if v.type_code is None else v.type_code != TYPE_DOUBLE
        variables.add(v.pair, v.name, v.count, v.changes, fmt.value(v.min, integral), fmt.value(v.max, integral),
                      v.last or "")  # (control characters escaped as every table cell)
    if st.frames == 0 and st.robots.packets:  # a P2OS or blackboard capture: no empty SharedLink tables
        summary.title = f"Capture statistics: {st.path}"
        return [summary, *robot_tables(st.robots), *health_table(st.health.finish_once())]
    return [summary, kinds, pairs, variables, *robot_tables(st.robots), *health_table(st.health.finish_once(st.last_ns))]


def render_text(st: CaptureStats) -> str:
    """Plain aligned text of :func:`tables` (what ``stats`` prints on a pipe)."""
    out = "\n".join(plain(t) for t in tables(st))
    if st.error:
        out += f"\ncapture damaged: {st.error}\n"
    return out
