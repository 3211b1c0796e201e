"""watch: `sharedlink watch` (the live view) taking 10,000 frames/s on loopback.

`sharedlink replay --pps 10000` sends a compressed 30,000-frame beacon capture to the watch's
UDP port on 127.0.0.1; the watch draws its live view (a forced terminal, output to a file). Its
CPU time over the traffic (utime + stime from /proc, the decoding and drawing included) per
frame, times 10,000, is the share of a core 10,000 frames/s take; every frame must be shown
(the view's frame count at Ctrl-C). The rate replay reached is printed beside it (on a loaded
machine it can fall short of 10,000/s; the per-frame figure does not depend on it).
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from bench import Result, load_now, load_since
from sharedlink.generators.beacon import GenOptions, generate_file

FRAMES = 30_000
RATE = 10_000
TARGET_CORES = 0.5


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def shown_frames(view: Path) -> int:
    """The frame count the live view last drew (its head: "...: 30,000 frames, 0 noise", the
    count grouped in thousands as every count people read)."""
    with open(view, "rb") as fh:
        fh.seek(max(0, view.stat().st_size - 20000))
        counts = re.findall(rb": ([\d,]+) frames, ", fh.read())
    return int(counts[-1].replace(b",", b"")) if counts else 0


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(work: Path) -> list[Result]:
    cap = work / "watch.pcap"
    generate_file(GenOptions(frames=FRAMES, compress=True), cap)
    port = free_port()
    env = dict(os.environ, FORCE_COLOR="1", COLUMNS="120", LINES="40")
    view = work / "watch-view.txt"
    started = load_now()
    with open(view, "w") as out:
        w = subprocess.Popen([sys.executable, "-m", "sharedlink", "watch", "--port", str(port)],
                             stdout=out, stderr=subprocess.PIPE, text=True, env=env)
        try:
            while "udp port" not in (w.stderr.readline() or "udp port"):  # type: ignore[union-attr]
                pass
            c0, t0 = cpu_seconds(w.pid), time.perf_counter()
            r = subprocess.run([sys.executable, "-m", "sharedlink", "replay", str(cap), "--to", f"127.0.0.1:{port}",
                                "--pps", str(RATE), "-q"], capture_output=True, text=True)
            sent_s = time.perf_counter() - t0
            shown, changed = 0, time.monotonic()
            while shown < FRAMES and time.monotonic() - changed < 5:  # until every frame is drawn, or none for 5 s
                time.sleep(0.1)
                n = shown_frames(view)
                if n != shown:
                    shown, changed = n, time.monotonic()
            cpu = cpu_seconds(w.pid) - c0
        finally:
            w.send_signal(signal.SIGINT)
            w.wait(timeout=60)
    shown = max(shown, shown_frames(view))
    cores = cpu / FRAMES * RATE
    ok = r.returncode == 0 and shown == FRAMES and w.returncode == 0  # (watch: Ctrl-C is its normal end, exit 0)
    return [
        Result(
            "watch 10k frames/s: CPU cores, no loss" + ("" if ok else f" (SHOWN {shown}/{FRAMES})"),
            f"{cores:.2f} core ({FRAMES / sent_s:,.0f}/s sent)",
            f"{TARGET_CORES} core",
            cores / TARGET_CORES,
            "<= 1x",
            ok and cores <= TARGET_CORES,
            load_since(started),
        )
    ]
