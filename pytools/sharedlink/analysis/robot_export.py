"""``export`` csv/jsonl rows for P2OS packets and blackboard messages (issue 42): one row per
packet (a blackboard slave's answer is a row too), with a ``protocol`` column and the decoded
fields, units in the column names as the P2OS manual gives them (mm, mm/s, degrees, volts).

Columns (:data:`COLUMNS`; JSON Lines leave out the empty ones)::

    protocol number time ts_ns t session link side type checksum bytes
    command arg                                      (P2OS client commands; arg: int or string)
    x_mm y_mm heading_deg left_velocity_mm_s right_velocity_mm_s velocity_mm_s battery_v
    stall_left stall_right motors_enabled moving compass_deg sonars_mm     (standard SIPs)
    encoder_left encoder_right robot_name robot_class robot_subclass        (ENCODER, SYNC2 echo)
    address node count data                          (blackboard: data as hex)
    error                                            (why a payload did not decode)

``t`` is seconds since the first row of the export; ``x_mm``/``y_mm`` are the SIP's positions
in the robot's odometry frame (16 bits, as sent); ``sonars_mm`` is ``number:range`` pairs
separated by spaces. ``time``: UTC ISO 8601 with nanoseconds, as the SharedLink rows.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
import tempfile
from typing import IO, Any

from sharedlink.analysis.decode import format_time
from sharedlink.analysis.sessions import Ack, SessionMessage
from sharedlink.protocols import blackboard, p2os

COLUMNS = [
    "protocol", "number", "time", "ts_ns", "t", "session", "link", "side", "type", "checksum", "bytes",
    "command", "arg",
    "x_mm", "y_mm", "heading_deg", "left_velocity_mm_s", "right_velocity_mm_s", "velocity_mm_s", "battery_v",
    "stall_left", "stall_right", "motors_enabled", "moving", "compass_deg", "sonars_mm",
    "encoder_left", "encoder_right", "robot_name", "robot_class", "robot_subclass",
    "address", "node", "count", "data",
    "error",
]
_CHECKSUM = {True: "good", False: "bad", None: "none"}
#: rows held before one write
_HELD = 512


def _text(b: bytes) -> str:
    return b.decode("latin-1")


def _p2os_fields(row: dict[str, Any], m: SessionMessage, synced: set[int]) -> None:
    msg = m.message
    if isinstance(msg, p2os.Command):
        sync = msg.number <= 2 and msg.argtype is None and m.session not in synced  # the handshake (p2os.lua)
        row["type"] = row["command"] = f"SYNC{msg.number}" if sync else msg.name
        if isinstance(msg.value, bytes):
            row["arg"] = _text(msg.value)
        elif msg.value is not None:
            row["arg"] = msg.value
    elif isinstance(msg, p2os.Sip):
        row["type"] = "SIP"
        row.update(x_mm=msg.xpos, y_mm=msg.ypos, heading_deg=round(msg.heading_deg, 6), left_velocity_mm_s=msg.lvel,
                   right_velocity_mm_s=msg.rvel, velocity_mm_s=(msg.lvel + msg.rvel) / 2, battery_v=msg.battery / 10,
                   stall_left=msg.stall_bumpers & 1, stall_right=msg.stall_bumpers >> 8 & 1, motors_enabled=msg.flags & 1,
                   moving=int(msg.moving), compass_deg=2 * msg.compass,
                   sonars_mm=" ".join(map("%d:%d".__mod__, msg.sonars)))
    elif isinstance(msg, p2os.Encoder):
        row.update(type="ENCODER", encoder_left=msg.left, encoder_right=msg.right)
    elif isinstance(msg, p2os.SyncReply):
        row["type"] = f"SYNC{msg.number} echo"
        if msg.number == 2 and msg.strings:
            synced.add(m.session)
        for col, s in zip(("robot_name", "robot_class", "robot_subclass"), msg.strings):
            row[col] = _text(s)
    elif msg is not None:
        t = m.raw[3] if len(m.raw) > 3 else -1
        row["type"] = p2os.SERVER_TYPES.get(t, "type 0x%02X" % t)
    else:
        row["type"] = "undecoded"
        row["error"] = m.error


def _blackboard_fields(row: dict[str, Any], m: SessionMessage, _synced: set[int]) -> None:
    msg = m.message
    if isinstance(msg, blackboard.SetMessage):
        row.update(type="set", address=msg.address, node=msg.node, count=len(msg.data), data=msg.data.hex())
    elif isinstance(msg, blackboard.RequestMessage):
        row.update(type="request", address=msg.address, node=msg.node, count=msg.count)
    elif isinstance(msg, Ack):
        row.update(type="ack", data=m.raw.hex())
    elif isinstance(msg, blackboard.ReadResponse):
        row.update(type="response", count=len(msg.data), data=msg.data.hex())
    elif msg is None:
        row.update(type="malformed", error=m.error)
    req = m.request
    if req is not None:
        row["address"], row["node"] = req.address, req.node


class RobotRows:
    """Rows of one export: ``row(m)`` as a dict (the columns a packet has)."""

    def __init__(self) -> None:
        self.t0: int | None = None
        self.rows = 0
        self.synced: set[int] = set()  # P2OS sessions past their SYNC2 echo

    def row(self, m: SessionMessage) -> dict[str, Any]:
        if self.t0 is None:
            self.t0 = m.ts_ns
        row: dict[str, Any] = {
            "protocol": m.protocol, "number": m.number, "time": format_time(m.ts_ns), "ts_ns": m.ts_ns,
            "t": round((m.ts_ns - self.t0) / 1e9, 9), "session": m.session, "link": m.label, "side": m.side,
            "type": None, "checksum": _CHECKSUM[m.ok], "bytes": len(m.raw),
        }
        (_p2os_fields if m.protocol == "p2os" else _blackboard_fields)(row, m, self.synced)
        self.rows += 1
        return row


#: a str as a JSON string (the C function json.dumps uses for one)
_jstr = json.encoder.encode_basestring_ascii  # type: ignore[attr-defined]
_SIP_TAIL = (', "type": "SIP", "checksum": "%s", "bytes": %d, "x_mm": %d, "y_mm": %d, "heading_deg": %r, '
             '"left_velocity_mm_s": %d, "right_velocity_mm_s": %d, "velocity_mm_s": %r, "battery_v": %r, '
             '"stall_left": %d, "stall_right": %d, "motors_enabled": %d, "moving": %d, "compass_deg": %d')
_ENCODER_TAIL = ', "type": "ENCODER", "checksum": "%s", "bytes": %d, "encoder_left": %d, "encoder_right": %d}\n'


class RobotJsonl(RobotRows):
    """JSON Lines, into the SharedLink writer's held lines (``held``, flushed by ``flush``) so
    every line stays in capture order. :meth:`line` is the plain path (the row without its empty
    columns, ``json.dumps``); SIPs and ENCODER packets, most of a session, are formatted
    straight into the same text (tests/analysis/test_robot_export.py compares the two)."""

    def __init__(self, held: list[str], flush: Any) -> None:
        super().__init__()
        self.held, self.flush = held, flush
        self._heads: dict[tuple[int, str], str] = {}  # (session, side) -> its members' text

    def line(self, m: SessionMessage) -> str:
        row = {k: v for k, v in self.row(m).items() if v is not None and v != ""}
        return json.dumps(row, ensure_ascii=True) + "\n"

    def fast_line(self, m: SessionMessage) -> str | None:
        """The line of a SIP or ENCODER packet, or None (another message: :meth:`line`)."""
        msg = m.message
        t = type(msg)
        if t is not p2os.Sip and t is not p2os.Encoder:
            return None
        ts = m.ts_ns
        if self.t0 is None:
            self.t0 = ts
        key = (m.session, m.side)
        head = self._heads.get(key)
        if head is None:
            head = self._heads[key] = ', "session": %d, "link": %s, "side": %s' % (m.session, _jstr(m.label), _jstr(m.side))
        self.rows += 1
        start = '{"protocol": "p2os", "number": %d, "time": "%s", "ts_ns": %d, "t": %r%s' % (
            m.number, format_time(ts), ts, round((ts - self.t0) / 1e9, 9), head)
        if t is p2os.Encoder:
            return start + _ENCODER_TAIL % (_CHECKSUM[m.ok], len(m.raw), msg.left, msg.right)  # type: ignore[union-attr]
        s: p2os.Sip = msg  # type: ignore[assignment]
        sb = s.stall_bumpers
        tail = _SIP_TAIL % (_CHECKSUM[m.ok], len(m.raw), s.xpos, s.ypos, round(s.heading_deg, 6), s.lvel, s.rvel,
                            (s.lvel + s.rvel) / 2, s.battery / 10, sb & 1, sb >> 8 & 1, s.flags & 1, int(s.moving),
                            2 * s.compass)
        if s.sonars:
            tail += ', "sonars_mm": "%s"' % " ".join(map("%d:%d".__mod__, s.sonars))
        return start + tail + "}\n"

    def write(self, m: SessionMessage) -> int:
        held = self.held
        held.append(self.fast_line(m) or self.line(m))
        if len(held) >= _HELD:
            self.flush()
        return 1


class RobotCsv(RobotRows):
    """CSV rows spooled; :meth:`finish` writes the header and them (a capture with no SharedLink
    frame: the whole CSV is this one)."""

    def __init__(self, outages: bool = False) -> None:
        super().__init__()
        self.spool = tempfile.TemporaryFile("w+b")  # noqa: SIM115 (closed in finish/close)
        self.buf = io.StringIO()
        self.w = csv.writer(self.buf, lineterminator="\n")
        self.columns = COLUMNS + (["duration_s"] if outages else [])  # (export --outages: outage rows)

    def write(self, m: SessionMessage) -> int:
        row = self.row(m)
        self.w.writerow(["" if row.get(c) is None else row.get(c) for c in self.columns])
        if self.rows % _HELD == 0:
            self._spill()
        return 1

    def outage(self, o: Any, number: int | None) -> None:
        """A robot link's outage (:class:`~sharedlink.analysis.health.Outage`) as a row of type
        ``outage``: the message that ends it (none when open), its start's time, the link and the
        side that went silent, its ``duration_s``."""
        ts = o.start_ns
        if self.t0 is None:
            self.t0 = ts
        protocol, _, label = o.link.partition(" ")
        row = {"protocol": protocol, "number": number, "time": format_time(ts), "ts_ns": ts,
               "t": round((ts - self.t0) / 1e9, 9), "link": label, "side": o.pair.partition(">")[0], "type": "outage",
               "duration_s": repr(o.duration_ns / 1e9)}
        self.rows += 1
        self.w.writerow(["" if row.get(c) is None else row.get(c) for c in self.columns])

    def _spill(self) -> None:
        self.spool.write(self.buf.getvalue().encode("utf-8"))
        self.buf.seek(0)
        self.buf.truncate()

    def finish(self, out: IO[str]) -> None:
        self._spill()
        self.spool.seek(0)
        csv.writer(out, lineterminator="\n").writerow(self.columns)
        with io.TextIOWrapper(self.spool, encoding="utf-8", newline="") as rows:
            shutil.copyfileobj(rows, out, 1 << 20)

    def close(self) -> None:
        self.spool.close()


#: what a robot track's coordinates are (GeoJSON and KML say so)
FRAME_NOTE = ("robot odometry frame: x, y in metres from the robot's odometry origin (P2OS standard SIP xpos, ypos, "
              "16-bit positions unwrapped); not longitude/latitude")


class RobotTrack:
    """The P2OS odometry track of each session (standard SIPs with a good checksum), for GeoJSON
    (one LineString feature a session) and KML (one Folder a session), in the robot's frame."""

    def __init__(self) -> None:
        self.tracks: dict[int, list[tuple[float, float, int]]] = {}  # session -> (x m, y m, ts_ns)
        self.labels: dict[int, str] = {}
        self._last: dict[int, tuple[int, int, float, float]] = {}  # raw x, y; unwrapped x, y (mm)

    @property
    def points(self) -> int:
        return sum(map(len, self.tracks.values()))

    def write(self, m: SessionMessage) -> int:
        s = m.message
        if type(s) is not p2os.Sip or m.ok is False:
            return 0
        last = self._last.get(m.session)
        if last is None:
            x, y = float(s.xpos), float(s.ypos)
            self.tracks[m.session] = []
            self.labels[m.session] = m.label
        else:
            x = last[2] + (s.xpos - last[0] + 0x8000) % 0x10000 - 0x8000
            y = last[3] + (s.ypos - last[1] + 0x8000) % 0x10000 - 0x8000
        self._last[m.session] = (s.xpos, s.ypos, x, y)
        self.tracks[m.session].append((x / 1000, y / 1000, m.ts_ns))
        return 1

    def geojson(self) -> list[str]:
        """One LineString Feature (as JSON text) a session."""
        out = []
        for session, pts in sorted(self.tracks.items()):
            props = {"track": f"p2os session {session}", "link": self.labels[session], "frame": FRAME_NOTE,
                     "points": len(pts), "start": format_time(pts[0][2]), "end": format_time(pts[-1][2])}
            coords = ", ".join("[%r, %r]" % (x, y) for x, y, _ in pts)
            out.append('{"type": "Feature", "properties": %s, "geometry": {"type": "LineString", "coordinates": [%s]}}'
                       % (json.dumps(props), coords))
        return out

    def kml(self) -> str:
        """One Folder a session: the track, its frame said in the description."""
        from xml.sax.saxutils import escape

        out = []
        for session, pts in sorted(self.tracks.items()):
            out.append("<Folder><name>p2os session %d</name><description>%s (%s)</description>\n"
                       % (session, escape(FRAME_NOTE), escape(self.labels[session])))
            out.append("<Placemark><name>odometry track %d</name><styleUrl>#track</styleUrl>"
                       "<TimeSpan><begin>%s</begin><end>%s</end></TimeSpan><LineString><coordinates>\n"
                       % (session, format_time(pts[0][2]), format_time(pts[-1][2])))
            out.extend("%r,%r,0\n" % (x, y) for x, y, _ in pts)
            out.append("</coordinates></LineString></Placemark>\n</Folder>\n")
        return "".join(out)
