"""`watch --foxglove` with clients this project did not write: a WebSocket client (the
`websockets` package) that offers only `foxglove.websocket.v1`, as Foxglove's own FoxgloveClient
and Lichtblick do; the channels `watch --from` serves against those `export --format mcap`
writes for the same capture; the server's log under a flood of bad subscriptions."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

if sys.version_info < (3, 10):  # foxglove-schemas-protobuf (the official classes) needs Python 3.10
    pytest.skip("foxglove-schemas-protobuf needs Python 3.10+", allow_module_level=True)
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from mcap.reader import make_reader
from sl_captures import reference
from sl_cli import run_cli
from sl_foxglove import Watch, advertised, subscribed
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from sharedlink.foxglove_server import offered, rewrite_answer, rewrite_request
from sharedlink.generators.beacon import GenOptions, generate_file


def exported(tmp_path: Path, cap: Path) -> dict[str, str]:
    """Topic -> schema name of `export --format mcap` (the `mcap` reader)."""
    out = tmp_path / "x.mcap"
    r = run_cli("export", str(cap), "-o", str(out), timeout=120)
    assert r.returncode == 0, r.stderr
    with open(out, "rb") as fh:
        summary = make_reader(fh).get_summary()
    return {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("fox") / "drive.pcap"
    generate_file(GenOptions(duration=12, seed=4), path)
    return path


@pytest.mark.live
def test_a_client_offering_only_foxglove_websocket_v1_gets_the_positions(drive):
    # (at 2x the 12 s drive lasts 6 s: at 4x, at load 11, the capture ended before the client's
    # subscription came: "attempted to subscribe to unknown channel")
    w = Watch("--from", drive, "--speed", 2)
    try:
        # the client that offers the new name too still gets it
        with connect(f"ws://127.0.0.1:{w.port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws2:
            assert ws2.subprotocol == "foxglove.sdk.v1"
        with connect(f"ws://127.0.0.1:{w.port}", subprotocols=["foxglove.websocket.v1"]) as ws:
            assert ws.subprotocol == "foxglove.websocket.v1"
            loc = advertised(ws, {"/sharedlink/B_to_A/location"})["/sharedlink/B_to_A/location"]
            assert loc["schemaName"] == "foxglove.LocationFix"
            got = [(t, LocationFix.FromString(m)) for t, m in subscribed(ws, loc, 3)]
    except InvalidStatus as exc:  # pragma: no cover - what the SDK's server alone answers
        pytest.fail(f"handshake refused: {exc}")
    finally:
        err = w.stop(ends=True)
    assert "foxglove:" not in err, err
    want = {fr.ts_ns: fr for fr in reference(drive) if fr.ok}
    assert len(got) > 10
    for t, fix in got:  # every message a valid fix of the capture at its capture time
        assert fix.latitude == float(want[t].values["AutoGpsLat"]) and len(fix.position_covariance) == 9


@pytest.mark.live
def test_a_client_offering_neither_name_is_refused(drive):
    w = Watch("--from", drive, "--speed", 1)
    try:
        with pytest.raises(InvalidStatus):
            with connect(f"ws://127.0.0.1:{w.port}", subprotocols=["something.else"]):
                pass
    finally:
        w.stop()


@pytest.mark.live
@pytest.mark.parametrize("protocol, transport", [("p2os", "tcp"), ("blackboard", "udp"), ("sharedlink", "serial")])
def test_watch_from_serves_the_channels_export_writes_and_none_without_data(tmp_path, protocol, transport):
    cap = tmp_path / f"{protocol}.pcapng"
    r = run_cli("gen", str(cap), "--protocol", protocol, "--transport", transport, "--duration", "6", timeout=120)
    assert r.returncode == 0, r.stderr
    want = exported(tmp_path, cap)
    assert want
    w = Watch("--from", cap, "--speed", 1)  # (the client connects while the 6 s capture plays, under load too)
    chans: dict[str, str] = {}
    try:
        with connect(f"ws://127.0.0.1:{w.port}", subprotocols=["foxglove.websocket.v1"]) as ws:
            while True:  # every channel advertised until the capture's end (the server closes)
                try:
                    m = ws.recv(timeout=30)
                except ConnectionClosed:
                    break
                if isinstance(m, str) and (j := json.loads(m))["op"] == "advertise":
                    chans.update({c["topic"]: c["schemaName"] for c in j["channels"]})
    finally:
        w.stop(ends=True)
    assert chans == want


@pytest.mark.live
def test_a_flood_of_bad_subscriptions_logs_one_line(drive):
    # a fifth of the pace: the 12 s drive outlasts the flood on a busy machine (at 1x the capture
    # could end, and the server with it, before the 10,000 messages were sent)
    w = Watch("--from", drive, "--speed", 0.2)
    try:
        # The SDK answers each bad subscription with a status message; its control queue holds
        # 1024 per client, and a client that falls behind reading them is disconnected (its
        # documented policy). max_queue=None keeps this client reading; if it is dropped all the
        # same on a busy machine, the flood ends there and the log must still say it once.
        with connect(f"ws://127.0.0.1:{w.port}", subprotocols=["foxglove.sdk.v1"], max_queue=None) as ws:
            advertised(ws, {"/sharedlink/B_to_A/frames"})
            answered = 0
            try:
                for i in range(10_000):
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": 999_999}]}))
                while answered < 10_000:  # the server's status answer to each: it has taken them all
                    m = ws.recv(timeout=30)
                    answered += isinstance(m, str) and json.loads(m)["op"] == "status"
            except ConnectionClosed:  # dropped: the flood ended there
                pass
    finally:
        err = w.stop()
    lines = [ln for ln in err.splitlines() if "unknown channel" in ln]
    assert 1 <= len(lines) <= 2, err[-2000:]


def test_handshake_rewriting():
    req = (b"GET / HTTP/1.1\r\nHost: h\r\nSec-WebSocket-Key: k\r\n"
           b"sec-websocket-protocol: foxglove.websocket.v1, other\r\n\r\n")
    head, name = rewrite_request(req)
    assert name == "foxglove.websocket.v1" and offered(head) == ["foxglove.sdk.v1"]
    assert head.startswith(b"GET / HTTP/1.1\r\nHost: h\r\nSec-WebSocket-Key: k\r\n") and head.endswith(b"\r\n\r\n")
    both = req.replace(b"foxglove.websocket.v1, other", b"foxglove.websocket.v1\r\nSec-WebSocket-Protocol: foxglove.sdk.v1")
    assert rewrite_request(both) == (both, None)
    answer = b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\nx: y\r\n\r\n"
    assert rewrite_answer(answer, name) == answer.replace(b"sec-websocket-protocol: foxglove.sdk.v1",
                                                          b"Sec-WebSocket-Protocol: foxglove.websocket.v1")
