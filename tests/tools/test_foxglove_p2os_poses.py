"""Issue 42: `watch --foxglove` of a P2OS link serves the robot's poses as `foxglove.PoseInFrame`
to a client this project did not write (the `websockets` package offering
`foxglove.websocket.v1`), decoded with the official protobuf classes: each pose is a SIP of the
capture at its capture time (x, y in metres from export's `x_mm`, `y_mm`)."""

from __future__ import annotations

import json
import sys

import pytest

if sys.version_info < (3, 10):  # foxglove-schemas-protobuf (the official classes) needs Python 3.10
    pytest.skip("foxglove-schemas-protobuf needs Python 3.10+", allow_module_level=True)
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from sl_cli import run_cli
from sl_foxglove import Watch, advertised, subscribed, wait_for_channel
from websockets.sync.client import connect


@pytest.mark.live
def test_p2os_poses_reach_a_foxglove_client(tmp_path):
    cap = tmp_path / "p.pcap"
    r = run_cli("gen", "-o", str(cap), "-q", "--protocol", "p2os", "--duration", "8", timeout=120)
    assert r.returncode == 0, r.stderr
    rows = tmp_path / "p.jsonl"
    run_cli("export", "-o", str(rows), str(cap), text=False, check=True, timeout=120)
    sips = {row["ts_ns"]: row for line in rows.read_text().splitlines()
            if "x_mm" in (row := json.loads(line)) and row["checksum"] == "good"}
    assert sips
    w = Watch("--from", cap, "--speed", 1)  # 8 s for the client to subscribe (at 2x, 2 s: missed under load)
    try:
        wait_for_channel(w.port, "/p2os/1/pose")  # (a client connected once it exists subscribes)
        with connect(f"ws://127.0.0.1:{w.port}", subprotocols=["foxglove.websocket.v1"]) as ws:
            pose = advertised(ws, {"/p2os/1/pose"})["/p2os/1/pose"]
            assert pose["schemaName"] == "foxglove.PoseInFrame"
            got = [(t, PoseInFrame.FromString(m)) for t, m in subscribed(ws, pose)]
    finally:
        w.stop(ends=True)
    assert len(got) > 5
    for t, p in got:  # every pose a SIP of the capture, at its time
        row = sips[t]
        assert p.pose.position.x == pytest.approx(row["x_mm"] / 1000)
        assert p.pose.position.y == pytest.approx(row["y_mm"] / 1000)
