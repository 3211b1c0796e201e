"""`watch --foxglove` serves a link_quality channel per link (issue 43), live: a real WebSocket
client (the `websockets` package, as Foxglove's clients speak it) subscribed to it gets each
second once it has ended, the outage's seconds while the link is silent (by the clock: no frame
comes), and the messages are those `export --format mcap` writes and `health -o -` lists for the
same seconds."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import time

import pytest

if sys.version_info < (3, 10):  # (as test_foxglove_server.py: the SDK's server)
    pytest.skip("foxglove-sdk's server needs Python 3.10+", allow_module_level=True)
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

CLI = [sys.executable, "-m", "sharedlink"]
NS = 10**9
TOPIC = "/sharedlink/B_to_A/link_quality"


def test_watch_serves_each_seconds_link_quality(tmp_path):
    cap = tmp_path / "o.pcap"
    r = subprocess.run([*CLI, "gen", "-o", str(cap), "--duration", "16", "--outage", "10:3"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    want = {row["second"] * NS: {k: row[k] for k in ("frames", "quality", "state", "down_s")} for row in map(
        json.loads, subprocess.run([*CLI, "health", "-o", "-", str(cap)], capture_output=True, text=True,
                                   timeout=120).stdout.splitlines())}
    p = subprocess.Popen([*CLI, "watch", "--from", str(cap), "--speed", "4", "--json", "--foxglove", "--foxglove-port",
                          "0"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    got: list[tuple[int, dict]] = []
    try:
        while True:
            line = p.stderr.readline()  # type: ignore[union-attr]
            assert line, f"watch ended early: rc={p.poll()}"
            if "Foxglove WebSocket server on ws://" in line:
                port = int(line.strip().rsplit(":", 1)[1])
                break
        with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.websocket.v1"]) as ws:
            chan = None
            deadline = time.monotonic() + 30
            while chan is None and time.monotonic() < deadline:
                m = ws.recv(timeout=30)
                if isinstance(m, str) and json.loads(m)["op"] == "advertise":
                    chan = next((c for c in json.loads(m)["channels"] if c["topic"] == TOPIC), None)
            assert chan is not None and chan["schemaName"] == "sharedlink.LinkQuality"
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": chan["id"]}]}))
            while True:
                try:
                    m = ws.recv(timeout=30)
                except ConnectionClosed:  # the capture ended: the server closed
                    break
                if isinstance(m, bytes):
                    op, sub, log_time = struct.unpack_from("<BIQ", m)
                    assert (op, sub) == (1, 7)
                    got.append((log_time, json.loads(m[13:])))
    finally:
        _out, err = p.communicate(timeout=60)
    assert p.returncode == 0 and "Traceback" not in err, err
    times = [t for t, _ in got]
    assert times == sorted(set(times)) and times == list(range(times[0], times[-1] + NS, NS))  # each second once
    assert all(want[t] == doc for t, doc in got)  # as health (and export) say
    downs = [doc["down_s"] for _t, doc in got if doc["state"] == "down"]
    assert downs == [1.2, 2.2, 3.2]  # the 3 s silence after the frame at 9.8 s, second by second
    assert times[-1] >= max(want) - NS  # all but the last second, which never ended
