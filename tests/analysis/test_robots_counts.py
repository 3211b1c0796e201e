"""Issue 42 item 1: P2OS packets and blackboard messages decoded through the core's record walk
(analysis/robots.py hooked into decode._capture_items) count what tshark with p2os.lua,
blackboard.lua and serial.lua counts: the generated sessions (TCP, UDP, serial), the P2OS
vectors (tests/vectors/p2os.json: known-good, ARIA's string commands, byte counts 0x80 and
over), TCP cut at awkward places, and issue 44's loss (a SIP whose position reads ``[:``)."""

from __future__ import annotations

import json
import random
from collections import Counter
from pathlib import Path

import pytest
from sl_robots import tshark_counts, write_tcp

from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file
from sharedlink.protocols.p2os import Sip, build_packet

REPO = Path(__file__).resolve().parents[2]
VECTORS = REPO / "tests" / "vectors" / "p2os.json"


def python_counts(path: Path) -> tuple[Counter, Counter]:
    dec = Decoder(carried=False)
    dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
    p2 = Counter()
    bb = Counter()
    for item in dec.capture(path):
        if isinstance(item, SessionMessage):
            if item.protocol == "p2os":
                p2[(item.side, bool(item.ok))] += 1
            else:
                kind = type(item.message).__name__
                bb[{"SetMessage": "set", "RequestMessage": "request", "Ack": "ack", "ReadResponse": "response"}[kind]] += 1
    return p2, bb


def assert_same(path: Path, serial: bool = False) -> tuple[Counter, Counter]:
    py = python_counts(path)
    ts = tshark_counts(path, serial)
    assert py == ts
    assert sum(py[0].values()) + sum(py[1].values()) > 0
    return py


@pytest.mark.parametrize("transport", ["tcp", "serial"])
def test_generated_p2os_sessions_count_as_tshark(tmp_path, transport):
    path = tmp_path / ("p.pcapng" if transport == "serial" else "p.pcap")
    fmt = "pcapng" if transport == "serial" else "pcap"
    stats = generate_p2os_file(P2osGenOptions(duration=8, transport=transport, fmt=fmt), path)
    p2, bb = assert_same(path, serial=transport == "serial")
    assert sum(p2.values()) == stats.packets and not bb


@pytest.mark.parametrize("transport", ["udp", "tcp", "serial"])
def test_generated_blackboard_sessions_count_as_tshark(tmp_path, transport):
    path = tmp_path / ("b.pcapng" if transport == "serial" else "b.pcap")
    fmt = "pcapng" if transport == "serial" else "pcap"
    stats = generate_blackboard_file(BlackboardGenOptions(duration=8, transport=transport, fmt=fmt, seed=3), path)
    p2, bb = assert_same(path, serial=transport == "serial")
    assert not p2 and sum(bb.values()) == stats.messages


def vector_packets() -> list[tuple[bool, bytes]]:
    """(from the client, packet bytes) of every vector of tests/vectors/p2os.json."""
    table = json.loads(VECTORS.read_text())
    return [(v["direction"] == "client", bytes.fromhex(v["hex"])) for v in table["vectors"]]


@pytest.mark.parametrize("port", [8101, 9000])
def test_vectors_whole_and_cut_count_as_tshark(tmp_path, port):
    """The vectors one a segment, then as one stream per side cut at random (a packet split
    across segments, several packets in one): on the server port and through the heuristic."""
    events = vector_packets()
    whole = tmp_path / "whole.pcap"
    write_tcp(whole, events, port)
    p2, _ = assert_same(whole)
    assert sum(p2.values()) == len(events)
    rng = random.Random(port)
    sides: dict[bool, list[bytes]] = {}
    for side in (True, False):
        stream = b"".join(p for c, p in events if c == side) * 3
        cuts = sorted(set(rng.sample(range(1, len(stream)), len(stream) // 9))) + [len(stream)]
        sides[side] = [stream[a:b] for a, b in zip([0, *cuts], cuts)]
    sides[True][:2] = [sides[True][0] + sides[True][1]]
    cut: list[tuple[bool, bytes]] = [(True, sides[True].pop(0))]  # the heuristic's: a whole packet first
    while sides[True] or sides[False]:  # the two sides interleaved at random, each in its order
        side = rng.choice([s for s in (True, False) if sides[s]])
        cut.append((side, sides[side].pop(0)))
    cutp = tmp_path / "cut.pcap"
    write_tcp(cutp, cut, port)
    p2, _ = assert_same(cutp)
    assert sum(p2.values()) == 3 * len(events)


@pytest.mark.parametrize("port", [8101, 9000])
def test_a_position_reading_open_bracket_colon_stays_p2os(tmp_path, port):
    """Issue 44 (loss): SIPs whose x position bytes are 5B 3A ("[:") and commands around them:
    every segment is P2OS in stats, every packet decoded, as tshark has them."""
    sip = build_packet(Sip(True, 0x3A5B, 0x3A5B, 0, 100, 100, 120, 0, 0, 1, 0, ((1, 0x3A5B),)).encode())
    vel = bytes.fromhex("FAFB060B3B64006F3B")
    events = [(True, vel)] + [(i % 3 != 0, vel if i % 3 == 0 else sip) for i in range(600)]
    path = tmp_path / "bracket.pcap"
    write_tcp(path, events, port)
    p2, _ = assert_same(path)
    assert sum(p2.values()) == len(events)
    st = capture_stats(path)
    assert st.other_protocols["p2os"] == [len(events), sum(len(p) for _, p in events)]
    assert st.frames == 0 and st.noise_segments == 0 and st.kinds == {}


def test_sharedlinks_port_is_never_claimed(tmp_path):
    """A datagram on SharedLink's port that reads as a blackboard message (or a P2OS packet)
    does not take the conversation's frames away: the same frames as without it."""
    from sharedlink.generators.beacon import GenOptions, generate_file
    from sharedlink.protocols.blackboard import SetMessage

    path = tmp_path / "sl.pcap"
    generate_file(GenOptions(frames=40), path)
    from sharedlink.capture.packets import decode_packet
    from sharedlink.capture.pcapio import read_records

    recs = list(read_records(path))
    dg = decode_packet(recs[0].linktype, recs[0].data)
    odd = tmp_path / "odd.pcap"
    with open(odd, "wb") as fh:
        w = PcapWriter(fh)
        evs = [(recs[0].ts_ns - 1000, True, SetMessage(0x1F00, 1, b"\x01\x02\x03").encode()),
               (recs[0].ts_ns - 500, True, bytes.fromhex("FAFB060B3B64006F3B"))]
        for ts, _, frame in session_frames(evs, "udp", (dg.src, dg.sport), (dg.dst, dg.dport)):
            w.write(ts, frame)
        for r in recs:
            w.write(r.ts_ns, r.data)
    assert capture_stats(odd).frames == capture_stats(path).frames == 40
