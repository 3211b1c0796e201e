"""``watch`` of P2OS and blackboard links (issue 42): the terminal view's robot panel and the
``--json`` lines of their packets.

:class:`RobotView` takes the :class:`~sharedlink.analysis.sessions.SessionMessage` s a watch
source hands out (``session_outputs`` of :func:`sharedlink.watch.run_watch`) and keeps, per
session, what a person driving a Pioneer or a blackboard post office looks at: packets per
type, checksum failures, the last SIP (pose in the robot's odometry frame, wheel velocities,
battery, stall and motor flags) and its age, the last command; blackboard messages per type,
unanswered ones. ``--json`` writes each packet as ``export --format jsonl`` does
(:class:`~sharedlink.analysis.robot_export.RobotJsonl`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedlink.analysis.robot_export import RobotRows
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import NS


@dataclass
class _Session:
    protocol: str
    label: str
    types: dict[str, int] = field(default_factory=dict)
    packets: int = 0
    bad: int = 0
    last: dict[str, Any] = field(default_factory=dict)  # the last SIP's row (p2os)
    last_ns: int | None = None
    command: str = ""
    waiting: int = 0  # blackboard: master messages without an answer yet


class RobotView:
    """The robot panel of ``watch`` (see the module doc)."""

    def __init__(self, outage_after: float | None = None) -> None:
        from sharedlink.analysis.health import Health

        self.rows = RobotRows()
        self.sessions: dict[tuple[int, str], _Session] = {}
        self.health = Health(outage_after, timeline=True)  # the robot links' health (robot_health.py): quality, LINK DOWN

    def update(self, m: SessionMessage) -> None:
        from sharedlink.analysis.robot_health import feed_session

        feed_session(self.health, m)
        row = self.rows.row(m)
        key = (m.session, m.protocol)  # (a serial line may carry P2OS one way, blackboard the other)
        s = self.sessions.get(key)
        if s is None:
            s = self.sessions[key] = _Session(m.protocol, m.label)
        s.packets += 1
        s.bad += m.ok is False
        kind = f"{m.side} {row['type']}"
        s.types[kind] = s.types.get(kind, 0) + 1
        if row["type"] == "SIP":
            s.last, s.last_ns = row, m.ts_ns
        elif row.get("command"):
            s.command = f"{row['command']} {row.get('arg', '')}".strip()
        if m.protocol == "blackboard":
            s.waiting = 1 if m.side == "master" else 0

    def lines(self, now_ns: int) -> list[str]:
        out = []
        for (n, _p), s in sorted(self.sessions.items()):
            out.append(f"{s.protocol} session {n} ({s.label}): {s.packets} packets, {s.bad} bad checksums")
            if s.last:
                r = s.last
                age = "" if s.last_ns is None or now_ns < s.last_ns else " (%.1f s ago)" % ((now_ns - s.last_ns) / NS)
                out.append(f"  SIP{age}: x {r['x_mm']} mm, y {r['y_mm']} mm, heading {r['heading_deg']:.1f} deg, "
                           f"wheels {r['left_velocity_mm_s']}/{r['right_velocity_mm_s']} mm/s, battery {r['battery_v']:.1f} V, "
                           f"stall {r['stall_left']}/{r['stall_right']}, motors {'on' if r['motors_enabled'] else 'off'}")
            if s.command:
                out.append(f"  last command: {s.command}")
            if s.protocol == "blackboard" and s.waiting:
                out.append("  waiting for the slave's answer")
            out.append("  " + ", ".join(f"{k} {v}" for k, v in sorted(s.types.items())))
            out += self.link_lines(s, now_ns)
        return out

    def link_lines(self, s: _Session, now_ns: int) -> list[str]:
        """Link health of a session's paced links (the P2OS robot's SIPs, both blackboard sides):
        the link quality (its frames in the last whole second), learnt rate, outages, and while one
        lasts ``LINK DOWN`` and for how long."""
        from sharedlink.analysis.health import live_down_s

        out = []
        conv = ("robot", s.protocol, s.label)
        last = now_ns // NS - 1
        for (c, _side, _), h in sorted(self.health.links.items(), key=lambda kv: kv[1].pair):
            if c != conv:
                continue
            seconds, frames = h.seconds, 0  # (self.health keeps a timeline: never None)
            if seconds is not None:
                seconds.drop_before(last - 60)  # (the last minute is plenty)
                frames = seconds.get(last, 0)
            down = live_down_s(h, now_ns, self.health.fixed_ns)
            rate = h.rate_hz
            line = (f"  link {h.pair}: quality {frames}/s, {'%.1f/s' % rate if rate else '-'} learnt, "
                    f"outages {len(h.outages) + (down is not None)}")
            out.append(line + (f"  LINK DOWN {down:.1f} s" if down is not None else ""))
        return out

    def render(self, now_ns: int) -> Any:
        from rich.text import Text

        return Text("\n".join(self.lines(now_ns)))


#: records :func:`has_robot_traffic` looks at
PROBE_RECORDS = 512


def has_robot_traffic(path: str | Path, records: int = PROBE_RECORDS) -> bool:
    """Whether a capture's first ``records`` records hold a P2OS or blackboard conversation (as
    the core's robot links claim one) or serial records (which may): then ``watch`` reads its
    sessions too. A capture that cannot be read: False (the frames' reader reports it)."""
    from sharedlink.capture.pcapio import CaptureError, read_records

    try:
        for i, rec in enumerate(read_records(path)):
            if i >= records:
                break
            if is_robot_record(rec):
                return True
    except (CaptureError, OSError):
        return False
    return False


def is_robot_record(rec: Any) -> bool:
    """Whether one capture record is what :func:`has_robot_traffic` looks for."""
    from sharedlink.analysis.robots import claim
    from sharedlink.capture.packets import decode_packet
    from sharedlink.capture.serial_format import USER_LINKTYPES

    if rec.linktype in USER_LINKTYPES:
        return True
    dg = decode_packet(rec.linktype, rec.data)
    return dg is not None and claim(dg.proto, dg.sport, dg.dport, dg.payload) is not None


def with_robots(batches: Iterator[Any], robots: Any) -> Iterator[Any]:
    """A live UDP source's batches (``watch --port``) with the datagrams of P2OS and blackboard
    conversations (claimed by ``robots``, a :class:`~sharedlink.analysis.robots.RobotLinks` in
    messages mode) replaced by their :class:`SessionMessage` s: the robot panel and JSON lines."""
    udp = robots.udp
    for batch in batches:
        out: list[Any] = []
        for item in batch:
            got = udp(item.number, item.ts_ns, item.conv, item.data)
            if got is None:
                out.append(item)
            else:
                out += got
        yield out
