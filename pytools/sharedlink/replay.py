"""Replay a capture's SharedLink payloads through an ordinary UDP socket or a serial port.

The library behind ``sharedlink replay``. No root is needed: the payloads (UDP payloads of the
capture; records on a USER link type taken as raw serial bytes) are sent with ``sendto`` on a
plain datagram socket, so local receivers on loopback get them like any other datagram.

Timing follows the capture (optionally sped up or slowed down), a fixed rate, or no pacing at
all. Every frame has an absolute deadline on the monotonic clock, computed from the first frame
(:class:`~sharedlink.pacing.Schedule`, the one schedule of every sink: UDP, serial, TCP),
so timing errors never add up with the number of frames. :class:`~sharedlink.pacing.Pacer` sleeps until shortly
before each deadline (how early follows how late this machine's sleeps end) and spins for the
rest, a spin bounded to a small share of each gap: a few percent of a core at most instead of a
whole one. :func:`~sharedlink.pacing.latency_hints` asks Linux for prompt wake-ups (timer slack, a short scheduler
slice; optionally real-time priority where permitted).

The timed modes stream the capture (one record at a time); ``topspeed`` pre-reads it in chunks
and, when looping over a small capture, keeps the payloads for the later passes.

What to send is here (:class:`CaptureFrames`; a TCP capture's segments:
:mod:`sharedlink.replay_tcp`), where to send it in :mod:`sharedlink.replay_sinks` (its names
importable from here too), and how: :class:`Replayer`.
"""

from __future__ import annotations

import errno
import ipaddress
import math
import random
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from socket import inet_ntoa
from typing import Any, NamedTuple, Optional

from sharedlink._interrupt import Terminated
from sharedlink.capture.packets import Datagram, PacketDecoder, decode_packet
from sharedlink.capture.pcapio import LINKTYPE_ETHERNET, LINKTYPE_USER0, NS, CaptureError, read_records
from sharedlink.defaults import MAX_PPS, MIN_PPS  # noqa: F401 - the steady rates --pps takes
from sharedlink.pacing import Pacer, Schedule, latency_hints
from sharedlink.replay_sinks import (
    ReplayError,
    SerialSink,
    Sink,
    SinkStalled,
    Target,
    UdpSink,
    is_broadcast,
    is_multicast,
    split_host_port,
)

#: LINKTYPE_USER0 .. LINKTYPE_USER15: records taken as raw serial bytes
USER_LINKTYPES = range(LINKTYPE_USER0, LINKTYPE_USER0 + 16)

TOPSPEED_CHUNK = 4096  # payloads pre-read at a time at top speed
LOOP_CACHE_BYTES = 64 << 20  # at top speed, passes after the first reuse payloads up to this size
LAG_SAMPLES = 65536  # lags kept for the median (reservoir sample beyond this many frames)

class OutFrame(NamedTuple):
    """One payload to send, with what the capture said about it."""

    number: int  # record number in the capture (1-based)
    ts_ns: int
    payload: bytes
    port: int | None  # the capture's destination UDP port; None for serial records
    src: str | None  # the capture's source address; None for serial records


@dataclass(frozen=True)
class FrameFilter:
    """Which frames to take: by UDP port (source or destination) and by source address."""

    ports: tuple[int, ...] = ()
    src: tuple[ipaddress.IPv4Network | ipaddress.IPv6Network, ...] = ()

    @classmethod
    def build(cls, ports: Sequence[int] = (), src: Sequence[str] = ()) -> FrameFilter:
        nets = []
        for s in src:
            try:
                nets.append(ipaddress.ip_network(s, strict=False))
            except ValueError:
                raise ReplayError(f"--filter-src {s!r} is not an IP address or network") from None
        for p in ports:
            if not 0 < p < 65536:
                raise ReplayError(f"--filter-port {p} is not a port (1..65535)")
        return cls(tuple(ports), tuple(nets))

    @property
    def active(self) -> bool:
        return bool(self.ports or self.src)


@dataclass
class SourceCounts:
    records: int = 0  # capture records read (over all passes)
    skipped: int = 0  # records that carry no UDP payload and are not serial records
    filtered: int = 0  # frames left out by the filter


class CaptureFrames:
    """The frames of a capture, read as they are needed; iterate again for another pass.

    A damaged capture yields every frame before the damage, then raises
    :class:`~sharedlink.capture.pcapio.CaptureError`.
    """

    def __init__(self, path: str | Path, flt: FrameFilter | None = None, direction: int | None = None) -> None:
        self.path = Path(path)
        self.filter = flt or FrameFilter()
        self.counts = SourceCounts()
        #: serial records: only those of this direction (pcapng EPB flags: 1 inbound, 2 outbound)
        self.direction = direction

    def __iter__(self) -> Iterator[OutFrame]:
        counts = self.counts
        ports = set(self.filter.ports)
        nets = self.filter.src
        active = self.filter.active
        user = USER_LINKTYPES
        decode = PacketDecoder().decode  # IP fragments reassembled, as Wireshark does
        for rec in read_records(self.path):
            counts.records += 1
            linktype, data = rec.linktype, rec.data
            if linktype in user:
                if active or (self.direction is not None and rec.flags & 3 != self.direction):
                    counts.filtered += 1
                    continue
                yield OutFrame(rec.number, rec.ts_ns, data, None, None)
                continue
            u = udp_fields(linktype, data, decode)
            if u is None:
                counts.skipped += 1
                continue
            src, sport, dport, payload = u
            if active:
                if ports and sport not in ports and dport not in ports:
                    counts.filtered += 1
                    continue
                if nets:
                    a = ipaddress.ip_address(src)
                    if not any(a in n for n in nets):
                        counts.filtered += 1
                        continue
            yield OutFrame(rec.number, rec.ts_ns, payload, dport, src)


def udp_fields(
    linktype: int, data: bytes, decode: Callable[[int, bytes], Datagram | None] = decode_packet
) -> tuple[str, int, int, bytes] | None:
    """(source address, source port, destination port, payload) of a UDP packet, else None.

    The common case (Ethernet, IPv4 without options or fragments, UDP) is read in place here,
    as :func:`sharedlink.capture.packets.decode_packet` would; everything else goes to ``decode``
    (a test holds the two to the same answers).
    """
    if (
        linktype == LINKTYPE_ETHERNET
        and len(data) >= 42
        and data[12] == 8
        and data[13] == 0
        and data[14] == 0x45
        and data[23] == 17
        and not (data[20] & 0x3F or data[21])
    ):
        n = len(data)
        end = 14 + ((data[16] << 8) | data[17])
        if end < 34:  # total length shorter than the header: decode_packet reads to the end
            end = n
        ulen = (data[38] << 8) | data[39]
        stop = 34 + ulen if ulen >= 8 else n
        stop = min(stop, end, n)
        return inet_ntoa(data[26:30]), (data[34] << 8) | data[35], (data[36] << 8) | data[37], data[42:stop]
    d = decode(linktype, data)
    if d is None or d.proto != "udp":
        return None
    return d.src, d.sport, d.dport, d.payload


def first_linktype(path: str | Path) -> int | None:
    """The link type of the capture's first record (None for an empty capture). Raises
    :class:`CaptureError` for a missing or damaged file."""
    for rec in read_records(path):
        return rec.linktype
    return None


# -- the replay ---------------------------------------------------------------------------


@dataclass
class ReplayOptions:
    speed: float = 1.0  # capture timing times this multiplier (2 = twice as fast)
    pps: float | None = None  # a fixed rate instead of the capture's timing (speed is then unused)
    topspeed: bool = False  # no pacing at all
    loop: int = 1  # passes over the capture; 0 = until stopped
    loop_delay: float = 0.0  # extra seconds between passes (timed passes are also one frame gap apart)
    limit: int | None = None  # stop after this many frames
    realtime: bool = False  # timed modes: ask for SCHED_FIFO (needs privileges; see latency_hints)

    def validate(self) -> None:
        if not self.speed > 0:
            raise ReplayError("--speed must be positive")
        if self.pps is not None and not (self.pps >= MIN_PPS and math.isfinite(self.pps)):
            raise ReplayError(f"--pps must be at least {MIN_PPS:g} frames per second (a period of at most 1e7 s)")
        if self.loop < 0:
            raise ReplayError("--loop must be 0 (until stopped) or more")
        if self.loop_delay < 0:
            raise ReplayError("--loop-delay must not be negative")
        if self.limit is not None and self.limit <= 0:
            raise ReplayError("--limit must be positive")

    @property
    def mode(self) -> str:
        if self.topspeed:
            return "topspeed"
        if self.pps:
            return f"{self.pps:g} frames/s"
        return "capture timing" + (f" x{self.speed:g}" if self.speed != 1 else "")


@dataclass
class ReplayStats:
    frames: int = 0  # sent
    bytes: int = 0  # payload bytes sent
    attempted: int = 0  # frames taken from the capture (sent or failed)
    send_errors: int = 0
    errors: dict[str, int] = field(default_factory=dict)  # by kind
    first_error: str | None = None
    passes: int = 0  # complete passes over the capture
    elapsed_s: float = 0.0
    cpu_s: float = 0.0
    lag_now_ns: int | None = None  # the latest frame's lag behind its deadline
    lag_median_ns: int | None = None
    lag_max_ns: int | None = None
    interrupted: bool = False
    terminated: bool = False  # the interruption was SIGTERM (exit 143), not Ctrl-C (130)
    realtime: bool = False  # real-time scheduling was asked for and granted
    capture_error: str | None = None
    #: capture timing: the frames of the first pass whose time did not advance past the first
    #: frame's, when none did (all of them at one time: sent back to back); else 0
    flat_times: int = 0
    counts: SourceCounts = field(default_factory=SourceCounts)
    _lags: list[int] = field(default_factory=list, repr=False)

    @property
    def rate_fps(self) -> float:
        return self.frames / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def rate_bps(self) -> float:
        return self.bytes / self.elapsed_s if self.elapsed_s > 0 else 0.0

    def error(self, kind: str, message: str) -> None:
        self.send_errors += 1
        self.errors[kind] = self.errors.get(kind, 0) + 1
        if self.first_error is None:
            self.first_error = message

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "bytes": self.bytes,
            "send_errors": self.send_errors,
            "errors": dict(self.errors),
            "first_error": self.first_error,
            "records": self.counts.records,
            "skipped": self.counts.skipped,
            "filtered": self.counts.filtered,
            "passes": self.passes,
            "elapsed_s": round(self.elapsed_s, 6),
            "rate_fps": round(self.rate_fps, 3),
            "rate_bytes_per_s": round(self.rate_bps, 3),
            "lag_median_ms": _ms(self.lag_median_ns),
            "lag_max_ms": _ms(self.lag_max_ns),
            "cpu_s": round(self.cpu_s, 6),
            "interrupted": self.interrupted,
            "realtime": self.realtime,
            "capture_error": self.capture_error,
            "flat_times": self.flat_times,
        }


def _ms(ns: int | None) -> float | None:
    return None if ns is None else round(ns / 1e6, 6)


def _error_kind(exc: OSError) -> str:
    if exc.errno is not None and exc.errno in errno.errorcode:
        return errno.errorcode[exc.errno]
    return type(exc).__name__


class SigintGate:
    """Ctrl-C without a frame half counted: while ``held`` is set (a frame is being handed to
    the sink and counted), SIGINT only sets ``pending``, and the loop raises
    :class:`KeyboardInterrupt` itself once the frame is counted; otherwise it raises at once
    (a long pacing sleep ends at the key press). Installed only in the main thread and only
    over Python's default handler: a program with a SIGINT handler of its own keeps it (and
    the one-frame window in which a frame may be sent but not counted)."""

    def __init__(self) -> None:
        self.held = False
        self.pending = False
        self._old: Any = None

    def _handler(self, signum: int, frame: object) -> None:
        if self.held:
            self.pending = True
        else:
            raise KeyboardInterrupt

    def __enter__(self) -> SigintGate:
        if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self._old = signal.signal(signal.SIGINT, self._handler)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
            self._old = None


Progress = Callable[[ReplayStats], None]
#: a wait for one frame this long or longer is announced (``Replayer(long_wait=...)``)
LONG_WAIT_S = 60
LONG_WAIT_NS = LONG_WAIT_S * NS


class Replayer:
    """Sends the frames of ``source`` to ``sink`` with the timing of ``opts``.

    ``progress`` is called about every ``progress_interval`` seconds with the running
    statistics, only when there is time to spare before the next deadline (it never delays a
    frame). ``long_wait(record, seconds)`` is called before a frame the capture's timing makes
    wait :data:`LONG_WAIT_S` or more (a gap in the capture: a year-long one would otherwise
    look like a hang). Ctrl-C stops cleanly: :meth:`run` returns the statistics with
    ``interrupted`` set.
    """

    def __init__(
        self,
        source: CaptureFrames,
        sink: Sink,
        opts: ReplayOptions | None = None,
        progress: Progress | None = None,
        progress_interval: float = 0.5,
        long_wait: Callable[[int, float], None] | None = None,
    ) -> None:
        self.source, self.sink = source, sink
        self.long_wait = long_wait  # (record number, seconds) before a wait of LONG_WAIT_S or more
        self.opts = opts or ReplayOptions()
        self.opts.validate()
        self.progress = progress
        self.progress_ns = int(progress_interval * NS)
        self.stats = ReplayStats(counts=source.counts)
        self._rng = random.Random(0)
        self._next_progress = 0
        self._start = 0
        self.gate = SigintGate()

    # -- bookkeeping
    def _lag(self, lag: int) -> None:
        st = self.stats
        st.lag_now_ns = lag
        if st.lag_max_ns is None or lag > st.lag_max_ns:
            st.lag_max_ns = lag
        lags = st._lags
        n = st.frames + st.send_errors  # frames timed so far, before this one
        if len(lags) < LAG_SAMPLES:
            lags.append(lag)
        else:
            j = self._rng.randrange(n + 1)
            if j < LAG_SAMPLES:
                lags[j] = lag

    def _report(self, now: int) -> None:
        if self.progress is not None and now >= self._next_progress:
            self._next_progress = now + self.progress_ns
            self.stats.elapsed_s = (now - self._start) / NS
            self.progress(self.stats)

    def run(self) -> ReplayStats:
        st = self.stats
        cpu0 = time.process_time()
        self._start = time.monotonic_ns()
        self._next_progress = self._start + self.progress_ns
        try:
            with self.gate:
                if self.opts.topspeed:
                    _TopSpeed(self).run()
                else:
                    with latency_hints(self.opts.realtime) as granted:
                        st.realtime = granted
                        self._run_timed()
        except KeyboardInterrupt as exc:
            st.interrupted = True
            st.terminated = isinstance(exc, Terminated)
        except SinkStalled:
            pass  # counted as a send error: exit 1
        except CaptureError as exc:
            st.capture_error = str(exc)
        st.elapsed_s = (time.monotonic_ns() - self._start) / NS
        st.cpu_s = time.process_time() - cpu0
        if st._lags:
            s = sorted(st._lags)
            n = len(s)
            st.lag_median_ns = s[n // 2] if n % 2 else (s[n // 2 - 1] + s[n // 2]) // 2
        return st

    def _passes(self) -> Iterator[int]:
        n = 0
        while self.opts.loop == 0 or n < self.opts.loop:
            yield n
            n += 1

    def _flat(self, npass: int, schedule: Schedule) -> None:
        """Note a first pass in capture timing whose times never advanced (``flat_times``)."""
        if npass == 0:
            self.stats.flat_times = schedule.flat

    # -- the reference path (timed modes): one frame at a time, streaming, absolute deadlines
    def _run_timed(self) -> None:
        opts, st, sink, gate = self.opts, self.stats, self.sink, self.gate
        send, target_of = sink.send, sink.target
        clock, pace = time.monotonic_ns, Pacer().wait
        limit = opts.limit
        schedule = Schedule(NS / opts.pps if opts.pps else None, opts.speed, round(opts.loop_delay * NS))
        due = schedule.next
        for npass in self._passes():
            for fr in self.source:
                if limit is not None and st.attempted >= limit:
                    self._flat(npass, schedule)
                    return
                deadline, gap = due(fr.ts_ns)
                now = clock()
                if deadline - now >= LONG_WAIT_NS and self.long_wait is not None:
                    self.long_wait(fr.number, (deadline - now) / NS)
                if now >= self._next_progress and (deadline - now > 2_000_000 or now > self._next_progress + self.progress_ns):
                    self._report(now)  # when there is time to spare, or it is long overdue
                pace(deadline, gap)
                t = target_of(fr)
                now = clock()
                if t is None:
                    st.attempted += 1
                    st.error("no-port", _NO_PORT % fr.number)
                    continue
                gate.held = True  # Ctrl-C waits until this frame is sent (or failed) and counted
                try:
                    send(fr.payload, t)
                except OSError as exc:
                    self._lag(now - deadline)
                    st.attempted += 1
                    st.error(_error_kind(exc), f"record {fr.number}: {exc.strerror or exc}")
                    if isinstance(exc, SinkStalled):
                        return
                else:
                    self._lag(now - deadline)
                    st.attempted += 1
                    st.frames += 1
                    st.bytes += len(fr.payload)
                finally:
                    gate.held = False
                if gate.pending:
                    raise KeyboardInterrupt
            if schedule.count == 0:
                return  # nothing to send: looping would spin forever
            self._flat(npass, schedule)
            st.passes += 1
            schedule.end_pass()


class _TopSpeed:
    """The fast tier of :class:`Replayer`, for ``topspeed``: payloads pre-read in chunks of
    :data:`TOPSPEED_CHUNK` and sent in a tight loop, passes after the first from a cache (up to
    :data:`LOOP_CACHE_BYTES`). Same contract as the reference path (``Replayer._run_timed``
    without pacing): the same frames to the same targets in the same order, the same counts,
    errors, passes and limit; only the timing (none) and the progress calls (per chunk) differ."""

    def __init__(self, replayer: Replayer) -> None:
        self.replayer = replayer
        self.opts, self.stats, self.sink, self.source = replayer.opts, replayer.stats, replayer.sink, replayer.source
        self._kept_bytes = 0

    def run(self) -> None:
        opts, st = self.opts, self.stats
        limit = opts.limit
        delay = opts.loop_delay
        cache: list[_Chunk] | None = None
        for npass in self.replayer._passes():
            if npass and delay:
                time.sleep(delay)
            keep: list[_Chunk] | None = [] if cache is None and opts.loop != 1 else None
            chunks = iter(cache) if cache is not None else self._chunks(keep)
            taken = st.attempted
            for numbers, payloads, targets in chunks:
                if targets is None:  # frames without a target fail on every pass, as in the reference path
                    for number in numbers:
                        if limit is not None and st.attempted >= limit:
                            return
                        st.attempted += 1
                        st.error("no-port", _NO_PORT % number)
                    continue
                if limit is not None:
                    room = limit - st.attempted
                    if room <= 0:
                        return
                    if room < len(payloads):
                        self._send_chunk(numbers[:room], payloads[:room], targets[:room])
                        return
                self._send_chunk(numbers, payloads, targets)
                self.replayer._report(time.monotonic_ns())
            if st.attempted == taken:
                return  # nothing to send: looping would spin forever
            st.passes += 1
            if keep is not None and self._kept_bytes <= LOOP_CACHE_BYTES:
                cache = keep

    def _chunks(self, keep: list[_Chunk] | None) -> Iterator[_Chunk]:
        """Chunks of (record numbers, payloads, targets); a frame without a target is a chunk
        of its own with targets None. With ``keep``, chunks are also kept while they fit the
        cache."""
        target_of = self.sink.target
        self._kept_bytes = 0
        numbers: list[int] = []
        payloads: list[bytes] = []
        targets: list[Target] = []
        try:
            for fr in self.source:
                t = target_of(fr)
                if t is None:
                    if payloads:
                        self._keep(keep, (numbers, payloads, targets))
                        yield numbers, payloads, targets
                        numbers, payloads, targets = [], [], []
                    alone: _Chunk = ([fr.number], [], None)
                    self._keep(keep, alone)
                    yield alone
                    continue
                numbers.append(fr.number)
                payloads.append(fr.payload)
                targets.append(t)
                if len(payloads) >= TOPSPEED_CHUNK:
                    self._keep(keep, (numbers, payloads, targets))
                    yield numbers, payloads, targets
                    numbers, payloads, targets = [], [], []
        except CaptureError:
            if payloads:  # the frames before the damage still go out
                yield numbers, payloads, targets
            raise
        if payloads:
            self._keep(keep, (numbers, payloads, targets))
            yield numbers, payloads, targets

    def _keep(self, keep: list[_Chunk] | None, chunk: _Chunk) -> None:
        if keep is not None and self._kept_bytes <= LOOP_CACHE_BYTES:
            self._kept_bytes += sum(map(len, chunk[1]))
            keep.append(chunk)

    def _send_chunk(self, numbers: list[int], payloads: list[bytes], targets: list[Target]) -> None:
        """Send a chunk, counting exactly the frames handed to the sink: Ctrl-C (through the
        replayer's :class:`SigintGate`) stops the chunk between two frames, never inside one."""
        st = self.stats
        send = self.sink.send
        gate = self.replayer.gate
        n = len(payloads)
        failed = failed_bytes = 0
        start = i = 0
        gate.held = True
        try:
            while start < n:
                i = start
                try:
                    for i in range(start, n):
                        if gate.pending:
                            break
                        send(payloads[i], targets[i])
                    else:
                        i = n
                    start = i
                    break
                except SinkStalled as exc:  # nobody reads: stop here, say so
                    st.error(_error_kind(exc), f"record {numbers[i]}: {exc}")
                    failed, failed_bytes, start = failed + 1, failed_bytes + len(payloads[i]), i + 1
                    raise
                except OSError as exc:
                    failed += 1
                    failed_bytes += len(payloads[i])
                    st.error(_error_kind(exc), f"record {numbers[i]}: {exc.strerror or exc}")
                    start = i + 1
        except BaseException:  # a program's own SIGINT handler raised: the frames before i went
            start = max(start, i)
            raise
        finally:  # the frames really handed to the sink (all of them, unless interrupted)
            gate.held = False
            st.attempted += start
            st.frames += start - failed
            st.bytes += sum(map(len, payloads[:start])) - failed_bytes
        if gate.pending:
            raise KeyboardInterrupt


_Chunk = tuple[list[int], list[bytes], Optional[list[Target]]]
_NO_PORT = "record %d: a serial record has no destination port (give --to HOST:PORT)"


def replay(
    path: str | Path,
    sink: Sink,
    opts: ReplayOptions | None = None,
    flt: FrameFilter | None = None,
    progress: Progress | None = None,
    progress_interval: float = 0.5,
) -> ReplayStats:
    """Replay the capture at ``path`` into ``sink``; return what was sent. A damaged capture
    stops the replay after the frames before the damage (``capture_error`` says where)."""
    return Replayer(CaptureFrames(path, flt), sink, opts, progress, progress_interval).run()


__all__ = [
    "USER_LINKTYPES",
    "CaptureFrames",
    "FrameFilter",
    "OutFrame",
    "ReplayError",
    "ReplayOptions",
    "ReplayStats",
    "Replayer",
    "SerialSink",
    "UdpSink",
    "first_linktype",
    "is_broadcast",
    "is_multicast",
    "replay",
    "split_host_port",
]
