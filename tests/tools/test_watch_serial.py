"""`sharedlink watch --serial`: frames written to a pty, split across writes, come out as JSON lines."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from sl_pipes import read_lines

from sharedlink.protocols.codec import encode_named

CLI = [sys.executable, "-m", "sharedlink"]


def test_serial_frames_split_across_writes():
    master, slave = os.openpty()
    name = os.ttyname(slave)
    w = subprocess.Popen([*CLI, "watch", "--serial", name, "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = w.stderr.readline()  # type: ignore[union-attr]
        assert "serial" in line, line
        frames = [encode_named("A", "B", [("AutoGpsLat", 2, f"38.{i:04d}"), ("AutoGpsLon", 2, "-77.5")]) for i in range(20)]
        data = b"noise" + b"".join(frames)
        for k in range(0, len(data), 7):  # frames cut across writes
            os.write(master, data[k : k + 7])
            time.sleep(0.002)  # (pacing, so that the reads cut the frames too: no wait for anything)
        shown = read_lines(w.stdout.fileno(), len(frames))  # type: ignore[union-attr]
    finally:
        w.send_signal(signal.SIGINT)
        out, err = w.communicate(timeout=60)
        os.close(master)
        os.close(slave)
    assert w.returncode == 0, err  # Ctrl-C ends a watch as it does tcpdump
    rows = [json.loads(x) for x in (shown.decode() + out).splitlines()]
    assert [r["values"]["AutoGpsLat"] for r in rows] == [float(f"38.{i:04d}") for i in range(20)]
    assert all(r["checksum"] == "good" and (r["src"], r["dst"]) == ("B", "A") for r in rows)
