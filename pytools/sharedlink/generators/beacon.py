"""Generate beacon captures: a vehicle's GPS beacon as SharedLink frames over UDP.

The library behind ``sharedlink gen``. Everything is decided by :class:`GenOptions`; the same
options (seed included) give byte-identical files.
"""

from __future__ import annotations

import random
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import NS, atomic_open, make_writer
from sharedlink.generators.outages import check_outages, silenced, windows
from sharedlink.generators.scenario import drive_tuples
from sharedlink.protocols.codec import _HEX2, address_node
from sharedlink.protocols.state import BEACON_VARIABLES

#: 2026-01-01T12:00:00Z: a fixed start so the same options give the same bytes
#: 2026-01-01T12:00:00Z, where every generated session starts unless told (the one home of it)
DEFAULT_START_NS = 1_767_268_800 * NS


@dataclass
class GenOptions:
    duration: float = 60.0
    rate: float = 5.0
    frames: int | None = None  # overrides duration when given
    compress: bool = False
    sync_interval: float = 1.0
    seed: int = 1
    fmt: str = "pcap"
    port: int = 7013
    src: str = "B"
    dst: str = "A"
    form: str = "named"
    bad_checksum: float = 0.0
    drop: float = 0.0
    jitter_ms: float = 0.0
    start_ns: int = DEFAULT_START_NS
    src_ip: str | None = None
    dst_ip: str = "255.255.255.255"
    outages: tuple[tuple[float, float], ...] = ()  # planted silences (start s, duration s): generators/outages.py

    def validate(self) -> None:
        if self.rate <= 0:
            raise ValueError("--rate must be positive")
        if self.duration <= 0 and not self.frames:
            raise ValueError("--duration must be positive")
        if self.sync_interval <= 0:
            raise ValueError("--sync-interval must be positive")
        for name in ("bad_checksum", "drop"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"--{name.replace('_', '-')} must be a rate between 0 and 1")
        if self.jitter_ms < 0:
            raise ValueError("--jitter must not be negative")
        if self.form not in ("named", "positional"):
            raise ValueError("--form must be named or positional")
        if self.fmt not in ("pcap", "pcapng"):
            raise ValueError("--format must be pcap or pcapng")
        if not 0 < self.port < 65536:
            raise ValueError("--port must be 1..65535")
        for name in ("src", "dst"):
            if address_node(getattr(self, name)) is None:
                raise ValueError(f"--{name} must be a node letter A-P")
        check_outages(self.outages, self.frame_count / self.rate)

    @property
    def frame_count(self) -> int:
        return self.frames if self.frames else int(round(self.duration * self.rate))


@dataclass
class GenStats:
    frames: int = 0  # written to the file
    bytes: int = 0  # SharedLink payload bytes written
    full: int = 0
    delta: int = 0
    declarations: int = 0
    dropped: int = 0
    silenced: int = 0  # frames not sent in planted outages
    bad_checksums: int = 0
    kinds: dict[str, int] = field(default_factory=dict)


def beacon_payloads(opts: GenOptions) -> Iterator[tuple[int, bytes, str]]:
    """(timestamp ns, SharedLink payload, kind) for every frame the vehicle sends, before
    faults. Compression keeps the sender's view: a value is elided when it equals the last
    one sent, and a full set goes out when ``sync_interval`` has passed since the last.

    This is the generator's hot path, so it assembles the frame text itself; the tests check
    that every payload equals what :func:`sharedlink.protocols.codec.encode_named` /
    :func:`~sharedlink.protocols.codec.encode_positional` build from the same values.
    """
    dst, src = opts.dst, opts.src
    period_ns = round(NS / opts.rate)
    sync_ns = round(opts.sync_interval * NS)
    named = opts.form == "named"
    compress = opts.compress
    t0 = opts.start_ns
    head = ":%s%s|N0" % (dst, src)
    if named:
        prefixes = ["|T%d|Q%s|D" % (t, n) for n, t in BEACON_VARIABLES]
    else:
        # a positional stream opens with the declaration of its list, so readers learn names
        decl = head + "".join("|T%d|Q%s" % (t, n) for n, t in BEACON_VARIABLES) + "|C"
        raw = decl.encode()
        yield t0, b"[" + raw + _HEX2[sum(raw) & 0xFF] + b"]\r\n", "declaration"
        prefixes = ["|D"] * len(BEACON_VARIABLES)
    p0, p1, p2, p3 = prefixes
    e0, e1, e2, e3 = ("" if named else p for p in prefixes)  # what an elided value leaves
    hex2 = _HEX2
    last = (None, None, None, None)
    next_sync = t0
    count = opts.frame_count
    ts = t0 - period_ns
    for lat, lon, heading, speed in drive_tuples(opts.seed, count / opts.rate, opts.rate):
        ts += period_ns
        a, b, c, d = texts = ("%.8f" % lat, "%.8f" % lon, "%.1f" % heading, "%.1f" % speed)
        if not compress or ts >= next_sync:
            next_sync = ts + sync_ns
            body = head + p0 + a + p1 + b + p2 + c + p3 + d + "|C"
            kind = "full"
        else:
            la, lb, lc, ld = last
            body = (
                head
                + (e0 if a == la else p0 + a)
                + (e1 if b == lb else p1 + b)
                + (e2 if c == lc else p2 + c)
                + (e3 if d == ld else p3 + d)
                + "|C"
            )
            kind = "delta"
        last = texts
        raw = body.encode()
        yield ts, b"[" + raw + hex2[sum(raw) & 0xFF] + b"]\r\n", kind


def corrupt_checksum(payload: bytes, rng: random.Random) -> bytes:
    """Replace the checksum digits with a different, wrong value."""
    c = payload.rfind(b"|C")
    good = int(payload[c + 2 : c + 4], 16)
    bad = (good + rng.randrange(1, 256)) & 0xFF
    return payload[: c + 2] + _HEX2[bad] + payload[c + 4 :]


def generate(opts: GenOptions, out: BinaryIO) -> GenStats:
    """Write the capture to ``out``; return what was written."""
    opts.validate()
    rng = random.Random(opts.seed ^ 0x5EED)  # faults draw from their own stream
    src_ip = opts.src_ip or f"192.168.1.{10 + (address_node(opts.src) or 2)}"
    builder = UdpBuilder(src_ip, opts.dst_ip, opts.port, opts.port)
    writer = make_writer(out, opts.fmt)
    headers = builder.headers
    hdr = struct.Struct("<IIII").pack if opts.fmt == "pcap" else None
    record = writer.record
    stats = GenStats()
    kinds = stats.kinds
    chunk: list[bytes] = []
    jitter_ns = int(opts.jitter_ms * 1_000_000)
    prev_ts = 0
    ip_id = 0
    drop, bad = opts.drop, opts.bad_checksum
    rand = rng.random
    nbytes = 0
    quiet = windows(opts.outages, opts.start_ns)
    for ts, payload, kind in beacon_payloads(opts):
        if quiet and silenced(ts, quiet):
            stats.silenced += 1
            continue
        if drop and rand() < drop:
            stats.dropped += 1
            continue
        if bad and rand() < bad:
            payload = corrupt_checksum(payload, rng)
            stats.bad_checksums += 1
        if jitter_ns:
            ts += rng.randint(-jitter_ns // 2, jitter_ns // 2)
            if ts <= prev_ts:
                ts = prev_ts + 1000
            prev_ts = ts
        ip_id = (ip_id + 1) & 0xFFFF
        n = len(payload)
        if hdr is not None:  # classic pcap: the record header inline (hot path)
            chunk.append(hdr(ts // NS, ts % NS, n + 42, n + 42) + headers(n, payload, ip_id) + payload)
        else:
            chunk.append(record(ts, headers(n, payload, ip_id) + payload))
        nbytes += n
        kinds[kind] = kinds.get(kind, 0) + 1
        if len(chunk) >= 4096:
            out.write(b"".join(chunk))
            chunk.clear()
    out.write(b"".join(chunk))
    stats.bytes = nbytes
    stats.frames = sum(kinds.values())
    stats.full = kinds.get("full", 0)
    stats.delta = kinds.get("delta", 0)
    stats.declarations = kinds.get("declaration", 0)
    return stats


def generate_file(opts: GenOptions, path: str | Path) -> GenStats:
    with atomic_open(path) as fh:
        return generate(opts, fh)
