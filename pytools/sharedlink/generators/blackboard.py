"""Generate a blackboard session: a master computer writing and reading blocks of a slave's
blackboard memory, over UDP, TCP or a serial line.

Every 100 ms the master writes its drive setpoints (speed and steering, node 1, address
0x1F00) with a set message; the slave answers with the message's checksum as one byte. Every
250 ms the master requests the slave's status block (0xE000, 5 bytes: cycle counter, battery,
two bumper/sensor bytes, the last speed setpoint it accepted); every 2 s it reads its setpoints
back. The slave answers with the data and a checksum over data and request. Some
acknowledgements are lost (the sixth write's always, others at ``lost_ack``): the master
repeats the message after a 50 ms time-out.

Over a serial line (``transport="serial"``, pcapng with a USER link type, the master's bytes
outbound) every message takes its time on the line (10 bits a byte at ``baud``): the slave
answers only once the message's CR is in, the time-out runs from the end of the message, and
the master waits three character times after an answer before it sends again (the capture's
reader returns a chunk after three idle characters, so a message's last record always comes
before its answer's first).

The same options (seed included) give byte-identical files.
"""

from __future__ import annotations

import random
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from sharedlink.capture.packets import write_session
from sharedlink.capture.pcapio import NS, atomic_open
from sharedlink.generators.beacon import DEFAULT_START_NS
from sharedlink.generators.outages import cut_line
from sharedlink.generators.serial import check_robot_session, write_line_session
from sharedlink.protocols.blackboard import RequestMessage, SetMessage

MS = 1_000_000

SETPOINT_ADDR = 0x1F00
STATUS_ADDR = 0xE000
STATUS_LEN = 5
SLAVE_NODE = 1
MASTER_NODE = 0
RETRY_NS = 50 * MS


@dataclass
class BlackboardGenOptions:
    duration: float = 10.0
    seed: int = 1
    fmt: str = "pcap"
    transport: str = "udp"
    baud: int = 9600  # serial transport
    port: int = 7100  # the slave's port
    master_ip: str = "127.0.0.1"
    slave_ip: str = "127.0.0.1"
    master_port: int = 40100
    lost_ack: float = 0.02  # fraction of acknowledgements lost (besides the sixth)
    start_ns: int = DEFAULT_START_NS
    outages: tuple[tuple[float, float], ...] = ()  # planted silences, both directions (generators/outages.py)

    def validate(self) -> None:
        check_robot_session(self.duration, self.fmt, self.transport, "blackboard", self.outages, ("udp", "tcp", "serial"))
        if self.transport == "serial" and not 50 <= self.baud <= 4_000_000:
            raise ValueError("--baud must be 50..4000000")
        if not 0 < self.port < 65536 or not 0 < self.master_port < 65536:
            raise ValueError("--port must be 1..65535")
        if not 0.0 <= self.lost_ack < 1.0:
            raise ValueError("lost acknowledgement rate must be in [0, 1)")


@dataclass
class BlackboardStats:
    frames: int = 0
    messages: int = 0  # text messages and binary answers
    bytes: int = 0
    kinds: dict[str, int] = field(default_factory=dict)
    silenced: int = 0  # messages not sent in planted outages


def session_messages(opts: BlackboardGenOptions) -> Iterator[tuple[int, bool, bytes, str]]:
    """(timestamp ns, from_master, bytes, kind) in time order."""
    rng = random.Random(opts.seed)
    # time on the line (serial); packets arrive whole (0)
    byte_ns = 10 * NS // opts.baud if opts.transport == "serial" else 0

    def on_line(n: int) -> int:
        return n * byte_ns

    # a serial reader returns when the line has been idle for three characters: the master
    # waits that long after an answer, so the record ending its message comes before the answer's
    turnaround = on_line(3)
    memory = bytearray(0x10000)
    t = opts.start_ns + MS
    end = t + int(opts.duration * NS)
    cycle = 0
    writes = 0
    speed, steer, target = 0, 128, 0
    battery = 132
    next_status = t
    next_readback = t + 2 * NS
    while t < end:
        # drive setpoints: speed ramps to a random target, steering wanders
        if cycle % 30 == 0:
            target = rng.choice((0, 40, 80, 120, 160))
        speed += max(-8, min(8, target - speed))
        steer = max(64, min(192, steer + rng.randint(-6, 6)))
        data = bytes((speed & 0xFF, steer, 1 if speed else 0))
        msg = SetMessage(SETPOINT_ADDR, SLAVE_NODE, data)
        wire = msg.encode()
        writes += 1
        send_t = t
        tries = 0
        while True:
            yield send_t, True, wire, "set" if tries == 0 else "set (repeat)"
            tries += 1
            lost = (writes == 6 and tries == 1) or (tries < 3 and rng.random() < opts.lost_ack)
            if not lost:
                break
            send_t += on_line(len(wire)) + RETRY_NS  # no acknowledgement: repeat after the time-out
        memory[SETPOINT_ADDR : SETPOINT_ADDR + len(data)] = data
        ack_t = send_t + on_line(len(wire)) + rng.randint(1 * MS, 3 * MS)
        yield ack_t, False, msg.ack, "ack"
        t_after = ack_t + on_line(len(msg.ack)) + turnaround + MS
        # the slave's status block changes every cycle
        battery -= 1 if rng.random() < 0.01 else 0
        memory[STATUS_ADDR : STATUS_ADDR + STATUS_LEN] = bytes(
            (cycle & 0xFF, battery & 0xFF, rng.choice((0, 0, 0, 1, 2)), rng.randint(0, 255) & 0xF0, speed & 0xFF)
        )
        reads = []
        if t >= next_status:
            reads.append(RequestMessage(STATUS_ADDR, MASTER_NODE, STATUS_LEN))
            next_status += 250 * MS
        if t >= next_readback:
            reads.append(RequestMessage(SETPOINT_ADDR, MASTER_NODE, len(data)))
            next_readback += 2 * NS
        for req in reads:
            q_t = t_after + rng.randint(2 * MS, 5 * MS)
            qwire = req.encode()
            yield q_t, True, qwire, "request"
            block = bytes(memory[req.address : req.address + req.count])
            r_t = q_t + on_line(len(qwire)) + rng.randint(1 * MS, 3 * MS)
            answer = req.response(block)
            yield r_t, False, answer, "response"
            t_after = r_t + on_line(len(answer)) + turnaround
        cycle += 1
        t = max(t + 100 * MS, t_after + MS)


def generate_blackboard(opts: BlackboardGenOptions, out: BinaryIO) -> BlackboardStats:
    opts.validate()
    stats = BlackboardStats()
    messages, stats.silenced = cut_line(list(session_messages(opts)), opts.outages, opts.start_ns, answers=True)
    for _, _, data, kind in messages:
        stats.messages += 1
        stats.bytes += len(data)
        stats.kinds[kind] = stats.kinds.get(kind, 0) + 1
    if opts.transport == "serial":  # the capture is taken at the master: its messages are outbound
        stats.frames = write_line_session(messages, out, opts.baud, "generated blackboard session", opts.seed)
        return stats
    events = [(ts, from_master, data) for ts, from_master, data, _ in messages]
    master, slave = (opts.master_ip, opts.master_port), (opts.slave_ip, opts.port)
    stats.frames = write_session(out, opts.fmt, events, opts.transport, master, slave)
    return stats


def generate_blackboard_file(opts: BlackboardGenOptions, path: str | Path) -> BlackboardStats:
    with atomic_open(path) as fh:
        return generate_blackboard(opts, fh)
