"""``stats`` for P2OS and blackboard links (issue 42): one section per protocol present, from the
:class:`~sharedlink.analysis.sessions.SessionMessage` s the core's robot links give out
(:mod:`sharedlink.analysis.robots`).

P2OS: packets per direction and type (commands by name: 0..2 are SYNC0..SYNC2 until the
conversation's SYNC2 echo, as p2os.lua names them), checksum failures, commands P2OS ignores
(over 200 bytes), payloads that do not decode, the SIP rate and its gaps (an interval over
:data:`SIP_GAP_S`), the pose range and the distance travelled (robot frame, mm, the 16-bit
positions unwrapped), wheel velocities, battery, stall and motor flags, commands per name with
the server packet that answers them where one exists, serial noise (bytes outside any packet).

Blackboard: messages per type and direction (master: set, request; slave: ack, response),
acknowledged sets, repeats (a master message equal to the one still waiting), unanswered
messages (a new message, or the end, came before the answer), answer times, checksum failures.
``packets`` is what tshark counts: every P2OS packet, every blackboard message and answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sharedlink.analysis.sessions import Ack, SessionMessage
from sharedlink.capture.pcapio import NS
from sharedlink.present import COUNT, PROSE, Column, Table
from sharedlink.protocols import blackboard, p2os

#: a SIP interval longer than this is a gap (the robot sends one every 100 ms by default)
SIP_GAP_S = 0.5
#: command name -> the server packet type that answers it
RESPONSES = {"SYNC0": p2os.TYPE_SYNC0, "SYNC1": p2os.TYPE_SYNC1, "SYNC2": p2os.TYPE_SYNC2,
             "CONFIG": p2os.TYPE_CONFIG, "ENCODER": p2os.TYPE_ENCODER}
_SYNC_NAMES = {0: "SYNC0", 1: "SYNC1", 2: "SYNC2"}
_BB_KINDS = {blackboard.SetMessage: "set", blackboard.RequestMessage: "request", Ack: "ack",
             blackboard.ReadResponse: "response"}


def _finite(v: float) -> float | None:
    return v if -math.inf < v < math.inf else None


_INF = float("inf")


@dataclass
class P2osStats:
    packets: int = 0
    bytes: int = 0
    sides: dict[str, int] = field(default_factory=dict)
    checksum_failures: int = 0
    ignored: int = 0
    undecoded: int = 0
    sips: int = 0
    sip_first_ns: int | None = None
    sip_last_ns: int | None = None
    sip_gaps: int = 0
    sip_max_gap_ns: int = 0
    x: list[float] = field(default_factory=lambda: [_INF, -_INF])  # unwrapped, mm
    y: list[float] = field(default_factory=lambda: [_INF, -_INF])
    distance_mm: float = 0.0
    vel: list[float] = field(default_factory=lambda: [_INF, -_INF])  # the mean wheel velocity, mm/s
    vel_sum: float = 0.0
    volts: list[float] = field(default_factory=lambda: [_INF, -_INF])
    volts_first: float | None = None
    volts_last: float | None = None
    stall_left: int = 0
    stall_right: int = 0
    motors_on: int = 0
    moving: int = 0
    commands: dict[str, int] = field(default_factory=dict)
    server_types: dict[int, int] = field(default_factory=dict)
    noise_pieces: int = 0
    noise_bytes: int = 0
    _pose: dict[int, tuple[float, float, int, int]] = field(default_factory=dict, repr=False)  # session -> x, y, raw x, y
    _synced: set = field(default_factory=set, repr=False)  # sessions past their SYNC2 echo

    def add(self, m: SessionMessage) -> None:
        raw = m.raw
        self.packets += 1
        self.bytes += len(raw)
        side = m.side
        sides = self.sides
        sides[side] = sides.get(side, 0) + 1
        if m.ok is False:
            self.checksum_failures += 1
        msg = m.message
        if msg is None:
            self.undecoded += 1
            return
        if side == "client":
            if raw[2] > p2os.MAX_COUNT:
                self.ignored += 1
            num = msg.number  # type: ignore[union-attr]
            if num <= 2 and msg.argtype is None and m.session not in self._synced:  # type: ignore[union-attr]
                name = _SYNC_NAMES[num]
            else:
                name = msg.name  # type: ignore[union-attr]
            cmds = self.commands
            cmds[name] = cmds.get(name, 0) + 1
            return
        t = raw[3]
        st = self.server_types
        st[t] = st.get(t, 0) + 1
        if type(msg) is p2os.Sip:
            self._sip(m.session, m.ts_ns, msg)
        elif t == p2os.TYPE_SYNC2 and type(msg) is p2os.SyncReply and msg.strings:
            self._synced.add(m.session)

    def _sip(self, session: int, ts: int, s: p2os.Sip) -> None:
        self.sips += 1
        last = self.sip_last_ns
        if last is not None:
            gap = ts - last
            if gap > SIP_GAP_S * NS:
                self.sip_gaps += 1
            if gap > self.sip_max_gap_ns:
                self.sip_max_gap_ns = gap
        else:
            self.sip_first_ns = ts
        self.sip_last_ns = ts
        xr, yr = s.xpos, s.ypos
        pose = self._pose.get(session)
        if pose is None:
            x, y = float(xr), float(yr)
        else:  # the 16-bit positions wrap: the shorter way round
            dx = (xr - pose[2] + 0x8000) % 0x10000 - 0x8000
            dy = (yr - pose[3] + 0x8000) % 0x10000 - 0x8000
            x, y = pose[0] + dx, pose[1] + dy
            if dx or dy:
                self.distance_mm += math.hypot(dx, dy)
        self._pose[session] = (x, y, xr, yr)
        r = self.x
        if x < r[0]:
            r[0] = x
        if x > r[1]:
            r[1] = x
        r = self.y
        if y < r[0]:
            r[0] = y
        if y > r[1]:
            r[1] = y
        v = (s.lvel + s.rvel) / 2
        r = self.vel
        if v < r[0]:
            r[0] = v
        if v > r[1]:
            r[1] = v
        self.vel_sum += v
        volts = s.battery / 10
        r = self.volts
        if volts < r[0]:
            r[0] = volts
        if volts > r[1]:
            r[1] = volts
        if self.volts_first is None:
            self.volts_first = volts
        self.volts_last = volts
        sb = s.stall_bumpers
        self.stall_left += sb & 1
        self.stall_right += sb >> 8 & 1
        self.motors_on += s.flags & 1
        self.moving += s.moving

    def types(self) -> list[tuple[str, str, int]]:
        """(side, type, packets): commands by name, server packets by type (SIP for both standard ones)."""
        out = [("client", n, c) for n, c in self.commands.items()]
        server: dict[str, int] = {}
        for t, c in self.server_types.items():
            name = "SIP" if t in (p2os.TYPE_SIP_STOPPED, p2os.TYPE_SIP_MOVING) else p2os.SERVER_TYPES.get(t, "type 0x%02X" % t)
            server[name] = server.get(name, 0) + c
        out += [("robot", n, c) for n, c in server.items()]
        if self.undecoded:
            out.append(("", "(undecoded)", self.undecoded))
        return sorted(out)

    def to_dict(self) -> dict:
        span = (self.sip_last_ns or 0) - (self.sip_first_ns or 0)
        return {
            "packets": self.packets,
            "bytes": self.bytes,
            "by_side": dict(sorted(self.sides.items())),
            "types": [{"side": s, "type": t, "packets": n} for s, t, n in self.types()],
            "checksum_failures": self.checksum_failures,
            "ignored_commands": self.ignored,
            "undecoded": self.undecoded,
            "sip": {
                "count": self.sips,
                "rate_hz": (self.sips - 1) * NS / span if self.sips > 1 and span > 0 else None,
                "gap_threshold_s": SIP_GAP_S,
                "gaps": self.sip_gaps,
                "max_gap_s": self.sip_max_gap_ns / NS if self.sips > 1 else None,
            },
            "pose": {
                "frame": "robot odometry (mm from where the robot started its count; not geographic)",
                "x_min_mm": _finite(self.x[0]), "x_max_mm": _finite(self.x[1]),
                "y_min_mm": _finite(self.y[0]), "y_max_mm": _finite(self.y[1]),
                "distance_mm": round(self.distance_mm, 3),
            },
            "velocity_mm_s": {"min": _finite(self.vel[0]), "max": _finite(self.vel[1]),
                              "mean": self.vel_sum / self.sips if self.sips else None},
            "battery_v": {"first": self.volts_first, "last": self.volts_last, "min": _finite(self.volts[0]),
                          "max": _finite(self.volts[1])},
            "flags": {"stall_left": self.stall_left, "stall_right": self.stall_right, "motors_enabled": self.motors_on,
                      "moving": self.moving},
            "commands": [self._command(n, c) for n, c in sorted(self.commands.items())],
            "serial_noise": {"pieces": self.noise_pieces, "bytes": self.noise_bytes},
        }

    def _command(self, name: str, count: int) -> dict:
        t = RESPONSES.get(name)
        return {"name": name, "count": count, "response": None if t is None else p2os.SERVER_TYPES[t],
                "responses": None if t is None else self.server_types.get(t, 0)}


@dataclass
class BlackboardStats:
    packets: int = 0
    bytes: int = 0
    kinds: dict[tuple[str, str], int] = field(default_factory=dict)
    checksum_failures: int = 0
    acknowledged: int = 0
    answered: int = 0
    repeated: int = 0
    unanswered: int = 0
    answer_ns: list[int] = field(default_factory=list)  # (min, sum, max) kept below
    _pending: dict[int, tuple[bytes, int]] = field(default_factory=dict, repr=False)
    _times: list[float] = field(default_factory=lambda: [math.inf, 0.0, 0.0], repr=False)
    _timed: int = field(default=0, repr=False)  # the answers to a waiting message (the ones timed)

    def add(self, m: SessionMessage) -> None:
        self.packets += 1
        self.bytes += len(m.raw)
        kind = _BB_KINDS.get(type(m.message), "malformed")
        key = (m.side, kind)
        self.kinds[key] = self.kinds.get(key, 0) + 1
        if m.ok is False:
            self.checksum_failures += 1
        if m.message is None:
            return  # a malformed message waits for no answer (docs/fields-p2os-blackboard.md)
        pend = self._pending.get(m.session)
        if m.side == "master":
            if pend is not None:
                self.unanswered += 1
                if pend[0] == m.raw.rstrip(b"\r\n"):
                    self.repeated += 1
            self._pending[m.session] = (m.raw.rstrip(b"\r\n"), m.ts_ns)
            return
        if pend is not None:
            del self._pending[m.session]
            dt = (m.ts_ns - pend[1]) / 1e6
            t = self._times
            t[0] = min(t[0], dt)
            t[1] += dt
            t[2] = max(t[2], dt)
            self._timed += 1
        self.answered += 1
        if kind == "ack" and m.ok:
            self.acknowledged += 1

    def to_dict(self) -> dict:
        t, timed = self._times, self._timed
        unanswered = self.unanswered + len(self._pending)
        return {
            "packets": self.packets,
            "bytes": self.bytes,
            "types": [{"side": s, "type": k, "messages": n} for (s, k), n in sorted(self.kinds.items())],
            "checksum_failures": self.checksum_failures,
            "acknowledged": self.acknowledged,
            "answered": self.answered,
            "repeated": self.repeated,
            "unanswered": unanswered,
            # (timed: an answer to no waiting message counts as answered but has no time)
            "answer_ms": {"min": t[0] if timed else None, "mean": t[1] / timed if timed else None,
                          "max": t[2] if timed else None},
        }


@dataclass
class RobotStats:
    """Both sections; ``to_dict`` only the protocols present."""

    p2os: P2osStats = field(default_factory=P2osStats)
    blackboard: BlackboardStats = field(default_factory=BlackboardStats)

    def add(self, m: SessionMessage) -> None:
        (self.p2os if m.protocol == "p2os" else self.blackboard).add(m)

    @property
    def packets(self) -> int:
        return self.p2os.packets + self.blackboard.packets

    def noise(self, noise: dict[str, list[int]]) -> None:
        """The serial noise the session reader counted (protocol -> [pieces, bytes])."""
        n = noise.get("p2os")
        if n:
            self.p2os.noise_pieces, self.p2os.noise_bytes = n

    def to_dict(self) -> dict:
        out: dict = {}
        if self.p2os.packets:
            out["p2os"] = self.p2os.to_dict()
        if self.blackboard.packets:
            out["blackboard"] = self.blackboard.to_dict()
        return out


def _num(x: float | None, fmt: str = "%.6g") -> str:
    return "" if x is None else fmt % x


def robot_tables(rs: RobotStats) -> list[Table]:
    """The sections as tables (sharedlink.present), after the SharedLink ones: each column of the
    kind its cells are (a names-and-values list's values written as text)."""
    d = rs.to_dict()
    out: list[Table] = []
    p = d.get("p2os")
    if p is not None:
        out.append(_listing("P2OS statistics", _p2os_summary(p)))
        out.append(_typed("P2OS packets per type", [Column("side"), Column("type", PROSE), Column("packets", COUNT, drop=0)],
                          [[t["side"], t["type"], t["packets"]] for t in p["types"]]))
        out.append(_typed("P2OS commands", [Column("command", drop=2), Column("count", COUNT), Column("response", PROSE, drop=1),
                                            Column("responses", COUNT, drop=0)],
                          [[c["name"], c["count"], c["response"], c["responses"]] for c in p["commands"]]))
    b = d.get("blackboard")
    if b is not None:
        a = b["answer_ms"]
        out.append(_listing("Blackboard statistics", [
            ["messages and answers", str(b["packets"])],
            ["bytes", str(b["bytes"])],
            ["checksum failures", str(b["checksum_failures"])],
            ["acknowledged sets", str(b["acknowledged"])],
            ["answered", str(b["answered"])],
            ["repeated", str(b["repeated"])],
            ["unanswered", str(b["unanswered"])],
            ["answer time (ms)", "min %s, mean %s, max %s" % (_num(a["min"], "%.3f"), _num(a["mean"], "%.3f"), _num(a["max"], "%.3f"))],
        ]))
        out.append(_typed("Blackboard messages per type", [Column("side"), Column("type", PROSE),
                                                           Column("messages", COUNT, drop=0)],
                          [[t["side"], t["type"], t["messages"]] for t in b["types"]]))
    return out


def _p2os_summary(p: dict) -> list[list[str]]:
    sip, pose, vel, bat, fl = p["sip"], p["pose"], p["velocity_mm_s"], p["battery_v"], p["flags"]
    return [
        ["packets", "%d (%s)" % (p["packets"], ", ".join(f"{k} {n}" for k, n in p["by_side"].items()))],
        ["bytes", str(p["bytes"])],
        ["checksum failures", str(p["checksum_failures"])],
        ["commands P2OS ignores (> 200 bytes)", str(p["ignored_commands"])],
        ["undecoded payloads", str(p["undecoded"])],
        ["SIPs", "%d, %s Hz" % (sip["count"], _num(sip["rate_hz"], "%.3f"))],
        ["SIP gaps (> %g s)" % SIP_GAP_S, "%d (longest %s s)" % (sip["gaps"], _num(sip["max_gap_s"], "%.3f"))],
        ["x range (mm, robot frame)", "%s .. %s" % (_num(pose["x_min_mm"], "%.0f"), _num(pose["x_max_mm"], "%.0f"))],
        ["y range (mm, robot frame)", "%s .. %s" % (_num(pose["y_min_mm"], "%.0f"), _num(pose["y_max_mm"], "%.0f"))],
        ["distance travelled", "%.0f mm" % pose["distance_mm"]],
        ["velocity (mm/s)", "min %s, mean %s, max %s" % (_num(vel["min"]), _num(vel["mean"], "%.1f"), _num(vel["max"]))],
        ["battery (V)", "first %s, last %s, min %s" % (_num(bat["first"]), _num(bat["last"]), _num(bat["min"]))],
        ["stall left / right", "%d / %d SIPs" % (fl["stall_left"], fl["stall_right"])],
        ["motors enabled / moving", "%d / %d SIPs" % (fl["motors_enabled"], fl["moving"])],
        ["serial noise", "%d pieces, %d bytes" % (p["serial_noise"]["pieces"], p["serial_noise"]["bytes"])],
    ]


def _listing(title: str, rows: list[list[str]]) -> Table:
    """A names-and-values list (no headers; the values written as text)."""
    return _typed(title, [Column(""), Column("", PROSE)], rows, header=False)


def _typed(title: str, columns: list[Column], rows: list[list], header: bool = True) -> Table:
    t = Table(title, columns, more="--json has every column", header=header)
    for r in rows:
        t.add(*r)
    return t
