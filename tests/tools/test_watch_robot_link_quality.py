"""`watch --foxglove` serves a link_quality channel per paced robot link (issues 42 and 43), live,
as for SharedLink links (test_watch_link_quality.py): a real WebSocket client subscribed to a
P2OS capture's /p2os/1/robot_to_client/link_quality gets each second once it has ended, the
outage's seconds while the robot is silent (by the clock: no packet comes), the messages being
the rows `health -o -` lists (and `export --format mcap` writes) for the same seconds."""

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


def watched(cap, topic: str, schema: str = "sharedlink.LinkQuality") -> list[tuple[int, dict]]:
    """The messages of ``topic`` a client subscribed to it as soon as it is advertised gets
    (connected once the channel exists: sl_foxglove.wait_for_channel)."""
    w = Watch("--from", cap, "--speed", 4)
    try:
        wait_for_channel(w.port, topic)
        with connect(f"ws://127.0.0.1:{w.port}", subprotocols=["foxglove.websocket.v1"]) as ws:
            chan = advertised(ws, {topic}, seconds=30).get(topic)
            assert chan is not None and chan["schemaName"] == schema
            return [(t, json.loads(m)) for t, m in subscribed(ws, chan, 7)]
    finally:
        w.stop(ends=True)


@pytest.mark.live
@pytest.mark.parametrize("protocol,pair", [("p2os", "robot>client"), ("blackboard", "slave>master")])
def test_watch_serves_a_robot_links_link_quality(tmp_path, protocol, pair):
    cap = tmp_path / "r.pcapng"
    r = run_cli("gen", "-o", str(cap), "--protocol", protocol, "--duration", "14", "--outage", "7:3", timeout=120)
    assert r.returncode == 0, r.stderr
    rows = [json.loads(x) for x in run_cli("health", "-o", "-", str(cap), timeout=120).stdout.splitlines()]
    want = {row["second"] * NS: {k: row[k] for k in ("frames", "quality", "state", "down_s")} for row in rows
            if row["pair"] == pair}
    topic = f"/{protocol}/1/{pair.replace('>', '_to_')}/link_quality"
    got = watched(cap, topic)
    assert got, "no link_quality message"
    times = [t for t, _ in got]
    assert times == sorted(set(times)) and times == list(range(times[0], times[-1] + NS, NS))  # each second once
    assert all(want[t] == doc for t, doc in got)  # as health (and export) say
    downs = [t for t, doc in got if doc["state"] == "down"]
    assert downs and downs == [t for t, doc in want.items() if doc["state"] == "down"]  # the outage, all its seconds
    assert times[-1] >= max(want) - NS  # all but the last second, which never ended


@pytest.mark.live
def test_watch_breaks_the_sip_lines_at_an_outage(tmp_path):
    """The robot's silence, seen by the clock: one gap message on /p2os/1/sip (every number
    "NaN") 1 ns after the outage's start, as `export --format mcap` writes it."""
    cap = tmp_path / "r.pcapng"
    r = run_cli("gen", "-o", str(cap), "--protocol", "p2os", "--duration", "12", "--outage", "6:3", timeout=120)
    assert r.returncode == 0, r.stderr
    outages = json.loads(run_cli("stats", "--json", str(cap), timeout=120).stdout)["outages"]
    assert len(outages) == 1
    got = watched(cap, "/p2os/1/sip", "p2os.Sip")
    gaps = [(t, doc) for t, doc in got if "NaN" in doc.values()]
    assert len(gaps) == 1 and abs(gaps[0][0] - 1 - outages[0]["start"] * NS) < 1000, gaps
    assert {k for k, v in gaps[0][1].items()} >= {"x_mm", "y_mm", "battery_v"} and set(gaps[0][1].values()) == {"NaN"}
