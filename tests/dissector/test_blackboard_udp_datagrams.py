"""Blackboard over UDP, datagram by datagram (tests/vectors/blackboard-udp-datagrams.json; the
rule: docs/fields-p2os-blackboard.md, "Over UDP", as for P2OS): each datagram is read alone; a
read response or a message cut off at a datagram's end is truncated there and its rest, in the
next datagram, is bytes outside any message (a cut message is a malformed one, "Malformed
messages"). blackboard.lua (over UDP) and the Python session
reader give the same messages and answers in the same datagrams; before the rule the Python
reader held a cut-off answer or message and joined it with the side's next datagram, a message
or answer blackboard.lua never shows (bb-edge.pcap's frame 18 in golden_small: a response
blackboard.lua shows truncated)."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import pytest
from sl_robots import OTHERS, write_udp_sessions

import tshark_util as tu
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionReader, iter_sessions
from sharedlink.capture.packets import decode_packet
from sharedlink.capture.pcapio import read_records

REPO = Path(__file__).resolve().parents[2]
VECTORS = json.loads((REPO / "tests" / "vectors" / "blackboard-udp-datagrams.json").read_text())["vectors"]
IDS = [v["name"] for v in VECTORS]
NAMES = ["udp.srcport", "blackboard.type", "blackboard.junk"]
BASE_PORT = 43000
OTHER = ("127.0.0.1", 9100)  # not a blackboard port: the heuristic takes the conversation
NOISE = ("truncated", "junk")
TRUNCATED, NO_CR = "Read response truncated", "Message not ended by CR"


def _raw(p: dict) -> bytes:
    return bytes.fromhex(p["hex"])


def _kind(p: dict) -> str:
    """The blackboard.type blackboard.lua gives a piece ("" for junk)."""
    raw = _raw(p)
    if p["kind"] in ("message", "cut"):
        return "set" if raw[:1] == b":" else "request"
    if p["kind"] == "truncated" or (p["kind"] == "answer" and len(raw) > 1):
        return "response"
    return "ack" if p["kind"] == "answer" else ""


def _want_lua(d: dict) -> tuple[list[str], bytes, bool, bool]:
    """One datagram's types, junk, and whether it has a truncated response / a message with no CR."""
    ps = d["pieces"]
    return ([_kind(p) for p in ps if p["kind"] != "junk"], b"".join(_raw(p) for p in ps if p["kind"] == "junk"),
            any(p["kind"] == "truncated" for p in ps), any(p["kind"] == "cut" for p in ps))


def _want_py(d: dict) -> list[tuple[str, bytes]]:
    """One datagram's messages and answers to the Python reader: (side, raw); a cut message is a
    malformed one (docs/fields-p2os-blackboard.md, "Malformed messages")."""
    return [("master" if p["kind"] in ("message", "cut") else "slave", _raw(p)) for p in d["pieces"]
            if p["kind"] in ("message", "answer", "cut")]


def test_the_vectors_cut_messages_and_answers_at_datagram_ends() -> None:
    """A truncated or cut piece ends its datagram and is shorter than a whole one; at least one
    vector has a cut-off answer, and one a cut-off message, whose rest is the next datagram."""
    for v in VECTORS:
        for d in v["datagrams"]:
            for i, p in enumerate(d["pieces"]):
                if p["kind"] in ("truncated", "cut"):
                    assert i == len(d["pieces"]) - 1, v["name"]
                if p["kind"] == "cut":
                    assert b"\r" not in _raw(p), v["name"]
    cut_then_junk = {(a["pieces"][-1]["kind"], b["pieces"][0]["kind"]) for v in VECTORS
                     for a, b in zip(v["datagrams"], v["datagrams"][1:]) if a["from"] == b["from"]}
    assert {("truncated", "junk"), ("cut", "junk")} <= cut_then_junk


def _capture(path: Path) -> Path:
    sessions = [[(d["from"] == "a", b"".join(_raw(p) for p in d["pieces"])) for d in v["datagrams"]] for v in VECTORS]
    return write_udp_sessions(path, sessions, BASE_PORT, OTHER)


def test_blackboard_lua_and_python_datagram_by_datagram(tmp_path: Path) -> None:
    cap = _capture(tmp_path / "bb-udp.pcap")
    lua: dict[int, list] = defaultdict(list)
    first: dict[int, int] = {}  # the frame number of each conversation's first datagram
    for n, r in enumerate(tu.fields(cap, NAMES, extra=OTHERS, two_pass=True), 1):
        port = int(r["udp.srcport"][0])
        experts = r["_ws.expert.message"]
        lua_row = (list(r["blackboard.type"]), b"".join(bytes.fromhex(j.replace(":", "")) for j in r["blackboard.junk"]),
                   TRUNCATED in experts, NO_CR in experts)
        lua[n].append(lua_row)
        if port != OTHER[1]:
            first.setdefault(port, n)
    py: dict[int, list] = defaultdict(list)
    for m in iter_sessions(cap):
        py[m.number].append((m.side, m.raw))
    core: dict[int, list] = defaultdict(list)  # the decoding core's robot links, datagram by datagram
    links = RobotLinks(messages=True)
    for rec in read_records(cap):
        dg = decode_packet(rec.linktype, rec.data)
        for m in links.datagram(rec.number, rec.ts_ns, dg) or []:  # type: ignore[arg-type]
            core[m.number].append((m.side, m.raw))
    assert core == py
    assert len(core) > 10
    n = 0
    for k, v in enumerate(VECTORS):
        assert first[BASE_PORT + k] == n + 1, v["name"]
        for d in v["datagrams"]:
            n += 1
            assert lua[n] == [_want_lua(d)], (v["name"], n)
            assert py.get(n, []) == _want_py(d), (v["name"], n)


@pytest.mark.parametrize("v", VECTORS, ids=IDS)
def test_python_reader_noise_is_the_junk_and_the_cut_off_pieces(v: dict) -> None:
    """Fed datagram by datagram, the session reader's noise is the vector's junk and truncated
    bytes, and nothing is held after a datagram."""
    reader = SessionReader()
    a, b = ("127.0.0.1", 1), OTHER
    key = ("udp", a, b)
    got = []
    for i, d in enumerate(v["datagrams"]):
        data = b"".join(_raw(p) for p in d["pieces"])
        side = a if d["from"] == "a" else b
        got.append([(m.side, m.raw) for m in reader.feed(key, "udp", side, i + 1, 0, data, None, True)])
        s = reader.sessions[key]
        assert not s.answer and not any(df.buf for df in s.sides.values()), v["name"]
    assert got == [_want_py(d) for d in v["datagrams"]]
    lost = sum(len(_raw(p)) for d in v["datagrams"] for p in d["pieces"] if p["kind"] in NOISE)
    assert reader.noise.get("blackboard", [0, 0])[1] == lost, v["name"]
