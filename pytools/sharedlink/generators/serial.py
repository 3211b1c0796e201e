"""Generate serial captures: a BUL-049 point-to-point SharedLink session over a UART.

Node ``host`` (default A, where the capture is taken) and node ``vehicle`` (default B) each
open with the declaration of their outbound list, then send positional frames at ``rate`` Hz
(with compression: unchanged values elided, a full set every ``sync_interval``); the host
queries a vehicle variable every ``query_interval`` seconds and the vehicle replies. Bytes
from the vehicle are inbound, the host's outbound.

The line is modelled as a UART at ``baud`` (10 bits per byte, 8N1): a frame occupies its line
for ``len * 10 / baud`` seconds, frames queue when the line is busy, and the reader gets the
bytes in chunks of random size (a read also ends when the line goes idle); each record's
timestamp is when its last byte arrived. ``noise`` is the chance that a burst of random bytes
precedes a frame on the line. The same options give the same bytes.
"""

from __future__ import annotations

import random
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from sharedlink.capture.pcapio import atomic_open
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT, USER_LINKTYPES, SerialCaptureWriter
from sharedlink.generators.beacon import DEFAULT_START_NS, NS
from sharedlink.generators.outages import Outages, check_outages, silenced, windows
from sharedlink.generators.scenario import drive_tuples
from sharedlink.protocols.codec import (
    address_node,
    build_fields,
    declaration_fields,
    encode_positional,
    query_fields,
    reply_fields,
)
from sharedlink.protocols.state import BEACON_VARIABLES

#: what the host sends the vehicle (name, type): speed and heading set points
HOST_VARIABLES: tuple[tuple[str, int], ...] = (("CmdSpeed", 2), ("CmdHeading", 2), ("CmdMode", 0))


@dataclass
class SerialGenOptions:
    duration: float = 30.0
    rate: float = 5.0
    baud: int = 9600
    seed: int = 1
    compress: bool = True
    sync_interval: float = 1.0
    query_interval: float = 2.0
    noise: float = 0.0
    max_chunk: int = 32
    host: str = "A"
    vehicle: str = "B"
    linktype: int = 147
    start_ns: int = DEFAULT_START_NS
    outages: tuple[tuple[float, float], ...] = ()  # planted silences of the vehicle (generators/outages.py)

    def validate(self) -> None:
        if self.duration <= 0:
            raise ValueError("--duration must be positive")
        check_outages(self.outages, self.duration)
        if self.rate <= 0:
            raise ValueError("--rate must be positive")
        if self.baud < 300:
            raise ValueError("--baud must be at least 300")
        if self.sync_interval <= 0 or self.query_interval <= 0:
            raise ValueError("--sync-interval must be positive")
        if not 0.0 <= self.noise <= 1.0:
            raise ValueError("--noise must be a rate between 0 and 1")
        if self.max_chunk < 1:
            raise ValueError("--max-chunk must be at least 1")
        for name in ("host", "vehicle"):
            if address_node(getattr(self, name)) is None:
                raise ValueError(f"--{'dst' if name == 'host' else 'src'} must be a node letter A-P")
        if self.host == self.vehicle:
            raise ValueError("the two nodes of a point-to-point link must differ")
        if self.linktype not in USER_LINKTYPES:
            raise ValueError("--linktype must be a USER link type (147..162)")


@dataclass(frozen=True)
class LineFrame:
    """One frame as sent: when it was queued, its direction, bytes and kind."""

    ts_ns: int
    direction: int
    data: bytes
    kind: str


@dataclass
class SerialGenStats:
    frames: int = 0
    records: int = 0
    bytes: int = 0
    noise_bytes: int = 0
    kinds: dict[str, int] = field(default_factory=dict)
    by_direction: dict[str, int] = field(default_factory=dict)


def session_frames(opts: SerialGenOptions) -> Iterator[LineFrame]:
    """Every frame of the session in time order (before line timing and noise), less the
    vehicle's in planted outages (generators/outages.py)."""
    quiet = windows(opts.outages, opts.start_ns)
    for lf in _session_frames(opts):
        if not (quiet and lf.direction == DIR_IN and silenced(lf.ts_ns, quiet)):
            yield lf


def _session_frames(opts: SerialGenOptions) -> Iterator[LineFrame]:
    host, veh = opts.host, opts.vehicle
    t0 = opts.start_ns
    period = round(NS / opts.rate)
    sync_ns = round(opts.sync_interval * NS)
    q_ns = round(opts.query_interval * NS)
    yield LineFrame(t0, DIR_IN, build_fields(declaration_fields(BEACON_VARIABLES), host, veh), "declaration")
    yield LineFrame(t0 + 1, DIR_OUT, build_fields(declaration_fields(HOST_VARIABLES), veh, host), "declaration")
    last_v: list[str | None] = [None] * len(BEACON_VARIABLES)
    last_h: list[str | None] = [None] * len(HOST_VARIABLES)
    sync_v = sync_h = t0
    next_q = t0 + q_ns // 2
    queries = [n for n, _ in BEACON_VARIABLES]
    qi = 0
    count = max(1, int(round(opts.duration * opts.rate)))
    ts = t0
    latest: tuple[str, ...] = ()
    for lat, lon, heading, speed in drive_tuples(opts.seed, count / opts.rate, opts.rate):
        ts += period
        vals = ["%.8f" % lat, "%.8f" % lon, "%.1f" % heading, "%.1f" % speed]
        latest = tuple(vals)
        frame, sync_v, kind = _positional(host, veh, vals, last_v, ts, sync_v, sync_ns, opts.compress)
        yield LineFrame(ts, DIR_IN, frame, kind)
        last_v = list(vals)
        cmd = ["%.1f" % (round(speed / 2.0) * 2.0), "%.0f" % (round(heading / 5.0) * 5.0 % 360), "1"]
        hts = ts + period // 2
        frame, sync_h, kind = _positional(veh, host, cmd, last_h, hts, sync_h, sync_ns, opts.compress)
        yield LineFrame(hts, DIR_OUT, frame, kind)
        last_h = list(cmd)
        if hts >= next_q:
            name = queries[qi % len(queries)]
            yield LineFrame(hts + 1, DIR_OUT, build_fields(query_fields(name), veh, host), "query")
            yield LineFrame(hts + period // 4, DIR_IN, build_fields(reply_fields(name, latest[qi % len(queries)]), host, veh), "reply")
            qi += 1
            next_q += q_ns


def _positional(
    dst: str, src: str, vals: list[str], last: list[str | None], ts: int, sync_at: int, sync_ns: int, compress: bool
) -> tuple[bytes, int, str]:
    if not compress or ts >= sync_at:
        return encode_positional(dst, src, vals), ts + sync_ns, "full"
    texts = [None if v == p else v for v, p in zip(vals, last)]
    return encode_positional(dst, src, texts), sync_at, "delta"


def line_records(opts: SerialGenOptions) -> Iterator[tuple[int, int, bytes]]:
    """(timestamp ns, direction, chunk) as a reader of the line gets them, in time order."""
    return uart_records(session_frames(opts), opts.baud, opts.max_chunk, opts.noise, opts.seed)


def uart_records(
    frames: Iterable[LineFrame], baud: int, max_chunk: int = 32, noise: float = 0.0, seed: int = 1
) -> Iterator[tuple[int, int, bytes]]:
    """Put frames (of any protocol) on a UART at ``baud`` and read them back in chunks:
    (timestamp ns, direction, chunk) in time order."""
    rng = random.Random(seed ^ 0x5E71A1)
    byte_ns = 10 * NS / baud
    # per direction: the byte stream with arrival times (ns) of each byte
    streams: dict[int, tuple[bytearray, list[int]]] = {DIR_IN: (bytearray(), []), DIR_OUT: (bytearray(), [])}
    free: dict[int, int] = {DIR_IN: 0, DIR_OUT: 0}
    for lf in frames:
        data = lf.data
        if noise and rng.random() < noise:
            data = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8))) + data
        buf, times = streams[lf.direction]
        start = max(lf.ts_ns, free[lf.direction])
        for i in range(len(data)):
            times.append(start + round((i + 1) * byte_ns))
        buf += data
        free[lf.direction] = times[-1]
    out: list[tuple[int, int, bytes]] = []
    gap = 3 * byte_ns  # a read returns when the line has been idle this long
    latency = int(byte_ns)  # the read returns shortly after its last byte
    for d, (buf, times) in streams.items():
        i, n = 0, len(buf)
        while i < n:
            j = min(n, i + rng.randint(1, max_chunk))
            for k in range(i + 1, j):  # stop at an idle gap
                if times[k] - times[k - 1] > gap:
                    j = k
                    break
            out.append((times[j - 1] + latency, d, bytes(buf[i:j])))
            i = j
    out.sort(key=lambda r: (r[0], r[1]))
    return iter(out)


def check_robot_session(duration: float, fmt: str, transport: str, what: str, outages: Outages,
                        transports: tuple[str, str, str] = ("tcp", "udp", "serial")) -> None:
    """The options a P2OS and a blackboard session share (``what``: "P2OS", "blackboard";
    ``transports`` in the order the message names them): ValueError naming the option for a
    bad one."""
    check_outages(outages, duration)
    if not 0 < duration <= 86_400:
        raise ValueError("--duration must be positive (at most a day)")
    if fmt not in ("pcap", "pcapng"):
        raise ValueError("--format must be pcap or pcapng")
    if transport not in transports:
        raise ValueError(f"{what} sessions are generated over {transports[0]}, {transports[1]} or {transports[2]}")
    if transport == "serial" and fmt != "pcapng":
        raise ValueError("serial captures are pcapng (the direction lives in the packet flags)")


def write_line_session(
    events: Iterable[tuple[int, bool, bytes, str]], out: BinaryIO, baud: int, description: str, seed: int = 1
) -> int:
    """A client/server exchange ``(ts_ns, from_client, data, kind)`` on a serial line, captured
    at the client (its bytes outbound). Returns the number of records written."""
    frames = [LineFrame(ts, DIR_OUT if from_client else DIR_IN, data, kind) for ts, from_client, data, kind in events]
    return write_line_capture(frames, out, baud, USER_LINKTYPES[0], description, seed)[0]


def write_line_capture(
    frames: Iterable[LineFrame], out: BinaryIO, baud: int, linktype: int, description: str, seed: int = 1
) -> tuple[int, int]:
    """Write frames of any protocol as a serial capture; returns (records, bytes)."""
    w = SerialCaptureWriter(out, linktype, if_name="serial", if_description=f"{description}, {baud} baud", flush=False)
    records = nbytes = 0
    for ts, d, chunk in uart_records(frames, baud, seed=seed):
        w.write(chunk, d, ts)
        records += 1
        nbytes += len(chunk)
    return records, nbytes


def generate_serial(opts: SerialGenOptions, out: BinaryIO) -> SerialGenStats:
    opts.validate()
    stats = SerialGenStats()
    for lf in session_frames(opts):
        stats.frames += 1
        stats.kinds[lf.kind] = stats.kinds.get(lf.kind, 0) + 1
    w = SerialCaptureWriter(
        out, opts.linktype, if_name="serial", if_description=f"generated SharedLink serial session, {opts.baud} baud",
        flush=False,
    )
    names = {DIR_IN: "inbound", DIR_OUT: "outbound"}
    for ts, d, chunk in line_records(opts):
        w.write(chunk, d, ts)
        stats.records += 1
        stats.bytes += len(chunk)
        stats.by_direction[names[d]] = stats.by_direction.get(names[d], 0) + len(chunk)
    payload = sum(len(lf.data) for lf in session_frames(opts))
    stats.noise_bytes = stats.bytes - payload
    return stats


def generate_serial_file(opts: SerialGenOptions, path: str | Path) -> SerialGenStats:
    with atomic_open(path) as fh:
        return generate_serial(opts, fh)
