"""P2OS over UDP, datagram by datagram (tests/vectors/p2os-udp-datagrams.json; the rule:
docs/fields-p2os-blackboard.md, "Over UDP"): each datagram is read alone, a packet cut off at a
datagram's end is truncated there and the rest of it, in the next datagram, is junk. p2os.lua
(UDP heuristic, then the conversation) and the Python session reader give the same packets in
the same datagrams; before the rule the Python reader held a cut-off tail and joined it with the
next datagram's bytes, a packet p2os.lua never shows."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import pytest
from sl_robots import OTHERS, write_udp_sessions

import tshark_util as tu
from sharedlink.analysis.sessions import SessionReader, iter_sessions

REPO = Path(__file__).resolve().parents[2]
VECTORS = json.loads((REPO / "tests" / "vectors" / "p2os-udp-datagrams.json").read_text())["vectors"]
IDS = [v["name"] for v in VECTORS]
NAMES = ["udp.srcport", "p2os.count", "p2os.checksum.status", "p2os.junk"]
BASE_PORT = 42000
SERVER = ("127.0.0.1", 9000)  # not 8101: the heuristic takes the conversation


def _datagrams(v: dict) -> list[bytes]:
    return [b"".join(bytes.fromhex(p["hex"]) for p in d["pieces"]) for d in v["datagrams"]]


def _want(d: dict) -> tuple[list[tuple[int, bool]], bytes, int | None]:
    """One datagram's (count, checksum good) of its whole packets, junk, and the truncated
    packet's count byte (-1: cut before it; None: none truncated)."""
    packets, junk, cut = [], b"", None
    for p in d["pieces"]:
        raw = bytes.fromhex(p["hex"])
        if p["kind"] == "junk":
            junk += raw
        elif p["kind"] == "truncated":
            cut = raw[2] if len(raw) > 2 else -1
        else:
            packets.append((raw[2], p["kind"] == "good"))
    return packets, junk, cut


def test_the_vectors_cut_packets_at_datagram_ends() -> None:
    """Each truncated piece ends its datagram and claims more than it holds; at least one vector
    has a cut-off packet whose rest starts the next datagram."""
    for v in VECTORS:
        for d in v["datagrams"]:
            for i, p in enumerate(d["pieces"]):
                raw = bytes.fromhex(p["hex"])
                if p["kind"] == "truncated":
                    assert i == len(d["pieces"]) - 1 and (len(raw) < 3 or raw[2] + 3 > len(raw)), v["name"]
    assert any(d["pieces"][0]["kind"] == "junk" for v in VECTORS for d in v["datagrams"][1:])


def _capture(path: Path) -> Path:
    return write_udp_sessions(path, [[(True, dg) for dg in _datagrams(v)] for v in VECTORS], BASE_PORT, SERVER)


def test_p2os_lua_and_python_datagram_by_datagram(tmp_path: Path) -> None:
    cap = _capture(tmp_path / "udp.pcap")
    rows = [r for r in tu.fields(cap, NAMES, extra=OTHERS, two_pass=True) if r["udp.srcport"]]
    lua: dict[int, list] = defaultdict(list)
    for r in rows:
        status = r["p2os.checksum.status"]
        counts = [int(c) for c in r["p2os.count"]]
        truncated = any(m == "Packet truncated" for m in r["_ws.expert.message"])
        cut = (counts[len(status)] if len(counts) > len(status) else -1) if truncated else None
        lua[int(r["udp.srcport"][0])].append(
            ([(c, s == "1") for c, s in zip(counts, status)],
             b"".join(bytes.fromhex(j.replace(":", "")) for j in r["p2os.junk"]), cut))
    first = {}  # the frame number of each conversation's first datagram
    py: dict[int, list] = defaultdict(list)
    for n, r in enumerate(tu.fields(cap, ["udp.srcport"], extra=OTHERS, two_pass=False), 1):
        first.setdefault(int(r["udp.srcport"][0]), n)
    for m in iter_sessions(cap):
        port = max(int(end.rsplit(":", 1)[1]) for end in m.label.split(" ", 1)[1].split(" - "))
        py[port].append((m.number - first[port], (m.raw[2], bool(m.ok))))
    for k, v in enumerate(VECTORS):
        want = [_want(d) for d in v["datagrams"]]
        assert lua[BASE_PORT + k] == want, v["name"]
        assert py[BASE_PORT + k] == [(i, p) for i, (ps, _j, _c) in enumerate(want) for p in ps], v["name"]


@pytest.mark.parametrize("v", VECTORS, ids=IDS)
def test_python_reader_noise_is_the_junk_and_the_cut_off_packets(v: dict) -> None:
    """Fed datagram by datagram, the session reader's noise is the vector's junk and truncated
    bytes, and nothing is held after a datagram."""
    reader = SessionReader()
    key, side = ("udp", ("127.0.0.1", 1), SERVER), ("127.0.0.1", 1)
    got = []
    for i, dg in enumerate(_datagrams(v)):
        got.append([(m.raw[2], bool(m.ok)) for m in reader.feed(key, "udp", side, i + 1, 0, dg, None, True)])
        assert not reader.sessions[key].sides[side].buf, v["name"]
    assert got == [_want(d)[0] for d in v["datagrams"]]
    lost = sum(len(bytes.fromhex(p["hex"])) for d in v["datagrams"] for p in d["pieces"]
               if p["kind"] in ("junk", "truncated"))
    assert reader.noise.get("p2os", [0, 0])[1] == lost, v["name"]
