"""Capture statistics: what ``sharedlink stats`` prints (and ``tshark -z sharedlink,stats``
mirrors from the dissector).

One streaming pass over :func:`sharedlink.analysis.decode.iter_decoded`; memory grows with the number of
node pairs and variables, never with the number of frames.

Definitions (the Lua tap ``dissector/sharedlink_stats.lua`` counts the same way):

* frames per kind and per node pair ``"B>A"`` (from B to A), bytes of the frames (CR LF
  included);
* checksum failures: frames whose checksum field does not match their bytes (their values are
  not used, see :mod:`sharedlink.analysis.decode`); frames with no checksum field are counted apart;
* per variable (and node pair): ``count`` values carried in frames with a good checksum (a
  value left out and carried forward is not counted), ``changes``, numeric ``min``/``max``,
  and the ``last`` value as written;
* sync: ``late`` frames as the dissector's ``sharedlink.sync.late`` expert; ``gaps``: full sets
  further apart than the sync interval plus the slack, and the longest such interval;
* compression: bytes of the value frames (full and delta) against the bytes the same frames
  would take as full sets in the same form; ``ratio`` = sent / full.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from sharedlink.analysis.decode import DATA_KINDS, NS, SYNC_SLACK_S, Decoded, iter_decoded
from sharedlink.capture.pcapio import CaptureError
from sharedlink.protocols.codec import guess_value, typed_value
from sharedlink.protocols.state import BEACON_VARIABLES, VariableTable


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
    value_bytes: int = 0  # bytes of good full/delta frames
    full_bytes: int = 0  # what those frames would take as full sets
    first_ns: int | None = None  # the earliest and the latest frame time (not the first and last
    last_ns: int | None = None  # records: a capture's records need not be in time order)
    error: str | None = None  # the capture is damaged here (everything before it is counted)

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
            "compression": {
                "value_bytes": self.value_bytes,
                "full_bytes": self.full_bytes,
                "ratio": ratio,
                "saving": None if ratio is None else 1.0 - ratio,
            },
            "pairs": [p.to_dict() for _, p in sorted(self.pairs.items())],
            "variables": [v.to_dict() for _, v in sorted(self.variables.items())],
            "error": self.error,
        }

    # -- accumulation --------------------------------------------------------------------

    def add(self, d: Decoded) -> None:
        size = len(d.raw)
        ts = d.ts_ns
        self.frames += 1
        self.bytes += size
        self.kinds[d.kind] = self.kinds.get(d.kind, 0) + 1
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
        p.kinds[d.kind] = p.kinds.get(d.kind, 0) + 1
        if ts < p.first_ns:  # type: ignore[operator]
            p.first_ns = ts
        if ts > p.last_ns:  # type: ignore[operator]
            p.last_ns = ts
        if d.checksum_ok is False:
            self.checksum_failures += 1
            p.checksum_failures += 1
            return
        if d.checksum_ok is None:
            self.checksum_missing += 1
        if d.late:
            self.sync_late += 1
            p.sync_late += 1
        if d.sync_gap_ns is not None:
            gap = d.sync_gap_ns / NS
            if gap > self.sync_interval + SYNC_SLACK_S:
                self.sync_gaps += 1
                p.sync_gaps += 1
            if p.max_sync_gap_s is None or gap > p.max_sync_gap_s:
                p.max_sync_gap_s = gap
        if d.kind in DATA_KINDS:
            self.value_bytes += size
            self.full_bytes += full_size(d.table, d.frame.dst, d.frame.src, d.raw.endswith(b"\r\n"))
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
            if u.changed:
                v.changes += 1
            v.last, v.last_frame = u.text, d.number
            x = guess_value(u.text) if v.type_code is None else typed_value(v.type_code, u.text)
            if isinstance(x, (int, float)) and x == x:  # numbers, NaN left out
                xf = float(x)
                if v.min is None or xf < v.min:
                    v.min = xf
                if v.max is None or xf > v.max:
                    v.max = xf


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
) -> CaptureStats:
    """Statistics of one capture. A damaged file gives the statistics of everything before
    the damage with ``error`` set; a missing or unreadable one raises CaptureError."""
    st = CaptureStats(path=str(path), sync_interval=sync_interval)
    it = iter_decoded(path, variables, sync_interval)
    try:
        for item in it:
            if isinstance(item, Decoded):
                st.add(item)
            elif isinstance(item, tuple):
                st.other_records += 1
            else:
                st.noise_segments += 1
                st.noise_bytes += len(item.raw)
                if item.raw.startswith(b"[:"):  # a frame that is not one: the dissector's "malformed"
                    st.kinds["malformed"] = st.kinds.get("malformed", 0) + 1
    except CaptureError as exc:
        if exc.record is None and st.frames == 0 and st.other_records == 0 and st.noise_segments == 0:
            raise
        st.error = str(exc)
    return st


def tables(st: CaptureStats) -> list[tuple[str, list[str], list[list[str]]]]:
    """The statistics as (title, headers, rows) tables, for terminals and plain text."""

    def num(x: float | None, fmt: str = "%.6g") -> str:
        return "" if x is None else fmt % x

    def whole(x: float | None) -> str:  # as --json has it: every digit
        return "" if x is None else repr(x)

    ratio = st.compression_ratio
    summary = [
        ["frames", str(st.frames)],
        ["bytes", str(st.bytes)],
        ["duration", "%.3f s" % st.duration_s],
        ["rate", num(st.rate_hz, "%.3f Hz")],
        ["checksum failures", str(st.checksum_failures)],
        ["no checksum", str(st.checksum_missing)],
        ["sync late frames", str(st.sync_late)],
        ["sync gaps (> %.3g s)" % (st.sync_interval + SYNC_SLACK_S), str(st.sync_gaps)],
        ["compression ratio", "" if ratio is None else "%.3f (%.1f %% saved)" % (ratio, 100 * (1 - ratio))],
        ["noise", "%d segments, %d bytes" % (st.noise_segments, st.noise_bytes)],
        ["other records", str(st.other_records)],
    ]
    kinds = [[k, str(n)] for k, n in sorted(st.kinds.items())]
    pairs = [
        [
            p.pair,
            str(p.frames),
            str(p.bytes),
            num(p.rate_hz, "%.3f"),
            " ".join(f"{k}={n}" for k, n in sorted(p.kinds.items())),
            str(p.checksum_failures),
            str(p.sync_late),
            str(p.sync_gaps),
            num(p.max_sync_gap_s, "%.3f"),
        ]
        for _, p in sorted(st.pairs.items())
    ]
    variables = [
        [v.pair, v.name, str(v.count), str(v.changes), whole(v.min), whole(v.max), v.last or ""]
        for _, v in sorted(st.variables.items())
    ]
    return [
        (f"SharedLink statistics: {st.path}", ["", ""], summary),
        ("Frames per kind", ["kind", "frames"], kinds),
        (
            "Frames per node pair",
            ["pair", "frames", "bytes", "rate Hz", "kinds", "bad checksum", "sync late", "sync gaps", "max gap s"],
            pairs,
        ),
        ("Variables", ["pair", "name", "count", "changes", "min", "max", "last"], variables),
    ]


def render_text(st: CaptureStats) -> str:
    """Plain aligned text of :func:`tables`."""
    out: list[str] = []
    for title, headers, rows in tables(st):
        out.append(title)
        grid = ([headers] if any(headers) else []) + rows
        if not grid:
            out.append("  (none)")
        widths = [max(len(r[i]) for r in grid) for i in range(len(grid[0]))] if grid else []
        for r in grid:
            out.append("  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
        out.append("")
    if st.error:
        out.append(f"capture damaged: {st.error}")
    return "\n".join(out).rstrip() + "\n"
