"""The `watch --foxglove` server from a test's side (test_foxglove_server.py,
test_foxglove_p2os_poses.py, test_watch_link_quality.py): the command with its server's port,
the channels a client sees advertised, and the messages of one subscribed channel; and what the
same messages look like in an exported MCAP file (the outage gaps, the link_quality topics)."""

from __future__ import annotations

import json
import math
import signal
import struct
import subprocess
import sys
import time

from websockets.exceptions import ConnectionClosed

CLI = [sys.executable, "-m", "sharedlink"]


class Watch:
    """``sharedlink watch ARGS --foxglove --foxglove-port 0`` with its server's port."""

    def __init__(self, *args: object) -> None:
        self.p = subprocess.Popen([*CLI, "watch", *map(str, args), "--json", "--foxglove", "--foxglove-port", "0"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        while True:
            line = self.p.stderr.readline()  # type: ignore[union-attr]
            assert line, f"watch ended early: rc={self.p.poll()}"
            if "Foxglove WebSocket server on ws://" in line:
                self.port = int(line.strip().rsplit(":", 1)[1])
                return

    def stop(self, ends: bool = False) -> str:
        """Ctrl-C, or (``ends``) the capture's end; its stderr after the server line."""
        if ends:
            _out, err = self.p.communicate(timeout=60)
            assert self.p.returncode == 0, err
        else:
            self.p.send_signal(signal.SIGINT)
            _out, err = self.p.communicate(timeout=60)
            assert self.p.returncode == 0, err  # Ctrl-C ends a watch (as tcpdump)
        assert "Traceback" not in err, err
        return err


def advertised(ws, until: set[str] | None = None, seconds: float = 10.0) -> dict[str, dict]:
    """Channels advertised within ``seconds`` (sooner once every topic of ``until`` is there)."""
    chans: dict[str, dict] = {}
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not (until is not None and until <= set(chans)):
        try:
            m = ws.recv(timeout=max(0.05, deadline - time.monotonic()))
        except TimeoutError:
            break
        if isinstance(m, str):
            j = json.loads(m)
            if j["op"] == "advertise":
                chans.update({c["topic"]: c for c in j["channels"]})
            elif j["op"] == "unadvertise":
                for topic in [t for t, c in chans.items() if c["id"] in j["channelIds"]]:
                    del chans[topic]
    return chans


def subscribed(ws, channel: dict, sub: int = 5, timeout: float = 30) -> list[tuple[int, bytes]]:
    """Subscribe to ``channel`` (as ``sub``) and read its messages until the server closes (the
    capture ended), properly (a close frame): (log time in ns, the message's payload) each.
    ``timeout`` guards a hang between two messages."""
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": sub, "channelId": channel["id"]}]}))
    got: list[tuple[int, bytes]] = []
    while True:
        try:
            m = ws.recv(timeout=timeout)
        except ConnectionClosed as exc:
            assert exc.rcvd is not None, exc
            return got
        if isinstance(m, bytes):
            op, sid, log_time = struct.unpack_from("<BIQ", m)
            assert (op, sid) == (1, sub)
            got.append((log_time, m[13:]))


def wait_for_channel(port: int, topic: str, seconds: float = 30) -> None:
    """Return once ``topic`` is advertised, seen by a client of its own: a client that subscribes
    should connect after that. foxglove-sdk's server (0.30) can refuse a subscription to a
    channel made while the client was connecting ("attempted to subscribe to unknown channel" in
    its log, nothing said to the client: 1 run in 4 for a P2OS session's channels, all made in
    the capture's first 40 ms), never one made before the client connected (8 runs in 8)."""
    from websockets.sync.client import connect

    with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.websocket.v1"]) as probe:
        assert topic in advertised(probe, {topic}, seconds=seconds), f"{topic} not advertised in {seconds} s"


#: an MCAP values message's timestamps are ns; an outage's start in stats' seconds
NS = 10**9


def is_gap(doc: dict) -> bool:
    return "NaN" in doc.values()


def check_gaps(values: list[tuple[int, dict]], outages: list[dict]) -> None:
    """One gap message an outage, right after its start (the frame before the silence), before
    the frame after it; its keys the numeric variables of the message before it, each NaN as a
    plotting tool reads it; nothing else NaN."""
    gaps = [(i, t) for i, (t, doc) in enumerate(values) if is_gap(doc)]
    assert len(gaps) == len(outages), (gaps, outages)
    for (i, t), o in zip(gaps, sorted(outages, key=lambda o: o["start"])):
        assert abs(t - 1 - o["start"] * NS) < 1000  # (stats gives seconds with a float's digits)
        t0, before = values[i - 1]
        assert t0 == t - 1
        doc = values[i][1]
        assert set(doc) == {n for n, v in before.items() if type(v) in (int, float)} and doc
        assert all(v == "NaN" and math.isnan(float(v)) for v in doc.values())
        if o["end"] is not None:
            assert abs(values[i + 1][0] - o["end"] * NS) < 1000  # the next sample: the frame after it
        else:
            assert i == len(values) - 1


def quality_topics(path) -> tuple[dict[str, list], dict[str, dict]]:
    """The link_quality messages of an MCAP file per topic ((log time, JSON) each), each validated
    against its schema (``sharedlink.LinkQuality``, JSON), and each topic's channel metadata."""
    import jsonschema
    from mcap.reader import make_reader

    got: dict[str, list] = {}
    meta: dict[str, dict] = {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if channel.topic.endswith("/link_quality"):
                doc = json.loads(message.data)
                jsonschema.validate(doc, json.loads(schema.data))
                assert schema.name == "sharedlink.LinkQuality" and channel.message_encoding == "json"
                got.setdefault(channel.topic, []).append((message.log_time, doc))
                meta[channel.topic] = dict(channel.metadata)
    return got, meta
