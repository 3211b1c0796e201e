"""Issue 42 item 4 (real material): the 200-byte limit is the robot's rule for client commands.
p2os.lua in the real tshark and the Python codec on tests/vectors/p2os.json: a server packet with
a byte count from 201 to 255 decodes with no "P2OS ignores this packet" expert (the heuristic
takes it, first in a conversation on another port); a command over 200 keeps it; counts of 0x80
and more checksum right (ARIA reported them as bad checksums until January 2025)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import LINKTYPE_USER0, PcapngWriter, PcapWriter
from sharedlink.protocols import p2os

REPO = Path(__file__).resolve().parents[2]
EXTRA = ["-X", f"lua_script:{REPO / 'dissector' / 'p2os.lua'}"]
USER0 = {"uat:user_dlts": '"User 0 (DLT=147)","p2os","0","","0",""'}
VECTORS = json.loads((REPO / "tests" / "vectors" / "p2os.json").read_text())["vectors"]
IGNORES = "P2OS ignores this packet"
NAMES = ["p2os.header", "p2os.count", "p2os.direction", "p2os.checksum.status", "_ws.expert.message"]


def _tcp(path: Path, sessions: list[list[tuple[bool, bytes]]], port: int) -> Path:
    """Each session a TCP conversation of its own (client port 40000 + its index), one after
    the other."""
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for k, events in enumerate(sessions):
            evs = [(10**18 + (k * 100 + i) * 10_000_000, c, p) for i, (c, p) in enumerate(events)]
            for ts, _, frame in session_frames(evs, "tcp", ("127.0.0.1", 40000 + k), ("127.0.0.1", port)):
                w.write(ts, frame)
    return path


def _packets(rows: list[dict]) -> list[dict]:
    return [r for r in rows if r["p2os.header"]]


def test_vectors_say_what_the_codec_says():
    for v in VECTORS:
        raw = bytes.fromhex(v["hex"])
        pkt = p2os.parse_packet(raw)
        assert pkt.count == v["count"] == raw[2]
        assert pkt.ok is (v["checksum"] == "good"), v["name"]
        assert pkt.ignored(v["direction"] == "client") is v["ignored"], v["name"]
    counts = {v["count"] for v in VECTORS}
    assert 0x89 in counts and 0xF0 in counts and any(c > 200 for c in counts)


@pytest.mark.parametrize("port", [8101, 9000])
def test_each_vector_alone_on_tcp(tmp_path, port):
    """One conversation a vector (a bad checksum after a good packet: the heuristic needs one),
    the conversations one after the other in one capture (one tshark run; p2os.lua keeps each
    conversation's state apart); the count, the checksum status and the expert as the vector says."""
    good = bytes.fromhex(VECTORS[0]["hex"])
    sessions = []
    for v in VECTORS:
        client = v["direction"] == "client"
        raw = bytes.fromhex(v["hex"])
        sessions.append([(client, raw)] if v["checksum"] == "good" else [(True, good), (client, raw)])
    rows = _packets(tu.fields(_tcp(tmp_path / "vectors.pcap", sessions, port), [*NAMES, "tcp.srcport", "tcp.dstport"],
                              extra=EXTRA))
    for i, v in enumerate(VECTORS):
        client = v["direction"] == "client"
        mine = [r for r in rows if str(40000 + i) in r["tcp.srcport"] + r["tcp.dstport"]]
        assert mine, v["name"]
        row = mine[-1]
        assert row["p2os.count"] == [str(v["count"])], v["name"]
        assert row["p2os.direction"] == ["0" if client else "1"], v["name"]
        assert row["p2os.checksum.status"] == ["1" if v["checksum"] == "good" else "0"], v["name"]
        ignored = any(IGNORES in m for m in row["_ws.expert.message"])
        assert ignored is v["ignored"], (v["name"], row["_ws.expert.message"])


def test_vectors_on_a_serial_line(tmp_path):
    path = tmp_path / "serial.pcapng"
    with open(path, "wb") as fh:
        w = PcapngWriter(fh, LINKTYPE_USER0)
        for i, v in enumerate(VECTORS):
            w.write(10**18 + i * 1000, bytes.fromhex(v["hex"]), 2 if v["direction"] == "client" else 1)
    rows = _packets(tu.fields(path, NAMES, prefs=USER0, extra=EXTRA))
    assert len(rows) == len(VECTORS)
    for v, row in zip(VECTORS, rows):
        assert row["p2os.checksum.status"] == ["1" if v["checksum"] == "good" else "0"], v["name"]
        assert any(IGNORES in m for m in row["_ws.expert.message"]) is v["ignored"], v["name"]
