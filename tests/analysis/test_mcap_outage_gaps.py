"""Issue 43: no line across an outage in the MCAP value channels. Plotting tools join a series'
samples by straight lines; each outage of a link puts one gap message on its direction's
``values`` topic, 1 ns after the outage's start, every numeric variable the text "NaN" (Foxglove's
Plot reads a string as a number: NaN, where it leaves its line open). Read back with the
independent ``mcap`` reader in log-time order, against ``stats --json``'s outages; and live, from
``watch --foxglove`` with a real WebSocket client."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import time
from functools import partial

import pytest
import sl_cli
from sl_cli import CLI
from sl_foxglove import check_gaps

mcap_reader = pytest.importorskip("mcap.reader")

NS = 10**9


#: every run here must succeed
run_cli = partial(sl_cli.run_cli, check=True)


@pytest.mark.parametrize("gen", [
    ["--duration", "30", "--outage", "10:3", "--outage", "20:2"],
    ["--duration", "20", "--transport", "serial", "--rate", "14", "--outage", "5:4"],
    ["--duration", "20", "--transport", "serial", "--outage", "15:5"],
    ["--duration", "15", "+", "--duration", "20", "--src", "A", "--dst", "B", "--rate", "7"],  # B>A open at the end
    ["--duration", "30", "--compress", "--drop", "0.35", "--seed", "4"],  # lossy: outages, maybe
    ["--duration", "10"],  # none
])
def test_mcap_values_break_at_each_outage(tmp_path, gen):
    cap, out = tmp_path / "c.pcapng", tmp_path / "c.mcap"
    parts = " ".join(gen).split(" + ")  # (two captures merged: two directions)
    for i, part in enumerate(parts):
        run_cli("gen", "-o", tmp_path / f"p{i}.pcapng", *part.split())
    if len(parts) == 1:
        (tmp_path / "p0.pcapng").rename(cap)
    else:
        subprocess.run(["mergecap", "-w", cap, *(tmp_path / f"p{i}.pcapng" for i in range(len(parts)))], check=True,
                       timeout=120)
    summary = json.loads(run_cli("export", cap, "-o", out, "--json").stdout)
    outages = json.loads(run_cli("stats", "--json", cap).stdout)["outages"]
    assert bool(outages) == ("--outage" in gen or "--drop" in gen or len(parts) > 1)
    assert ("+" in gen) == any(o["end"] is None for o in outages)
    values: dict[str, list] = {}
    frames: dict[str, int] = {}
    with open(out, "rb") as fh:
        total = 0
        for _schema, channel, message in mcap_reader.make_reader(fh).iter_messages(log_time_order=True):
            total += 1
            if channel.topic.endswith("/values"):
                values.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
            elif channel.topic.endswith("/frames"):
                frames[channel.topic] = frames.get(channel.topic, 0) + 1
    for topic, msgs in values.items():
        pair = topic.split("/")[2].replace("_to_", ">")
        mine = [o for o in outages if o["pair"] == pair]
        check_gaps(msgs, mine)
        assert len(msgs) == frames[topic.replace("/values", "/frames")] + len(mine)  # (no malformed frame here)
    assert summary["rows"] == total  # (the summary counts the gap messages)


@pytest.mark.live
def test_watch_sends_the_gap_live(tmp_path):
    """watch --foxglove: the gap message once the silence is an outage (by the clock), on the
    values topic in order (the last frame's values, the gap, the next frame's)."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    if sys.version_info < (3, 10):
        pytest.skip("foxglove-sdk's server needs Python 3.10+")
    cap = tmp_path / "o.pcap"
    run_cli("gen", "-o", cap, "--duration", "12", "--outage", "6:3")
    outages = json.loads(run_cli("stats", "--json", cap).stdout)["outages"]
    p = subprocess.Popen([*CLI, "watch", "--from", str(cap), "--speed", "1", "--json", "--foxglove", "--foxglove-port",
                          "0"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    got: list[tuple[int, dict]] = []
    try:
        while True:
            line = p.stderr.readline()  # type: ignore[union-attr]
            assert line, f"watch ended early: rc={p.poll()}"
            if "Foxglove WebSocket server on ws://" in line:
                port = int(line.strip().rsplit(":", 1)[1])
                break
        from sl_foxglove import wait_for_channel

        wait_for_channel(port, "/sharedlink/B_to_A/values")  # (a client connected once it exists subscribes)
        with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.websocket.v1"]) as ws:
            chan = None
            deadline = time.monotonic() + 30
            while chan is None and time.monotonic() < deadline:
                m = ws.recv(timeout=30)
                if isinstance(m, str) and json.loads(m)["op"] == "advertise":
                    chan = next((c for c in json.loads(m)["channels"] if c["topic"] == "/sharedlink/B_to_A/values"), None)
            assert chan is not None
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 3, "channelId": chan["id"]}]}))
            while True:
                try:
                    m = ws.recv(timeout=30)
                except ConnectionClosed:
                    break
                if isinstance(m, bytes):
                    _op, _sub, log_time = struct.unpack_from("<BIQ", m)
                    got.append((log_time, json.loads(m[13:])))
    finally:
        _out, err = p.communicate(timeout=60)
    assert p.returncode == 0 and "Traceback" not in err, err
    times = [t for t, _ in got]
    assert times == sorted(times)  # in order on the topic
    seen = [o for o in outages if got[0][0] <= o["start"] * NS]  # (subscribed after the first frames)
    assert len(outages) == 1 and seen
    check_gaps(got, seen)
