"""sharedlink.lua's heuristic and its Python twin (analysis/robots.sharedlink_heuristic, which tells
the core's robot links which conversations SharedLink took: a P2OS packet later in such a
conversation is SharedLink's in tshark, so the core must not claim it for P2OS): each payload
below is sent alone in a UDP conversation of its own (and over TCP) off port 7013, and tshark
shows SharedLink in exactly the frames the twin accepts."""

from __future__ import annotations

from pathlib import Path

from sl_robots import OTHERS

import tshark_util as tu
from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.robots import RobotLinks, sharedlink_heuristic
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.protocols import p2os

GOOD = tu.frame("A", "B", "N0", "T2", "QX", "D1.5")
#: payloads around each rule of the heuristic (looks_like_sharedlink)
PAYLOADS = [
    GOOD, GOOD.rstrip(b"\r\n"), GOOD.rstrip(b"\n"), b"\r\n" + GOOD, b"\r\n\r" + GOOD, b"\n\n" + GOOD,
    b"[:AB]", b"[:AB]\r\n", b"[:AB][:BA]", b"[:AB]x", b"[:AB]\rx", b"[:AQ|D1]", b"[:ab|D1]", b"[:AB D1]",
    b"[:AB|D1\x01]\r\n", b"[:AB|D1\t]\r\n", b"[:AB|D1]\x01", b"[:AB|D1\xc3\xa9]", b"[:AB|D1 no close",
    b"[:AB|", b"[:A", b" [:AB|D1]", b"[AB|D1]", b"[:PP|D1]\n", b"[:AB|D1]\r\n" + b"\xff" * 4,
]
TCP_ONLY = [b"[:AB|D1 no close", b"[:AB|D1\x01 no close", b"[:AB|"]


def _frames(path: Path) -> list[bool]:
    rows = tu.fields(path, ["frame.protocols"], extra=OTHERS, two_pass=True)
    return ["sharedlink" in ":".join(r["frame.protocols"]).split(":") for r in rows]


def test_tshark_shows_sharedlink_where_the_twin_says(tmp_path: Path) -> None:
    """UDP: each datagram is SharedLink's or not. TCP: each connection sends the payload, then
    ``]`` CR LF; a connection SharedLink took shows it (a frame not finished yet completes in the
    second segment), one it did not shows none (``]`` CR LF alone is not a frame's head)."""
    specs, want = [], []
    for k, p in enumerate(PAYLOADS):
        specs.append(tu.Pkt(k * 0.01, p, sport=20000 + k, dport=9999))
        want.append(sharedlink_heuristic(p, False))
    for k, p in enumerate(PAYLOADS + TCP_ONLY):
        specs += [tu.Pkt(1 + k * 0.01, p, sport=21000 + k, dport=9998, proto="tcp"),
                  tu.Pkt(1.005 + k * 0.01, b"]\r\n", sport=21000 + k, dport=9998, proto="tcp")]
        want.append(sharedlink_heuristic(p, True))
    shown = _frames(tu.write_pcap(tmp_path / "heuristic.pcap", specs))
    n = len(PAYLOADS)
    assert shown[:n] + [a or b for a, b in zip(shown[n::2], shown[n + 1 :: 2])] == want
    assert 8 < sum(want) < len(want) - 8  # (both verdicts, on both transports)
    assert sharedlink_heuristic(b"[:AB|D1 no close", True) and not sharedlink_heuristic(b"[:AB|D1 no close", False)


def test_a_conversation_sharedlink_took_keeps_its_p2os_packets(tmp_path: Path) -> None:
    """SharedLink first on UDP 8101, then a whole good P2OS packet: tshark shows SharedLink (no
    P2OS) and so does the core (the robot links never claim the conversation)."""
    sip = p2os.build_packet(p2os.encode_sip(p2os.Sip(xpos=5)))
    cap = tu.write_pcap(tmp_path / "took.pcap", [tu.Pkt(0, GOOD, sport=8101, dport=8101),
                                                  tu.Pkt(0.1, sip, sport=8101, dport=8101)])
    rows = tu.fields(cap, ["frame.protocols"], extra=OTHERS, two_pass=True)
    assert ["p2os" in ":".join(r["frame.protocols"]).split(":") for r in rows] == [False, False]
    dec = Decoder()
    dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
    assert not [i for i in dec.capture(cap) if isinstance(i, SessionMessage)]
