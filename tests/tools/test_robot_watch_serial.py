"""Issue 42: `sharedlink watch --serial DEV --json` of a Pioneer's serial line: the P2OS packets
written to a pty, cut across writes, come out as export's JSON lines (the bytes read are the
robot's)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

from sharedlink.protocols.p2os import Encoder, Sip, build_packet

CLI = [sys.executable, "-m", "sharedlink"]


def test_p2os_packets_from_a_serial_port():
    master, slave = os.openpty()
    name = os.ttyname(slave)
    w = subprocess.Popen([*CLI, "watch", "--serial", name, "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    rows = []
    try:
        line = w.stderr.readline()  # type: ignore[union-attr]
        assert "serial" in line, line
        packets = []
        for i in range(10):
            packets.append(build_packet(Sip(True, 1000 + i, 2000, 0, 100, 120, 123).encode()))
            packets.append(build_packet(Encoder(i, -i).encode()))
        data = b"\x00\x01" + b"".join(packets)
        for k in range(0, len(data), 7):  # packets cut across writes
            os.write(master, data[k : k + 7])
        while len(rows) < 20:  # (each line as it comes: no waiting on a clock)
            rows.append(json.loads(w.stdout.readline()))  # type: ignore[union-attr]
    finally:
        w.send_signal(signal.SIGINT)
        w.communicate(timeout=60)
        os.close(master)
        os.close(slave)
    assert [r["type"] for r in rows] == ["SIP", "ENCODER"] * 10
    assert [r["x_mm"] for r in rows[::2]] == list(range(1000, 1010))
    assert all(r["protocol"] == "p2os" and r["side"] == "robot" and r["checksum"] == "good" for r in rows)
