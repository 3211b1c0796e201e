"""The decoding core's robot links (analysis/robots.py) read each UDP datagram alone
(docs/fields-p2os-blackboard.md, "Over UDP"): the flag ``RobotLinks._segment`` hands the session
reader for a UDP conversation, on both of the core's paths: the fast record loop
(``RobotLinks.udp``: plain Ethernet/IPv4/UDP records) and the general one (``RobotLinks.datagram``:
here raw-IP records, which the fast loop leaves to the packet decoder). The same payloads over TCP
are one stream, where a packet or message cut across segments is joined: so a reader that lost
the flag on either path joins the UDP pieces too and fails here."""

from __future__ import annotations

from pathlib import Path

import pytest

from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import LINKTYPE_ETHERNET, LINKTYPE_RAW, PcapWriter
from sharedlink.protocols import blackboard as bbc
from sharedlink.protocols import p2os

SYNC0 = p2os.build_packet(b"\x00")
VEL = p2os.build_packet(p2os.encode_command(p2os.command("VEL", 200)))
SET = bbc.build_message(bbc.SetMessage(0x1F00, 1, bytes([1, 2, 3])))
REQ = bbc.build_message(bbc.RequestMessage(0xE000, 1, 5))
#: (protocol, server port, the client's payloads: a whole one and the first part of the next,
#: the rest of it, the next whole)
CASES = [("p2os", 9101, [SYNC0 + VEL[:4], VEL[4:], VEL]),
         ("blackboard", 9200, [SET + REQ[:5], REQ[5:], REQ])]
#: the messages per payload when each datagram is read alone (a cut blackboard message is a
#: malformed one, "Malformed messages"; a cut P2OS packet noise), and when the bytes are a stream
READ_ALONE = {"p2os": [[SYNC0], [], [VEL]], "blackboard": [[SET, REQ[:5]], [], [REQ]]}
JOINED = {"p2os": [[SYNC0], [VEL], [VEL]], "blackboard": [[SET], [REQ], [REQ]]}


def _capture(path: Path, transport: str, port: int, payloads: list[bytes], linktype: int) -> Path:
    evs = [(10**18 + i * 10_000_000, True, p) for i, p in enumerate(payloads)]
    with open(path, "wb") as fh:
        w = PcapWriter(fh, linktype)
        for ts, _c, frame in session_frames(evs, transport, ("127.0.0.1", 40000), ("127.0.0.1", port)):
            w.write(ts, frame if linktype == LINKTYPE_ETHERNET else frame[14:])  # (raw IP: no Ethernet header)
    return path


@pytest.mark.parametrize("linktype", [LINKTYPE_ETHERNET, LINKTYPE_RAW], ids=["fast-loop", "general-path"])
@pytest.mark.parametrize("proto,port,payloads", CASES, ids=[c[0] for c in CASES])
def test_udp_datagrams_are_read_alone_tcp_segments_joined(tmp_path: Path, proto: str, port: int,
                                                          payloads: list[bytes], linktype: int) -> None:
    want = {"udp": READ_ALONE[proto], "tcp": JOINED[proto]}
    for transport in ("udp", "tcp"):
        cap = _capture(tmp_path / f"{transport}.pcap", transport, port, payloads, linktype)
        dec = Decoder(carried=False)
        dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
        msgs = [m for m in dec.capture(cap) if isinstance(m, SessionMessage)]
        assert {m.protocol for m in msgs} == {proto}, transport
        # payload k is record k + 1 over UDP; over TCP the handshake comes first (3 records)
        first = min(m.number for m in msgs)
        got = [[m.raw for m in msgs if m.number == first + k] for k in range(len(payloads))]
        assert got == want[transport], (transport, linktype)
