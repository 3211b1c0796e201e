"""``diff`` of two P2OS / blackboard captures (issue 42), e.g. a run and its replay: packet by
packet on the decoded fields.

Both captures go through the decoding core's robot links (:mod:`sharedlink.analysis.robots`) in
lockstep; the packets of each (protocol, side) stream are paired in order (the n-th robot
packet of A with the n-th of B) and compared on their decoded fields (the columns ``export``
writes, :mod:`sharedlink.analysis.robot_export`, less the ones that name where and when: record
number, time, session, link). Doubles within ``tolerance`` are equal. The time of each packet
since its capture's first is compared too, reported as the largest shift, never a difference.
Memory: the packets one stream is ahead of the other's, only.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.robot_export import RobotRows
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import CaptureError

#: columns that say where and when, not what
_PLACE = ("number", "time", "ts_ns", "t", "session", "link")
#: differences listed at most
MAX_LISTED = 10


@dataclass
class RobotDiff:
    a: str
    b: str
    packets_a: int = 0
    packets_b: int = 0
    pairs: int = 0
    identical: int = 0
    differing: int = 0
    fields: dict[str, int] = field(default_factory=dict)  # field -> pairs differing in it
    unmatched_a: int = 0
    unmatched_b: int = 0
    max_shift_s: float = 0.0  # the largest difference in time since the first packet
    listed: list[dict[str, Any]] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    @property
    def agree(self) -> bool:
        return not self.differing and not self.unmatched_a and not self.unmatched_b

    def to_dict(self) -> dict[str, Any]:
        return {"a": self.a, "b": self.b, "packets_a": self.packets_a, "packets_b": self.packets_b,
                "pairs": self.pairs, "identical": self.identical, "differing": self.differing,
                "fields": dict(sorted(self.fields.items())), "unmatched_a": self.unmatched_a,
                "unmatched_b": self.unmatched_b, "max_shift_s": self.max_shift_s, "agree": self.agree,
                "differences": self.listed, "errors": self.errors}


def _rows(path: str | Path, errors: list[str]) -> Iterator[dict[str, Any]]:
    dec = Decoder(carried=False)
    dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
    rows = RobotRows()
    try:
        for item in dec.capture(path):
            if type(item) is SessionMessage:
                yield rows.row(item)  # type: ignore[arg-type]
    except CaptureError as exc:
        if exc.record is None and rows.rows == 0:
            raise
        errors.append(str(exc))


def _equal(x: Any, y: Any, tolerance: float) -> bool:
    if isinstance(x, float) and isinstance(y, (int, float)) or isinstance(y, float) and isinstance(x, (int, float)):
        return abs(x - y) <= tolerance
    return x == y


def diff_robots(a: str | Path, b: str | Path, tolerance: float = 0.0) -> RobotDiff:
    """Compare the P2OS and blackboard packets of ``a`` and ``b`` (see the module doc)."""
    r = RobotDiff(str(a), str(b))
    pending: dict[tuple[str, str], tuple[deque, deque]] = {}
    ia, ib = _rows(a, r.errors), _rows(b, r.errors)
    done_a = done_b = False
    while not (done_a and done_b):
        for side in (0, 1):
            if (done_a, done_b)[side]:
                continue
            row = next(ia if side == 0 else ib, None)
            if row is None:
                if side == 0:
                    done_a = True
                else:
                    done_b = True
                continue
            if side == 0:
                r.packets_a += 1
            else:
                r.packets_b += 1
            qs = pending.setdefault((row["protocol"], row["side"]), (deque(), deque()))
            qs[side].append(row)
            if qs[0] and qs[1]:
                _compare(r, qs[0].popleft(), qs[1].popleft(), tolerance)
    for qa, qb in pending.values():
        r.unmatched_a += len(qa)
        r.unmatched_b += len(qb)
    return r


def _compare(r: RobotDiff, x: dict[str, Any], y: dict[str, Any], tolerance: float) -> None:
    r.pairs += 1
    shift = abs(x["t"] - y["t"])
    if shift > r.max_shift_s:
        r.max_shift_s = round(shift, 9)
    names = [k for k in x.keys() | y.keys() if k not in _PLACE and not _equal(x.get(k), y.get(k), tolerance)]
    if not names:
        r.identical += 1
        return
    r.differing += 1
    for n in names:
        r.fields[n] = r.fields.get(n, 0) + 1
    if len(r.listed) < MAX_LISTED:
        r.listed.append({"protocol": x["protocol"], "side": x["side"], "a_frame": x["number"], "b_frame": y["number"],
                         "type": x["type"], "fields": {n: [x.get(n), y.get(n)] for n in sorted(names)}})


def _short(x: Any) -> str:
    text = repr(x)
    return text if len(text) <= 40 else text[:37] + "..."


def render(r: RobotDiff) -> str:
    """The report as plain lines."""
    lines = [
        f"P2OS/blackboard packets: A {r.packets_a:,} ({r.a}), B {r.packets_b:,} ({r.b})",
        f"paired in order per protocol and side: {r.pairs:,}; identical {r.identical:,}, differing {r.differing:,}",
        f"unmatched: A {r.unmatched_a:,}, B {r.unmatched_b:,}; largest time shift {r.max_shift_s:.6f} s",
    ]
    if r.fields:
        lines.append("fields differing: " + ", ".join(f"{k} {n:,}" for k, n in sorted(r.fields.items())))
    for d in r.listed:
        what = "; ".join(f"{k}: {_short(a)} / {_short(b)}" for k, (a, b) in d["fields"].items())
        lines.append(f"  {d['protocol']} {d['side']} {d['type']}: A #{d['a_frame']} / B #{d['b_frame']}: {what}")
    lines.append("AGREE: both captures carry the same P2OS/blackboard packets" if r.agree
                 else "DIVERGE: the P2OS/blackboard packets differ")
    return "\n".join(lines) + "\n"
