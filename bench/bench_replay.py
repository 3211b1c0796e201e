"""replay: timing accuracy, drift and CPU of `sharedlink replay` on loopback, and its top speed.

1. 100 beacon frames at the capture's 200 ms spacing, sent by the real CLI (a subprocess) to a
   receiver in this process that takes the kernel's arrival timestamps (SO_TIMESTAMPNS): the
   standard deviation of the inter-arrival error, the drift of the last frame against the
   schedule, and the CPU time the sender used (its rusage) as a share of the wall time.
2. ``--topspeed`` frames per second to a loopback receiver (best of three; the CLI's own figure:
   frames sent over its elapsed time, reading and extracting the capture included).

tcpreplay, the tool users would pick otherwise, needs root and cannot be run side by side here,
so the reference column holds the targets and the ratio is the figure over its target.
"""

from __future__ import annotations

import json
import os
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench import Result
from sharedlink.generators.beacon import GenOptions, generate_file

TIMED_FRAMES = 100
TOP_FRAMES = 200_000
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
CLI = [sys.executable, "-m", "sharedlink", "replay"]


class Receiver(threading.Thread):
    """Counts datagrams on 127.0.0.1; with ``stamps`` keeps each kernel arrival time."""

    def __init__(self, stamps: bool) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        if stamps:
            self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.port = self.sock.getsockname()[1]
        self.stamps = stamps
        self.arrivals: list[int] = []
        self.count = 0
        self.stop = False

    def run(self) -> None:
        recv_into, recvmsg = self.sock.recv_into, self.sock.recvmsg
        buf = bytearray(2048)
        while not self.stop:
            try:
                if self.stamps:
                    _, anc, _, _ = recvmsg(2048, 64)
                    for level, kind, value in anc:
                        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                            sec, nsec = struct.unpack("qq", value[:16])
                            self.arrivals.append(sec * 1_000_000_000 + nsec)
                else:
                    recv_into(buf)
                self.count += 1
            except socket.timeout:
                continue

    def close(self) -> None:
        self.stop = True
        self.join()
        self.sock.close()


class Sender(threading.Thread):
    """Runs the CLI; keeps its JSON summary, wall seconds and CPU seconds (its rusage)."""

    def __init__(self, args: list[str], start_after: float = 0.0) -> None:
        super().__init__(daemon=True)
        self.args, self.start_after = args, start_after
        self.summary: dict = {}
        self.wall = self.cpu = 0.0
        self.error: str | None = None

    def run(self) -> None:
        time.sleep(self.start_after)
        with tempfile.TemporaryFile("w+") as errf:
            t = time.perf_counter()
            p = subprocess.Popen([*CLI, *self.args, "--quiet", "--json"], stdout=subprocess.PIPE, stderr=errf, text=True)
            assert p.stdout is not None
            out = p.stdout.read()
            _, status, usage = os.wait4(p.pid, 0)  # the whole process's CPU time, startup included
            self.wall = time.perf_counter() - t
            p.returncode = os.waitstatus_to_exitcode(status)
            p.stdout.close()
            errf.seek(0)
            err = errf.read()
        if p.returncode != 0:
            self.error = f"sharedlink replay {' '.join(self.args)} exited {p.returncode}: {err.strip()}"
            return
        self.summary = json.loads(out)
        self.cpu = usage.ru_utime + usage.ru_stime


def _timing_rows(label: str, rx: Receiver, sender: Sender) -> list[Result]:
    a = rx.arrivals
    if sender.error:
        raise RuntimeError(sender.error)
    if len(a) != TIMED_FRAMES:
        raise RuntimeError(f"{label}: receiver got {len(a)} of {TIMED_FRAMES} frames")
    period = 200_000_000
    errors_ms = [((b - x) - period) / 1e6 for x, b in zip(a, a[1:])]
    dev = statistics.pstdev(errors_ms)
    drift = abs((a[-1] - a[0]) - (TIMED_FRAMES - 1) * period) / 1e6
    share = 100 * sender.cpu / sender.wall
    s = sender.summary
    return [
        Result(f"replay 200 ms{label}: inter-arrival error stdev", f"{dev:.4f} ms", "<= 0.1 ms", dev / 0.1, "<= 1x", dev <= 0.1),
        Result(f"replay 200 ms{label}: drift of frame 100", f"{drift:.4f} ms", "<= 0.1 ms", drift / 0.1, "<= 1x", drift <= 0.1),
        Result(f"replay 200 ms{label}: sender CPU / wall", f"{share:.2f} % ({sender.cpu:.2f} s)", "< 5 %", share / 5, "< 1x", share < 5),
        Result(
            f"replay 200 ms{label}: sender's lag median/max",
            f"{s['lag_median_ms']:.4f} / {s['lag_max_ms']:.3f} ms",
            "(its own view)",
            s["lag_median_ms"] / 0.1,
            "info",
            True,
        ),
    ]


def timed(work: Path) -> list[Result]:
    """The default run and a --realtime run side by side (100 ms apart), so load on the machine
    hits both alike; the --realtime rows only when this user may have real-time priority."""
    plain_rx, rt_rx = Receiver(stamps=True), Receiver(stamps=True)
    try:
        plain_rx.start()
        rt_rx.start()
        caps = []
        for name, rx in (("plain", plain_rx), ("rt", rt_rx)):
            cap = work / f"replay-timed-{name}.pcap"
            generate_file(GenOptions(frames=TIMED_FRAMES, port=rx.port), cap)  # 200 ms apart
            caps.append(cap)
        plain = Sender([str(caps[0])])
        rt = Sender([str(caps[1]), "--realtime"], start_after=0.1)
        plain.start()
        rt.start()
        plain.join()
        rt.join()
        end = time.monotonic() + 2
        while (len(plain_rx.arrivals) < TIMED_FRAMES or len(rt_rx.arrivals) < TIMED_FRAMES) and time.monotonic() < end:
            time.sleep(0.01)
    finally:
        plain_rx.close()
        rt_rx.close()
    rows = _timing_rows("", plain_rx, plain)
    if rt.summary.get("realtime"):
        rows += [r for r in _timing_rows(" --realtime", rt_rx, rt) if "lag" not in r.name]
    return rows


def topspeed(work: Path) -> list[Result]:
    rx = Receiver(stamps=False)
    rx.start()
    best = per_cpu = 0.0
    received = 0
    try:
        cap = work / "replay-top.pcap"
        generate_file(GenOptions(frames=TOP_FRAMES, port=rx.port), cap)
        for _ in range(3):
            before = rx.count
            sender = Sender([str(cap), "--topspeed"])
            sender.run()
            if sender.error:
                raise RuntimeError(sender.error)
            summary = sender.summary
            time.sleep(0.3)
            per_cpu = max(per_cpu, summary["frames"] / sender.cpu)
            if summary["rate_fps"] > best:
                best, received = summary["rate_fps"], rx.count - before
    finally:
        rx.close()
    return [
        Result(
            "replay --topspeed to loopback",
            f"{best:,.0f} frames/s",
            ">= 100,000 frames/s",
            best / 100_000,
            ">= 1x",
            best >= 100_000,
        ),
        Result(
            "  (frames per CPU second of the sender: what load does not change)",
            f"{per_cpu:,.0f} frames/s",
            "(startup included)",
            per_cpu / 100_000,
            "info",
            True,
        ),
        Result(
            "  (of those, the receiver got)",
            f"{received:,} of {TOP_FRAMES:,}",
            "(UDP drops when it lags)",
            received / TOP_FRAMES,
            "info",
            True,
        ),
    ]


def run(work: Path) -> list[Result]:
    return topspeed(work) + timed(work)
