"""Generate a P2OS session: a client connecting to a Pioneer robot (the MobileSim simulator on
TCP port 8101) and driving it around a room.

The session: SYNC0/SYNC1/SYNC2 handshake (each echoed, the SYNC2 echo carrying the robot's
name, class and subclass), OPEN, a CONFIG request and its answer, ENCODER packets requested,
SETA/SETRA accelerations, ENABLE 1, a SAY (string argument), then velocity commands (VEL, RVEL)
from a simple reactive driver: cruise at a seeded random speed, turn away when the front sonar
sees a wall, and PULSE when nothing else was sent for a second. The robot answers every 100 ms
(its SIP cycle) with a standard SIP tracing the motion those commands cause: velocities ramp
with the set accelerations, the pose integrates them, the sonar readings are ray distances to
the room's walls, the battery slowly drains. At the end: VEL 0, RVEL 0, STOP, CLOSE, TCP FIN.

The same options (seed included) give byte-identical files.
"""

from __future__ import annotations

import math
import random
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from sharedlink.capture.packets import write_session
from sharedlink.capture.pcapio import NS, atomic_open
from sharedlink.generators.beacon import DEFAULT_START_NS
from sharedlink.generators.outages import cut_line
from sharedlink.generators.serial import check_robot_session, write_line_session
from sharedlink.protocols.p2os import (
    MOBILESIM_PORT,
    Config,
    Encoder,
    Sip,
    SyncReply,
    build_packet,
    command,
)

MS = 1_000_000

SIP_CYCLE_NS = 100 * MS
ROOM_W, ROOM_H = 10_000.0, 8_000.0  # mm
START_X, START_Y = 5_000.0, 4_000.0
AXLE_MM = 330.0  # wheel separation (P3-DX)
TICKS_PER_MM = 66.0
SONAR_MAX = 5_000
#: P3-DX sonar ring angles (degrees, counter-clockwise from straight ahead)
SONAR_ANGLES = (90, 50, 30, 10, -10, -30, -50, -90, -90, -130, -150, -170, 170, 150, 130, 90)
REAR_PER_SIP = 4


@dataclass
class P2osGenOptions:
    duration: float = 30.0  # seconds of driving
    seed: int = 1
    fmt: str = "pcap"
    transport: str = "tcp"
    baud: int = 9600  # serial transport
    port: int = MOBILESIM_PORT
    client_ip: str = "127.0.0.1"
    server_ip: str = "127.0.0.1"
    client_port: int = 45678
    start_ns: int = DEFAULT_START_NS
    robot_name: str = "MobileSim"
    robot_class: str = "Pioneer"
    robot_subclass: str = "p3dx-sh"
    outages: tuple[tuple[float, float], ...] = ()  # planted silences, both directions (generators/outages.py)

    def validate(self) -> None:
        check_robot_session(self.duration, self.fmt, self.transport, "P2OS", self.outages)
        if not 0 < self.port < 65536 or not 0 < self.client_port < 65536:
            raise ValueError("--port must be 1..65535")


@dataclass
class P2osStats:
    frames: int = 0  # link-layer frames written (TCP control segments included)
    packets: int = 0  # P2OS packets
    bytes: int = 0  # P2OS bytes
    kinds: dict[str, int] = field(default_factory=dict)
    silenced: int = 0  # packets not sent in planted outages


@dataclass
class _Robot:
    """The simulated robot: pose, commanded and actual velocities, limits."""

    x: float = START_X
    y: float = START_Y
    th: float = 0.0  # degrees
    v: float = 0.0  # mm/s
    w: float = 0.0  # deg/s
    v_cmd: float = 0.0
    w_cmd: float = 0.0
    accel: float = 300.0  # mm/s^2
    decel: float = 300.0
    raccel: float = 100.0  # deg/s^2
    enabled: bool = False
    left_ticks: float = 0.0
    right_ticks: float = 0.0
    battery: float = 130.0  # 0.1 V

    def step(self, dt: float) -> None:
        if not self.enabled:
            self.v_cmd = self.w_cmd = 0.0
        dv = self.v_cmd - self.v
        lim = (self.accel if abs(self.v_cmd) > abs(self.v) else self.decel) * dt
        self.v += max(-lim, min(lim, dv))
        dw = self.w_cmd - self.w
        rlim = self.raccel * dt
        self.w += max(-rlim, min(rlim, dw))
        mid = math.radians(self.th + self.w * dt / 2)
        self.x += self.v * dt * math.cos(mid)
        self.y += self.v * dt * math.sin(mid)
        self.th = (self.th + self.w * dt + 180.0) % 360.0 - 180.0
        lv, rv = self.wheels()
        self.left_ticks += lv * dt * TICKS_PER_MM
        self.right_ticks += rv * dt * TICKS_PER_MM
        self.battery -= dt * (0.002 + 0.00002 * abs(self.v))

    def wheels(self) -> tuple[float, float]:
        d = math.radians(self.w) * AXLE_MM / 2
        return self.v - d, self.v + d

    def sonar(self, num: int) -> int:
        """Distance (mm) from the robot along sonar ``num``'s axis to the room's walls."""
        a = math.radians(self.th + SONAR_ANGLES[num])
        c, s = math.cos(a), math.sin(a)
        best = float(SONAR_MAX)
        if c > 1e-9:
            best = min(best, (ROOM_W - self.x) / c)
        elif c < -1e-9:
            best = min(best, -self.x / c)
        if s > 1e-9:
            best = min(best, (ROOM_H - self.y) / s)
        elif s < -1e-9:
            best = min(best, -self.y / s)
        return int(max(0.0, min(best, SONAR_MAX)))


def _thpos(deg: float) -> int:
    u = int(round(deg / 360.0 * 4096.0))
    return (u + 2048) % 4096 - 2048


def _clamp16(v: float) -> int:
    return max(-32768, min(32767, int(round(v))))


#: one packet of the session: (timestamp ns, from_client, P2OS packet, kind)
Event = tuple[int, bool, bytes, str]


def session_packets(opts: P2osGenOptions) -> Iterator[Event]:
    """(timestamp ns, from_client, P2OS packet, kind) in time order: the handshake, then the
    drive one SIP cycle at a time until the client closes the connection."""
    rng = random.Random(opts.seed)
    t = yield from _handshake(opts, opts.start_ns + MS)
    yield from _Drive(opts, rng, t).run()


def _command(name: str, arg: int | bytes | None = None) -> bytes:
    return build_packet(command(name, arg).encode())


def _handshake(opts: P2osGenOptions, t: int) -> Generator[Event, None, int]:
    """SYNC0..2 (each echoed about a millisecond later), OPEN, CONFIG and the robot's CONFIG
    packet; returns the time the drive starts."""
    name = opts.robot_name.encode("latin-1", "replace")
    cls = opts.robot_class.encode("latin-1", "replace")
    sub = opts.robot_subclass.encode("latin-1", "replace")
    for n in range(3):
        yield t, True, build_packet(bytes((n,))), f"SYNC{n}"
        strings = (name, cls, sub) if n == 2 else ()
        yield t + 900_000, False, build_packet(SyncReply(n, strings).encode()), f"SYNC{n} echo"
        t += 3 * MS
    yield t, True, _command("OPEN"), "OPEN"
    t += 5 * MS
    yield t, True, _command("CONFIG"), "CONFIG"
    config = Config(
        (
            ("robot_type", cls), ("subtype", sub), ("serial", b"SIM"), ("four_mots", 0), ("rotvel_top", 300),
            ("transvel_top", 2200), ("rotaccel_top", 300), ("transaccel_top", 1000), ("pwm_max", 1000),
            ("name", name), ("sip_cycle", 100), ("host_baud", 0), ("aux_baud", 0), ("gripper", 0),
            ("front_sonar", 1), ("rear_sonar", 1), ("low_battery", 110), ("revcount", 16570), ("watchdog", 5000),
        )
    )
    yield t + MS, False, build_packet(config.encode()), "CONFIG"
    return t + 5 * MS


class _Drive:
    """The session after the handshake: each SIP cycle, the client's queued commands due
    before it, the robot's SIP (and ENCODER packet), then the client's reaction to it."""

    def __init__(self, opts: P2osGenOptions, rng: random.Random, t: int) -> None:
        self.rng = rng
        self.robot = _Robot()
        # client commands queued as (time, name, arg); applied to the robot when sent
        self.queue: list[tuple[int, str, int | bytes | None]] = [
            (t, "ENCODER", 2),
            (t + 5 * MS, "SETA", 300),
            (t + 10 * MS, "SETA", -400),
            (t + 15 * MS, "SETRA", 100),
            (t + 20 * MS, "SONAR", 1),
            (t + 200 * MS, "ENABLE", 1),
            (t + 210 * MS, "SAY", bytes((5, 60, 5, 64, 10, 67))),
        ]
        first_sip = opts.start_ns + SIP_CYCLE_NS * ((t - opts.start_ns) // SIP_CYCLE_NS + 1)
        self.end = first_sip + int(opts.duration * NS)
        self.encoders = False
        self.last_sent = t
        self.sonar_next = 0
        self.mode = "start"  # start, cruise, turn, stop
        self.mode_until = first_sip + NS
        self.cruise_v = 300
        self.sip_t = first_sip
        self.sim_t = t
        self.closing = False
        self.closed = False

    def run(self) -> Iterator[Event]:
        while True:
            yield from self._send_due()
            if self.closed:
                return
            self._simulate(self.sip_t)
            sonars = yield from self._robot_packets()
            react = self.sip_t + 5 * MS + self.rng.randint(0, 2 * MS)  # the client reacts about 5 ms after the SIP
            sent = self._react(react, sonars)
            if not sent and not self.queue and self.sip_t - self.last_sent >= NS:
                self.queue.append((react, "PULSE", None))
            self.sip_t += SIP_CYCLE_NS

    def _simulate(self, until: int) -> None:
        """Step the robot in 10 ms steps up to ``until``."""
        while self.sim_t + 10 * MS <= until:
            self.robot.step(0.01)
            self.sim_t += 10 * MS

    def _send_due(self) -> Iterator[Event]:
        """The queued commands due before the next SIP, each applied to the robot."""
        queue = self.queue
        queue.sort(key=lambda q: q[0])
        while queue and queue[0][0] < self.sip_t:
            qt, qname, qarg = queue.pop(0)
            self._simulate(qt)
            yield qt, True, _command(qname, qarg), qname
            self._apply(qname, qarg)
            self.last_sent = qt
            if qname == "CLOSE":
                self.closed = True

    def _apply(self, name: str, arg: int | bytes | None) -> None:
        robot = self.robot
        if name == "ENABLE":
            robot.enabled = bool(arg)
        elif name == "VEL" and isinstance(arg, int):
            robot.v_cmd = float(arg)
        elif name == "RVEL" and isinstance(arg, int):
            robot.w_cmd = float(arg)
        elif name == "STOP":
            robot.v_cmd = robot.w_cmd = 0.0
        elif name == "SETA" and isinstance(arg, int):
            if arg >= 0:
                robot.accel = float(arg or 300)
            else:
                robot.decel = float(-arg)
        elif name == "SETRA" and isinstance(arg, int):
            robot.raccel = float(abs(arg) or 100)
        elif name == "ENCODER" and isinstance(arg, int):
            self.encoders = arg > 0

    def _robot_packets(self) -> Generator[Event, None, list[tuple[int, int]]]:
        """The robot's SIP for this cycle (and its ENCODER packet); returns the sonar readings."""
        robot, sip_t = self.robot, self.sip_t
        lv, rv = robot.wheels()
        # the front ring every cycle, the rear ring a few at a time
        fired = list(range(8)) + [8 + (self.sonar_next + k) % 8 for k in range(REAR_PER_SIP)]
        self.sonar_next = (self.sonar_next + REAR_PER_SIP) % 8
        sonars = [(n, max(0, min(SONAR_MAX, robot.sonar(n) + self.rng.randint(-15, 15)))) for n in fired]
        moving = abs(robot.v) > 0.5 or abs(robot.w) > 0.05
        sip = Sip(
            moving=moving,
            xpos=int(round(robot.x)) & 0xFFFF,
            ypos=int(round(robot.y)) & 0xFFFF,
            thpos=_thpos(robot.th),
            lvel=_clamp16(lv),
            rvel=_clamp16(rv),
            battery=max(0, min(255, int(robot.battery))),
            control=_thpos(robot.th),
            flags=0x0002 | (1 if robot.enabled else 0),
            sonars=tuple(sonars),
        )
        yield sip_t, False, build_packet(sip.encode()), "SIP"
        if self.encoders:
            enc = Encoder(int(robot.left_ticks), int(robot.right_ticks))
            yield sip_t + 200_000, False, build_packet(enc.encode()), "ENCODER"
        return sonars

    def _react(self, react: int, sonars: list[tuple[int, int]]) -> bool:
        """The client's driving decisions after a SIP, queued for ``react``; True if it queued
        a command (closing, turning away from a wall, cruising on)."""
        if self.closing or not self.robot.enabled:
            return False
        rng, queue, sip_t = self.rng, self.queue, self.sip_t
        front = min(r for n, r in sonars if 2 <= n <= 5)
        rear = min(r for n, r in sonars if 10 <= n <= 13 or n > 13)
        mode = self.mode
        if sip_t >= self.end:
            self.closing = True
            queue += [
                (react, "VEL", 0),
                (react + MS, "RVEL", 0),
                (react + 1500 * MS, "STOP", None),
                (react + 1600 * MS, "ENABLE", 0),
                (react + 1700 * MS, "CLOSE", None),
            ]
        elif mode in ("start", "cruise") and front < 1000:
            self.mode, self.mode_until = "turn", sip_t + rng.choice((1500, 2000, 2500)) * MS
            queue[:] = [q for q in queue if q[1] not in ("VEL", "RVEL")]  # plans change
            queue += [(react, "VEL", 100), (react + MS, "RVEL", rng.choice((-40, 40)))]
        elif mode == "turn" and front < 600 and self.robot.v_cmd != 0:
            queue.append((react, "VEL", 0))  # too close: turn on the spot
        elif mode == "turn" and sip_t >= self.mode_until and front > 1500:
            self.mode, self.mode_until = "cruise", sip_t + rng.choice((3, 4, 5, 6)) * NS
            self.cruise_v = rng.choice((200, 300, 400, 500))
            queue += [(react, "RVEL", 0), (react + MS, "VEL", self.cruise_v)]
        elif mode == "start" and sip_t >= self.mode_until:
            self.mode, self.mode_until = "cruise", sip_t + 4 * NS
            queue.append((react, "VEL", self.cruise_v))
        elif mode == "cruise" and sip_t >= self.mode_until:
            self._cruise_change(react, front, rear)
        else:
            return False
        return True

    def _cruise_change(self, react: int, front: int, rear: int) -> None:
        """While cruising, now and then: a new speed, a gentle turn, or a short reverse."""
        rng, queue = self.rng, self.queue
        self.mode_until = self.sip_t + rng.choice((2, 3, 4)) * NS
        r = rng.random()
        if r < 0.4:
            self.cruise_v = rng.choice((150, 250, 350, 450, 600))
            queue.append((react, "VEL", self.cruise_v))
        elif r < 0.8:
            queue.append((react, "RVEL", rng.choice((-20, -10, 10, 20))))
            queue.append((react + rng.choice((1000, 1500)) * MS, "RVEL", 0))
        elif rear > 1500 and front > 1500:
            queue.append((react, "VEL", -self.cruise_v // 2))
            queue.append((react + 1200 * MS, "VEL", self.cruise_v))


def generate_p2os(opts: P2osGenOptions, out: BinaryIO) -> P2osStats:
    """Write the session capture to ``out``."""
    opts.validate()
    stats = P2osStats()
    packets, stats.silenced = cut_line(list(session_packets(opts)), opts.outages, opts.start_ns)
    for _, _, pkt, kind in packets:
        stats.packets += 1
        stats.bytes += len(pkt)
        stats.kinds[kind] = stats.kinds.get(kind, 0) + 1
    if opts.transport == "serial":  # the capture is taken at the client: its commands are outbound
        stats.frames = write_line_session(packets, out, opts.baud, "generated P2OS session", opts.seed)
        return stats
    events: list[tuple[int, bool, bytes]] = []
    for ts, from_client, pkt, _ in packets:
        # a SIP and the ENCODER packet written right after it travel in one TCP segment (over
        # UDP each packet is a datagram of its own)
        if opts.transport == "tcp" and events and not from_client and not events[-1][1] and ts - events[-1][0] < MS:
            prev = events.pop()
            events.append((prev[0], False, prev[2] + pkt))
        else:
            events.append((ts, from_client, pkt))
    events.sort(key=lambda e: e[0])
    client, server = (opts.client_ip, opts.client_port), (opts.server_ip, opts.port)
    stats.frames = write_session(out, opts.fmt, events, opts.transport, client, server)
    return stats


def generate_p2os_file(opts: P2osGenOptions, path: str | Path) -> P2osStats:
    with atomic_open(path) as fh:
        return generate_p2os(opts, fh)
