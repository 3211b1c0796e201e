"""``sharedlink watch``: decode a live link (UDP, serial) or a capture at its pace, as it happens.

Sources give :class:`~sharedlink.capture.stream.StreamFrame` s in batches; one
:class:`~sharedlink.analysis.decode.Decoder` turns them into
:class:`~sharedlink.analysis.decode.Decoded` frames (the rules of every other command), which go
to the outputs: the live terminal view (:class:`LiveView`, drawn with rich), one JSON line per
frame (:func:`~sharedlink.watch_json.json_line`), and the Foxglove channels
(:class:`~sharedlink.analysis.foxglove_channels.FoxgloveChannels`) behind foxglove-sdk's
WebSocket server.

* UDP, by default: the interface is sniffed as Wireshark's dumpcap does
  (:class:`~sharedlink.sniffer.UdpSniffer`, a Linux packet socket with a kernel filter for the
  port; root or CAP_NET_RAW), so the watch takes nothing from the vehicle software on the port:
  every program bound to it still gets every datagram. ``--bind-port`` (:class:`UdpSource`) binds the port instead, for a machine where
  nothing else uses it; it refuses a port another program holds (no SO_REUSEADDR or
  SO_REUSEPORT: sharing a unicast port means taking datagrams away). Either way a large receive
  buffer and a drain-then-draw loop keep up with bursts; frames are stamped with the arrival
  time.
* Serial: :class:`~sharedlink.capture.serial_format.Deframer` over the bytes read (SharedLink),
  stamped with the arrival time of the chunk that completed the frame.
* Capture: :func:`~sharedlink.capture.stream.iter_frames`' frames (and the P2OS and blackboard
  messages) read once (:mod:`sharedlink.watch_capture`: a pipe will do), played at the recorded pace (times
  ``speed``); frames keep their capture times and the view's clock follows the capture's.
"""

from __future__ import annotations

import os
import select
import socket
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, NamedTuple

from sharedlink.analysis.decode import NS, VALUE_KINDS, Decoded, Decoder
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import CaptureError
from sharedlink.capture.stream import StreamFrame
from sharedlink.defaults import WATCH_DEFAULT_PORT
from sharedlink.protocols.codec import Frame
from sharedlink.protocols.limits import MAX_CONVERSATIONS, MAX_NAMES, LimitCounts
from sharedlink.replay import SigintGate
from sharedlink.watch_json import JsonLines as JsonLines  # (--json: its home is watch_json)
from sharedlink.watch_json import json_line as json_line

DEFAULT_PORT = WATCH_DEFAULT_PORT
#: how long a change (value, failure, late sync, gap) stays highlighted, seconds
HIGHLIGHT_S = 2.0
#: the pause after a UDP batch that was not full, seconds: 10,000 frames/s arrive 50 at a time
#: instead of waking the watch for each (measured: a wake-up costs more CPU than decoding a frame)
GATHER_S = 0.005
#: receive buffer asked for (the kernel caps it at net.core.rmem_max)
RCVBUF = 8 << 20
#: datagrams (and their bytes) received and not yet decoded that a live UDP source holds: past
#: either bound the oldest is dropped and counted (issue 31: the watch's memory stays bounded)
BACKLOG_DATAGRAMS = 65536
BACKLOG_BYTES = 32 << 20
#: a datagram that waited longer than this to be decoded is dropped and counted: under a flood
#: the watch stays about this far behind the link at most, however slow its frames are to decode
#: (``watch --max-lag``; 0: never dropped for waiting). Not much shorter: on a busy machine the
#: watch gets a share of a core, and at 2 s it dropped 6,000 of 30,000 frames sent at 5,000/s
#: that it showed all of, some seconds late, with no bound
MAX_LAG_S = 10.0
#: the time one batch of a live UDP source should take to decode and show: the socket is drained
#: into the backlog between batches, so a batch of slow frames is made smaller
SLICE_S = 0.02
#: most datagrams in one batch
BATCH = 512

Batch = list[StreamFrame]


class RawDatagram(NamedTuple):
    """A UDP datagram as received: split into frames by the decoder (its fast path first)."""

    number: int
    ts_ns: int
    conv: tuple[str, str, int, str, int]
    data: bytes


# -- sources ----------------------------------------------------------------------------------


def big_receive_buffer(sock: socket.socket) -> None:
    """Ask for :data:`RCVBUF`: past net.core.rmem_max when privileged (SO_RCVBUFFORCE), else up
    to it."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_RCVBUFFORCE", 33), RCVBUF)
    except OSError:
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF)
        except OSError:
            pass



class Backlog:
    """The datagrams a live UDP source received and the decoder has not taken yet, a queue per
    conversation (sender and receiver address and port) served in turn, so a sender flooding
    the port delays the others by one datagram a turn, not by its whole flood. Both directions of
    a sniffed conversation share a queue (arrival order: a blackboard answer before the next message).

    At most :data:`BACKLOG_DATAGRAMS` and :data:`BACKLOG_BYTES`: past either the oldest datagram
    of the longest queue is dropped; none older than ``max_lag_s`` is handed out (dropped).
    ``dropped`` counts both, with what the kernel dropped from a full receive buffer
    (:meth:`kernel_dropped`)."""

    def __init__(self, max_items: int = BACKLOG_DATAGRAMS, max_bytes: int = BACKLOG_BYTES,
                 max_lag_s: float = MAX_LAG_S) -> None:
        self.queues: dict[tuple, deque[RawDatagram]] = {}  # in turn order: a queue served goes last
        self.count = 0
        self.bytes = 0
        self.max_items, self.max_bytes = max_items, max_bytes
        self.max_lag_ns = round(max_lag_s * NS) if max_lag_s > 0 else 1 << 62
        self.dropped = 0  # the sum of the three below
        self.full = 0  # dropped at the backlog's bounds
        self.stale = 0  # dropped having waited past max_lag_s
        self.kernel = 0  # dropped by the kernel (its receive buffer full)
        self._longest: tuple | None = None  # the conversation with the longest queue (as of its last put)

    def __len__(self) -> int:
        return self.count

    def put(self, dg: RawDatagram) -> None:
        queues = self.queues
        q = queues.get(key := dg.conv)
        if q is None and (q := queues.get(rev := (key[0], key[3], key[4], key[1], key[2]))) is not None:
            key = rev  # the other direction's queue while it holds datagrams: one queue, arrival order kept
        elif q is None:
            q = queues[key] = deque()
        q.append(dg)
        self.count, self.bytes = self.count + 1, self.bytes + len(dg.data)
        longest = self._longest
        if longest is None or longest not in queues or len(q) > len(queues[longest]):
            self._longest = key
        while self.count > self.max_items or (self.bytes > self.max_bytes and self.count > 1):
            self._drop_longest()

    def _drop_longest(self) -> None:
        key = self._longest
        if key is None or key not in self.queues:
            key = self._longest = max(self.queues, key=lambda k: len(self.queues[k]))
        q = self.queues[key]
        self._forget(q.popleft())
        self.full += 1
        if not q:
            del self.queues[key]
            self._longest = None

    def _forget(self, dg: RawDatagram) -> None:
        self.count -= 1
        self.bytes -= len(dg.data)
        self.dropped += 1

    def take(self, n: int, now_ns: int) -> list[RawDatagram]:
        """Up to ``n`` datagrams, one from each conversation in turn (the datagrams that waited
        too long dropped first), in the order they arrived."""
        queues = self.queues
        stale = now_ns - self.max_lag_ns
        out: list[RawDatagram] = []
        while len(out) < n and queues:
            for key in list(queues):
                q = queues.pop(key)
                while q and q[0].ts_ns < stale:
                    self._forget(q.popleft())
                    self.stale += 1
                if q:
                    dg = q.popleft()
                    self.count, self.bytes = self.count - 1, self.bytes - len(dg.data)
                    out.append(dg)
                    if q:
                        queues[key] = q  # its next turn comes after the others'
                if len(out) >= n:
                    break
        out.sort()  # (by number: the order of arrival)
        return out

    def kernel_dropped(self, n: int) -> None:
        self.dropped += n
        self.kernel += n

    def breakdown(self) -> str:
        """What ``dropped`` counts, for the last line."""
        return f"{self.stale} waited too long, {self.full} past the backlog's size, {self.kernel} by the kernel"


def socket_batches(source: Any, size: int, take: Callable[[bytes, Any], tuple[tuple, bytes] | None],
                   timeout: float) -> Iterator[Batch]:
    """The batches of a non-blocking socket source (``source.sock``, its datagram count
    ``source.number``, its :class:`Backlog` ``source.backlog``, what the kernel dropped
    ``source.kernel_drops()``). Every ``recvfrom(size)`` is made a :class:`RawDatagram` by
    ``take(data, addr) -> (conv, payload)`` (None: not one) and stamped with its arrival.

    Each round drains the socket without blocking into the backlog, then hands out datagrams
    (the oldest of each conversation in turn), at most :data:`BATCH`: as many as decode in about
    :data:`SLICE_S` of CPU time (the count halves after a slower batch and doubles after a fast
    one; CPU time, since on a busy machine the wall clock counts other programs' turns and
    shrank the batches to one datagram), so the socket is drained again
    soon whatever the frames cost and what the watch cannot decode in time is dropped and
    counted in the backlog, not lost unseen in the kernel. With nothing there, one wait of
    ``timeout`` (an empty batch after it); after a batch that was not full, a pause of
    :data:`GATHER_S` so the next datagrams arrive together (a wake-up per frame costs more
    than the frame)."""
    recv = source.sock.recvfrom
    fd = source.sock.fileno()
    backlog: Backlog = source.backlog
    put = backlog.put
    clock, cpu = time.time_ns, time.thread_time
    want = 16  # grows to BATCH while batches are fast
    next_count = 0.0
    while True:
        n = source.number
        for _ in range(backlog.max_items):
            try:
                data, addr = recv(size)
            except (BlockingIOError, InterruptedError):
                break
            got = take(data, addr)
            if got is None:
                continue
            n += 1
            put(RawDatagram(n, clock(), got[0], got[1]))
        source.number = n
        if time.monotonic() >= next_count:  # (a system call or a file read: not every round)
            backlog.kernel_dropped(source.kernel_drops())
            next_count = time.monotonic() + timeout
        if not backlog.count:
            if select.select([fd], [], [], timeout)[0]:
                continue
            yield []
            time.sleep(GATHER_S)
            continue
        asked = want
        out = backlog.take(asked, clock())
        t0 = cpu()
        yield out
        spent = cpu() - t0
        if spent > SLICE_S:
            want = max(1, want // 2)
        elif spent < SLICE_S / 4 and want < BATCH:
            want = min(BATCH, want * 2)
        if len(out) < asked and not backlog.count:
            time.sleep(GATHER_S)


class UdpSource:
    """Datagrams to ``port`` on ``host`` (every address, broadcasts included, by default), the
    port bound by the watch itself (``watch --bind-port``): they are the watch's, no other program
    gets them. Binding is exclusive (no SO_REUSEADDR, no SO_REUSEPORT): a port another program
    holds is refused with ``EADDRINUSE`` instead of sharing it (Linux hands a shared unicast
    datagram to one socket only, so the vehicle software would lose it)."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "", max_lag_s: float = MAX_LAG_S) -> None:
        self.port = port
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            big_receive_buffer(self.sock)
            self.sock.bind((host, port))
            self.sock.setblocking(False)
        except BaseException:
            self.sock.close()
            raise
        self.number = 0
        self.backlog = Backlog(max_lag_s=max_lag_s)
        self._inode = os.fstat(self.sock.fileno()).st_ino
        self._drops = 0
        self.description = f"udp port {port}{f' on {host}' if host else ''} (bound by the watch)"
        from sharedlink.analysis.robots import RobotLinks

        self.robots = RobotLinks(messages=True)  # P2OS, blackboard over UDP (robot_watch.with_robots)

    def batches(self, timeout: float) -> Iterator[Batch]:
        """Everything that arrived (as :class:`RawDatagram` s, up to 512), drained without
        blocking, then (nothing there) one wait of ``timeout``. After a batch that was not full
        the loop pauses :data:`GATHER_S` so the next datagrams arrive together. (Measured at
        10,000 frames/s: ``recvmmsg`` through ctypes saved 1.7 µs a frame over this loop, the
        pause 25 µs; not worth a ctypes binding.)"""
        port = self.port

        def take(data: bytes, addr: Any) -> tuple[tuple, bytes]:
            return ("udp", addr[0], addr[1], "", port), data

        from sharedlink.robot_watch import with_robots  # P2OS, blackboard: their SessionMessages
        return with_robots(socket_batches(self, 65535, take, timeout), self.robots)

    def kernel_drops(self) -> int:
        """Datagrams the kernel dropped from the full receive buffer since the last call (the
        socket's ``drops`` in /proc/net/udp; 0 where it cannot be read)."""
        total = _udp_drops(self._inode)
        new, self._drops = max(total - self._drops, 0), max(total, self._drops)
        return new

    def now_ns(self) -> int:
        return time.time_ns()

    def close(self) -> None:
        self.sock.close()


def _udp_drops(inode: int) -> int:
    """The ``drops`` column of the UDP socket with this inode in /proc/self/net/udp (0 if none)."""
    key = str(inode)
    try:
        with open("/proc/self/net/udp", encoding="ascii", errors="replace") as f:
            next(f, None)
            for line in f:
                cols = line.split()
                if len(cols) > 12 and cols[9] == key:
                    return int(cols[-1])
    except (OSError, ValueError):
        pass
    return 0


class SerialSource:
    """SharedLink frames read from a serial device with the serial deframer; P2OS packets and
    blackboard messages too (:class:`~sharedlink.analysis.robots.RobotLinks`, the bytes read taken
    as inbound: a robot's or a slave's), as :class:`SessionMessage` s."""

    def __init__(self, device: str, baud: int = 9600) -> None:
        from sharedlink.analysis.robots import RobotLinks
        from sharedlink.capture.serial_format import Deframer
        from sharedlink.capture.serial_port import open_port

        self.port = open_port(device, baud, timeout=0)
        self.deframer = Deframer("sharedlink")
        self.robots = RobotLinks(messages=True)
        self.number = 0
        self.conv = ("serial", device, baud, "", 0)
        self.description = f"serial {device} at {baud} baud"

    def batches(self, timeout: float) -> Iterator[Batch]:
        import selectors

        sel = selectors.DefaultSelector()
        fd = self.port.fileno()  # type: ignore[attr-defined]
        sel.register(fd, selectors.EVENT_READ)
        while True:
            out: Batch = []
            if sel.select(timeout):
                import os

                chunk = os.read(fd, 65536)
                self.number += 1
                ts = time.time_ns()
                for p in self.deframer.feed(chunk, self.number):
                    frame = p.frame if isinstance(p.frame, Frame) else None
                    out.append(StreamFrame(self.number, ts, self.conv, p.data, frame, None if frame else (p.reason or "noise")))
                out += self.robots.serial(self.number, ts, chunk, 1, 0)  # (flags 1: inbound)
            yield out

    def now_ns(self) -> int:
        return time.time_ns()

    def close(self) -> None:
        self.port.close()  # type: ignore[attr-defined]


class CaptureSource:
    """A capture's frames at its recorded pace times ``speed``; the clock is the capture's.

    A damaged capture: every frame before the damage is handed out (the same ones every run,
    whatever the pace), then the source ends with ``error`` set to the
    :class:`~sharedlink.capture.pcapio.CaptureError` for the caller to report.
    With ``sessions`` (``--foxglove``; None: if it has robot links, see
    :class:`~sharedlink.watch_capture.CaptureItems`), its P2OS and blackboard messages
    (:class:`~sharedlink.analysis.sessions.SessionMessage`, what ``export --format mcap`` adds)
    come in the same batches, in time order with the frames. The capture is read once, front to
    back (standard input will do)."""

    def __init__(self, path: str | Path, speed: float = 1.0, sessions: bool | None = False) -> None:
        self.path, self.speed, self.sessions = path, speed, sessions
        self.description = f"{path} at {speed:g}x"
        self._t0: int | None = None  # capture time of the first frame
        self._m0 = 0.0  # monotonic time it was shown
        self.done = False
        self.error: CaptureError | None = None

    def now_ns(self) -> int:
        if self._t0 is None:
            return 0
        return self._t0 + round((time.monotonic() - self._m0) * self.speed * NS)

    def batches(self, timeout: float) -> Iterator[Batch]:
        out: Batch = []
        due = time.monotonic() + timeout
        from sharedlink.watch_capture import END, NOTHING, CaptureItems, Taker

        items = Taker(CaptureItems(self.path, self.sessions), threaded=str(self.path) == "/dev/stdin")  # read once
        while True:
            try:
                item = items.take(due)
            except CaptureError as exc:  # the frames gathered so far go out first
                self.error = exc
                break
            if item is END:
                break
            if item is NOTHING:  # (standard input: nothing came in time)
                yield out
                out = []
                due = time.monotonic() + timeout
                continue
            if not isinstance(item, (StreamFrame, SessionMessage)):
                continue
            if self._t0 is None:
                self._t0, self._m0 = item.ts_ns, time.monotonic()
            at = self._m0 + (item.ts_ns - self._t0) / NS / self.speed
            while True:  # wait for the frame's time, handing out what is due meanwhile
                now = time.monotonic()
                if at <= now:
                    break
                if out or now >= due:
                    yield out
                    out = []
                    due = time.monotonic() + timeout
                    continue
                time.sleep(min(at, due) - now)
            out.append(item)
            if len(out) >= 512 or time.monotonic() >= due:
                yield out
                out = []
                due = time.monotonic() + timeout
        self.done = True
        yield out

    def close(self) -> None:
        pass


# -- decoding: the core decoder -----------------------------------------------------------------


# -- the live view ---------------------------------------------------------------------------


@dataclass
class VarStat:
    text: str | None = None
    changed_ns: int = 0  # when its value last changed
    updates: int = 0  # frames that carried it, this second
    rate: float = 0.0  # frames per second that carried it, last full second


@dataclass
class DirStat:
    """What the view shows for one direction."""

    pair: str
    conv: tuple
    frames: int = 0
    bad: int = 0
    late: int = 0
    gaps: int = 0
    last_ns: int = 0
    bad_ns: int = -(1 << 62)
    late_ns: int = -(1 << 62)
    gap_ns: int = -(1 << 62)
    second: int = 0  # the second the counters below count
    in_second: int = 0
    fps: float = 0.0
    vars: dict[str, VarStat] = field(default_factory=dict)


class LiveView:
    """Per direction: variables' last values, age since they changed, update rates; link
    frames/s, checksum failures, late syncs (frames while a full set is overdue) and late full
    sets (a full set more than the sync interval + 0.5 s after the previous one: docs/cli.md's
    words, never "gaps"); what just happened is highlighted for :data:`HIGHLIGHT_S`."""

    def __init__(self, sync_interval: float = 1.0, title: str = "") -> None:
        self.dirs: dict[tuple, DirStat] = {}
        self.gap_ns = round((sync_interval + 0.5) * NS)
        self.title = title
        self.frames = 0
        self.unshown = 0  # frames of directions past MAX_CONVERSATIONS (counted, not shown)
        self.stats = WatchStats()  # the loop's counts (noise, dropped, limits)
        from sharedlink.analysis.health import Health

        self.health = Health()  # link health (analysis/health.py): outages, live

    def update(self, d: Decoded) -> None:
        from sharedlink.analysis.health import feed_decoded

        key = (d.conv, d.src, d.dst)
        feed_decoded(self.health, d)
        st = self.dirs.get(key)
        if st is None:
            if len(self.dirs) >= MAX_CONVERSATIONS:  # as the decoder: a direction past it keeps no state
                self.unshown += 1
                return
            st = self.dirs[key] = DirStat(d.pair, d.conv)
        ts = d.ts_ns
        self.frames += 1
        st.frames += 1
        st.last_ns = ts
        sec = ts // NS
        if sec != st.second:
            self._roll(st, sec)
        st.in_second += 1
        if d.checksum_ok is False:
            st.bad += 1
            st.bad_ns = ts
            return
        if d.late:
            st.late += 1
            st.late_ns = ts
        if d.sync_gap_ns is not None and d.sync_gap_ns > self.gap_ns:
            st.gaps += 1
            st.gap_ns = ts
        if d.kind not in VALUE_KINDS:
            return
        vars_ = st.vars
        for u in d.updates:
            if u.carried or u.text is None:
                continue
            vs = vars_.get(u.name)
            if vs is None:
                if len(vars_) >= MAX_NAMES:  # a name the decoder did not store either
                    continue
                vs = vars_[u.name] = VarStat()
            vs.updates += 1
            if u.text != vs.text:
                vs.text, vs.changed_ns = u.text, ts

    def _roll(self, st: DirStat, sec: int) -> None:
        fresh = sec == st.second + 1
        st.fps = float(st.in_second) if fresh else 0.0
        for vs in st.vars.values():
            vs.rate = float(vs.updates) if fresh else 0.0
            vs.updates = 0
        st.in_second = 0
        st.second = sec

    def render(self, now_ns: int, height: int | None = None) -> Any:
        """The view at ``now_ns``, in at most about ``height`` lines (the terminal's: rich draws
        every row it is given, 7 s for a direction of 4,096 names, so a direction's rows past the
        room left, and the directions past it, are summed up in one line each)."""
        from rich.console import Group
        from rich.table import Table
        from rich.text import Text

        from sharedlink.present import count

        head = f"{self.title}: {count(self.frames)} frames, {count(self.stats.noise)} noise"
        if self.unshown:
            head += f" ({self.unshown} of directions past {MAX_CONVERSATIONS} not shown)"
        parts: list[Any] = [Text(head, style="bold")]
        if self.stats.dropped or self.stats.limits.total or self.stats.unserved:
            parts.append(Text(self.stats.summary(), style="bold red"))
        room = (height if height is not None else 1 << 62) - len(parts) - 1  # (one for "more directions")
        hl = round(HIGHLIGHT_S * NS)
        for i, st in enumerate(self.dirs.values()):
            if room < 4:  # its two lines, the table's header and one row
                parts.append(Text(f"... {len(self.dirs) - i} more directions", style="dim"))
                break
            if now_ns // NS > st.second + 1:
                self._roll(st, now_ns // NS)
            head = Text(f"{st.pair}  {' '.join(map(str, st.conv))}", style="bold cyan")
            line = Text(f"  {st.fps:.0f} frames/s  ")
            for label, n, at in (("checksum failures", st.bad, st.bad_ns), ("late syncs", st.late, st.late_ns),
                                 ("late full sets", st.gaps, st.gap_ns)):
                line.append(f"{label} {count(n)}", style="bold white on red" if now_ns - at < hl else ("red" if n else ""))
                line.append("  ")
            line.append(f"last frame {_age(now_ns - st.last_ns)} ago")
            self._link_quality(line, st, now_ns)
            parts += [head, line]
            t = Table(box=None, pad_edge=False, show_header=True, header_style="dim")
            t.add_column("variable")
            t.add_column("value", justify="right")
            t.add_column("changed", justify="right")
            t.add_column("rate", justify="right")
            rows = room - 3
            more = len(st.vars) - rows + 1 if len(st.vars) > rows else 0
            for j, (name, vs) in enumerate(st.vars.items()):
                if more and j == rows - 1:
                    t.add_row(Text(f"... {more} more variables", style="dim"), "", "", "")
                    break
                fresh = now_ns - vs.changed_ns < hl
                t.add_row(name, Text(vs.text or "", style="bold green" if fresh else ""), _age(now_ns - vs.changed_ns) + " ago",
                          f"{vs.rate:.0f}/s")
            parts.append(t)
            room -= 3 + min(len(st.vars), rows)
        return Group(*parts)


    def _link_quality(self, line: Any, st: DirStat, now_ns: int) -> None:
        """Link health's live line: the direction's outages, and while one lasts how long."""
        from sharedlink.analysis.health import live_down_s

        h = self.health.links.get((st.conv, *st.pair.split(">")))
        if h is None:
            return
        down = live_down_s(h, now_ns)
        n = len(h.outages) + (1 if down is not None else 0)
        line.append(f"  outages {n}", style="red" if n else "")
        if down is not None:
            line.append(f"  LINK DOWN {down:.1f} s", style="bold white on red")


def _age(ns: int) -> str:
    s = max(ns, 0) / NS
    if s < 10:
        return f"{s:.1f} s"
    if s < 3600:
        return f"{s:.0f} s"
    return f"{s / 3600:.1f} h"


# -- the loop --------------------------------------------------------------------------------


@dataclass
class WatchStats:
    """The loop's counts: frames decoded, noise (datagrams or records that are no frame),
    datagrams ``dropped`` because the watch fell behind (its backlog full or too old, or the
    kernel's receive buffer full: ``number`` skips them), and the decoder's ``limits`` (input
    past a bound of issue 31, dropped)."""

    frames: int = 0
    noise: int = 0
    dropped: int = 0
    limits: LimitCounts = field(default_factory=LimitCounts)
    unserved: int = 0  # frames of directions past the Foxglove server's channels (--foxglove)
    detail: str = ""  # what ``dropped`` is made of (a live source's Backlog.breakdown)

    def summary(self) -> str:
        """What the watch dropped, for its last line ("" when nothing was)."""
        parts = []
        if self.dropped:
            parts.append(f"{self.dropped} datagrams dropped (the watch fell behind{': ' + self.detail if self.detail else ''})")
        past = {k: v for k, v in self.limits.to_dict().items() if v}
        if past:
            parts.append("input past a limit dropped: " + ", ".join(f"{k} {v}" for k, v in past.items()))
        if self.unserved:
            parts.append(f"{self.unserved} frames of directions past {FOXGLOVE_CHANNELS} Foxglove channels not served")
        return "; ".join(parts)


#: channels the live Foxglove server opens at most (three a direction, one a session topic; as
#: an MCAP file): the frames of a direction past them are counted, not served
FOXGLOVE_CHANNELS = 65535


def served(output: Callable[[Any], None], stats: WatchStats) -> Callable[[Any], None]:
    """``output`` (a :class:`~sharedlink.analysis.foxglove_channels.FoxgloveChannels` method,
    its ``max_channels`` set) with what it refuses past its channels counted in
    ``stats.unserved`` instead of stopping the watch."""
    from sharedlink.errors import UsageError

    def out(item: Any) -> None:
        try:
            output(item)
        except UsageError:
            stats.unserved += 1

    return out


def run_watch(
    source: Any,
    decoder: Decoder,
    outputs: list[Callable[[Decoded], None]],
    tick: Callable[[int], None] | None = None,
    interval: float = 0.25,
    stats: WatchStats | None = None,
    out: IO[str] | None = None,
    session_outputs: Sequence[Callable[[SessionMessage], None]] = (),
) -> WatchStats:
    """Decode ``source`` 's batches into ``outputs`` until it ends (a capture) or Ctrl-C
    (KeyboardInterrupt propagates: the caller cleans up). ``stats`` counts what was decoded and
    what was dropped (a live source's :class:`Backlog`, the decoder's limits) as it goes, so an
    output may read it. ``tick(now_ns)`` is called at most
    every ``interval`` seconds, after every batch when the source is idle, and once more at the
    end (Ctrl-C too: the last view shows every frame counted).

    Ctrl-C never stops a batch half done: a replay's :class:`~sharedlink.replay.SigintGate`
    holds it while the batch is decoded, counted, handed to every output and flushed (a JSON
    line longer than the pipe's buffer was cut in two when Ctrl-C came while the reader lagged),
    and raises once that is done; waiting for the source still ends at the key press.

    A source's P2OS and blackboard messages (:class:`SessionMessage`) go to ``session_outputs``
    (not counted as frames)."""
    stats = stats if stats is not None else WatchStats()
    stats.limits = decoder.limits
    backlog: Backlog | None = getattr(source, "backlog", None)
    next_tick = time.monotonic()
    gate = SigintGate()
    try:
        with gate:
            for batch in source.batches(interval):
                gate.held = True  # Ctrl-C waits until this batch is counted, written and flushed
                try:
                    if backlog is not None and stats.dropped != backlog.dropped:
                        stats.dropped, stats.detail = backlog.dropped, backlog.breakdown()
                    _decode_batch(batch, decoder, outputs, session_outputs, stats)
                    if out is not None and batch:
                        out.flush()
                    if tick is not None and time.monotonic() >= next_tick:
                        tick(source.now_ns())
                        next_tick = time.monotonic() + interval
                finally:
                    gate.held = False
                if gate.pending:
                    raise KeyboardInterrupt
                if getattr(source, "done", False):
                    break
    except KeyboardInterrupt:
        if backlog is not None:  # received, never decoded: dropped too
            stats.dropped = backlog.dropped + len(backlog)
            stats.detail = backlog.breakdown() + f", {len(backlog)} left at the end"
        if tick is not None:
            tick(source.now_ns())
        raise
    if tick is not None:
        tick(source.now_ns())
    return stats


def _decode_batch(batch: Batch, decoder: Decoder, outputs: list[Callable[[Decoded], None]],
                  session_outputs: Sequence[Callable[[SessionMessage], None]], stats: WatchStats) -> None:
    """:func:`run_watch`'s step for one batch: each frame decoded, counted and handed to every
    output (a live UDP source's raw datagrams through ``decoder.datagram``), each session
    message to every session output, the rest counted as noise."""
    decode, datagram = decoder.decode, getattr(decoder, "datagram", None)
    for item in batch:
        if isinstance(item, RawDatagram):
            for d in datagram(item):  # type: ignore[misc]
                if isinstance(d, Decoded):
                    stats.frames += 1
                    for o in outputs:
                        o(d)
                else:
                    stats.noise += 1
            continue
        if item.__class__ is SessionMessage:
            for so in session_outputs:
                so(item)  # type: ignore[arg-type]
            continue
        if item.frame is None:
            stats.noise += 1
            continue
        d = decode(item)
        stats.frames += 1
        for o in outputs:
            o(d)
