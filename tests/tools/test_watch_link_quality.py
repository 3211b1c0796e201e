"""`watch --foxglove` serves a link_quality channel per link (issue 43), live: a real WebSocket
client (the `websockets` package, as Foxglove's clients speak it) subscribed to it gets each
second once it has ended, the outage's seconds while the link is silent (by the clock: no frame
comes), and the messages are those `export --format mcap` writes and `health -o -` lists for the
same seconds."""

from __future__ import annotations

import json
import sys

import pytest

if sys.version_info < (3, 10):  # (as test_foxglove_server.py: the SDK's server)
    pytest.skip("foxglove-sdk's server needs Python 3.10+", allow_module_level=True)
from sl_cli import run_cli
from sl_foxglove import Watch, advertised, subscribed, wait_for_channel
from websockets.sync.client import connect

NS = 10**9
TOPIC = "/sharedlink/B_to_A/link_quality"


@pytest.mark.live
def test_watch_serves_each_seconds_link_quality(tmp_path):
    cap = tmp_path / "o.pcap"
    r = run_cli("gen", "-o", str(cap), "--duration", "16", "--outage", "10:3", timeout=120)
    assert r.returncode == 0, r.stderr
    want = {row["second"] * NS: {k: row[k] for k in ("frames", "quality", "state", "down_s")} for row in map(
        json.loads, run_cli("health", "-o", "-", str(cap), timeout=120).stdout.splitlines())}
    w = Watch("--from", cap, "--speed", 4)
    try:
        wait_for_channel(w.port, TOPIC)  # (a client connected once it exists subscribes)
        with connect(f"ws://127.0.0.1:{w.port}", subprotocols=["foxglove.websocket.v1"]) as ws:
            chan = advertised(ws, {TOPIC}, seconds=30).get(TOPIC)
            assert chan is not None and chan["schemaName"] == "sharedlink.LinkQuality"
            got = [(t, json.loads(m)) for t, m in subscribed(ws, chan, 7)]
    finally:
        w.stop(ends=True)
    times = [t for t, _ in got]
    assert times == sorted(set(times)) and times == list(range(times[0], times[-1] + NS, NS))  # each second once
    assert all(want[t] == doc for t, doc in got)  # as health (and export) say
    downs = [doc["down_s"] for _t, doc in got if doc["state"] == "down"]
    assert downs == [1.2, 2.2, 3.2]  # the 3 s silence after the frame at 9.8 s, second by second
    assert times[-1] >= max(want) - NS  # all but the last second, which never ended
