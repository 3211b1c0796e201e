"""Frames on time, for ``sharedlink replay``'s timed modes (:mod:`sharedlink.replay`, over UDP,
serial or TCP alike): :class:`Schedule` gives each frame its deadline, :class:`Pacer` sleeps until
shortly before it and spins for the rest, and :func:`latency_hints` asks Linux for prompt
wake-ups while the frames are sent."""

from __future__ import annotations

import os
import platform
import struct
import time
from collections.abc import Iterator
from contextlib import contextmanager

from sharedlink.capture.pcapio import NS

SPIN_MARGIN_NS = 40_000  # spin this much longer than sleeps are expected to overshoot
SPIN_MAX_NS = 1_000_000  # never spin longer than this before a deadline
SPIN_SHARE = 0.02  # ... nor longer than this share of the gap since the previous frame

_SCHED_ATTR = struct.Struct("IIQiIQQQII")  # struct sched_attr (version 1, 56 bytes)
_SCHED_SYSCALLS = {"x86_64": (314, 315), "aarch64": (274, 275)}  # sched_setattr, sched_getattr


@contextmanager
def latency_hints(realtime: bool = False, slice_ns: int = 100_000, slack_ns: int = 1000) -> Iterator[bool]:
    """Ask Linux to wake this thread promptly, for its lifetime inside the block; a no-op
    elsewhere, and everything is restored afterwards.

    Without privileges: sleeps end within ``slack_ns`` of the asked time (timer slack, 50 us
    by default), and the scheduler slice is ``slice_ns`` (EEVDF custom slice, Linux 6.12+), so
    a task that wakes may preempt others sooner. With ``realtime``, the thread also asks for
    SCHED_FIFO, which wins against CPU-bound tasks on a busy machine but needs root,
    CAP_SYS_NICE or an RLIMIT_RTPRIO; the block's value says whether it was granted."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        prctl, syscall = libc.prctl, libc.syscall
    except (OSError, AttributeError):
        yield False
        return
    old_slack = prctl(30, 0, 0, 0, 0)  # PR_GET_TIMERSLACK
    if old_slack > 0:
        prctl(29, slack_ns, 0, 0, 0)  # PR_SET_TIMERSLACK
    old_attr = None
    nrs = _SCHED_SYSCALLS.get(platform.machine())
    if nrs:
        buf = ctypes.create_string_buffer(_SCHED_ATTR.size)
        if syscall(nrs[1], 0, buf, _SCHED_ATTR.size, 0) == 0:
            attr = list(_SCHED_ATTR.unpack(buf.raw))
            if attr[1] == 0:  # SCHED_OTHER: keep its nice value, set the slice
                old_attr = buf.raw
                attr[0], attr[2], attr[5] = _SCHED_ATTR.size, 0, slice_ns
                if syscall(nrs[0], 0, ctypes.create_string_buffer(_SCHED_ATTR.pack(*attr)), 0) != 0:
                    old_attr = None
    granted = False
    if realtime and hasattr(os, "sched_setscheduler"):
        try:
            old_policy, old_param = os.sched_getscheduler(0), os.sched_getparam(0)
            prio = min(10, os.sched_get_priority_max(os.SCHED_FIFO))
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
            granted = True
        except OSError:
            pass
    try:
        yield granted
    finally:
        if granted:
            try:
                os.sched_setscheduler(0, old_policy, old_param)
            except OSError:
                pass
        if old_slack > 0:
            prctl(29, old_slack, 0, 0, 0)
        if old_attr is not None and nrs:
            syscall(nrs[0], 0, ctypes.create_string_buffer(old_attr), 0)


class Pacer:
    """Waits for absolute deadlines on the monotonic clock without busy-waiting a core: it
    sleeps until shortly before the deadline, then spins for the rest. How early it wakes
    follows how late sleeps actually end on this machine (a running estimate), plus a margin,
    and never more than ``SPIN_SHARE`` of the gap since the previous deadline (bounding CPU
    use) nor more than ``SPIN_MAX_NS``."""

    def __init__(self) -> None:
        self.late_ns = 60_000  # estimate of how late a sleep ends

    def wait(self, deadline: int, gap: int) -> None:
        clock = time.monotonic_ns
        now = clock()
        left = deadline - now
        if left <= 0:
            return
        early = min(self.late_ns + SPIN_MARGIN_NS, SPIN_MAX_NS, int(gap * SPIN_SHARE))
        if left > early:
            wake = deadline - early
            time.sleep((wake - now) / NS)
            late = clock() - wake
            # a running mean that one preempted sleep cannot blow up
            late = min(late, 2 * self.late_ns + SPIN_MARGIN_NS)
            self.late_ns += (late - self.late_ns) >> 3
        while clock() < deadline:
            pass


class Schedule:
    """The deadlines of a timed replay's frames on the monotonic clock. Each is absolute,
    computed from its pass's first frame, so timing errors never add up with the number of
    frames: the capture's times divided by ``speed``, or one every ``interval`` ns (a fixed
    rate); never before the previous frame's (out-of-order times). The first deadline is when the
    first frame is ready; a pass after the first starts the first pass's mean gap between frames
    and ``delay_ns`` after the previous pass's last frame."""

    __slots__ = ("interval", "inv_speed", "delay_ns", "base", "prev", "mean_gap", "passes", "first_ts", "last_ts",
                 "count")

    def __init__(self, interval: float | None = None, speed: float = 1.0, delay_ns: int = 0) -> None:
        self.interval, self.inv_speed, self.delay_ns = interval, 1.0 / speed, delay_ns
        self.base = self.prev = -1  # the deadlines of the pass's first frame and of the previous frame
        self.mean_gap = 0
        self.passes = 0  # passes ended
        self.first_ts: int | None = None  # the pass's first frame's capture time
        self.last_ts = -(1 << 63)  # the pass's latest capture time
        self.count = 0  # the pass's frames so far

    def next(self, ts_ns: int) -> tuple[int, int]:
        """(deadline, gap since the previous deadline) of the pass's next frame, whose time in
        the capture is ``ts_ns``."""
        if self.first_ts is None:
            self.first_ts = ts_ns
            if self.base < 0:  # the schedule starts when the first frame is ready
                self.base = self.prev = time.monotonic_ns()
        if ts_ns > self.last_ts:
            self.last_ts = ts_ns
        if self.interval is not None:
            deadline = self.base + round(self.count * self.interval)
        else:
            deadline = self.base + round((ts_ns - self.first_ts) * self.inv_speed)
        prev = self.prev
        if deadline < prev:  # out-of-order timestamps: keep the schedule monotonic
            deadline = prev
        self.count += 1
        self.prev = deadline
        return deadline, deadline - prev

    @property
    def flat(self) -> int:
        """In capture timing, the pass's frames when there are several and their times never
        advanced past the first frame's (all of them at one time: sent back to back); else 0."""
        return self.count if self.interval is None and self.count > 1 and self.last_ts == self.first_ts else 0

    def end_pass(self) -> None:
        """The pass is over: the next starts one mean gap (the first pass's) and ``delay_ns``
        after its last deadline."""
        if self.passes == 0:
            n = self.count
            self.mean_gap = round(self.interval) if self.interval is not None else (
                (self.prev - self.base) // (n - 1) if n > 1 else 0)
        self.passes += 1
        self.base = self.prev + self.mean_gap + self.delay_ns
        self.first_ts, self.last_ts, self.count = None, -(1 << 63), 0
