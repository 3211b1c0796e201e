"""Issue 40, item 5: P2OS server packets with a byte count of 0x89 and 0xF0, through both decoders.

The robot ignores a *client command* over 200 bytes (the P2OS manual); ARIA reads *server* packets
up to 255 bytes, and until January 2025 misreported the checksum of every packet whose count is
0x80 or more (it read the count as a signed byte: shared/PROTOCOL-NOTES.md). So a server packet
counting 0x89 or 0xF0 is a good packet: its checksum good, no "over 200" expert (p2os.lua gave
every packet over 200 one, whatever its direction). The Python decoder (``sessions``, the MCAP
export's source) reads the same packets with the same verdicts. A client command of 0xF0 still
gets the expert.
"""

from __future__ import annotations

from pathlib import Path

from sharedlink.analysis.sessions import iter_sessions
from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.protocols.p2os import build_packet
from tshark_util import fields

REPO = Path(__file__).resolve().parents[2]
EXTRA = ["-X", f"lua_script:{REPO / 'dissector' / 'p2os.lua'}"]

#: server packets (an undecoded type 0x99, then counting bytes) with counts 0x89 and 0xF0
SERVER_89 = build_packet(bytes([0x99]) + bytes(range(0x89 - 3)))
SERVER_F0 = build_packet(bytes([0x99]) + bytes(i % 256 for i in range(0xF0 - 3)))
#: a client command (SAY) of count 0xF0: the robot ignores it
CLIENT_F0 = build_packet(bytes([0x0F, 0x2B, 0xEB]) + b"x" * 0xEB)


def _capture(path: Path) -> Path:
    events = [(10**18, True, bytes.fromhex("FAFB03000000")), (10**18 + 10**7, False, SERVER_89),
              (10**18 + 2 * 10**7, False, SERVER_F0), (10**18 + 3 * 10**7, True, CLIENT_F0)]
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for ts, _, frame in session_frames(events, "tcp", ("127.0.0.1", 40000), ("127.0.0.1", 8101)):
            w.write(ts, frame)
    return path


def test_server_packets_counting_0x89_and_0xf0_are_good_on_both_sides(tmp_path: Path) -> None:
    assert (SERVER_89[2], SERVER_F0[2], CLIENT_F0[2]) == (0x89, 0xF0, 0xF0)
    cap = _capture(tmp_path / "counts.pcap")
    rows = [r for r in fields(cap, ["p2os.count", "p2os.direction", "p2os.checksum.status", "_ws.expert.message"],
                              extra=EXTRA) if r["p2os.count"]]
    assert [(r["p2os.count"], r["p2os.direction"], r["p2os.checksum.status"]) for r in rows] == [
        (["3"], ["0"], ["1"]), (["137"], ["1"], ["1"]), (["240"], ["1"], ["1"]), (["240"], ["0"], ["1"])]
    over = [any("over 200" in m for m in r["_ws.expert.message"]) for r in rows]
    assert over == [False, False, False, True]
    py = [(m.side, len(m.raw), m.ok) for m in iter_sessions(cap) if m.protocol == "p2os"]
    assert py == [("client", 6, True), ("robot", 3 + 0x89, True), ("robot", 3 + 0xF0, True), ("client", 3 + 0xF0, True)]
