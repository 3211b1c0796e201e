"""P2OS over UDP (`gen --protocol p2os --transport udp`): p2os.lua's UDP heuristic takes every
datagram (one packet each, good checksums) and puts each packet on the side the Python reader
(`iter_sessions`, what stats, health, export and watch read) puts it: by the server's port 8101,
and on another port in a pcap (no port, no direction flag) by the content alone, where p2os.lua
guesses each packet and Python remembers the robot's side once it has sent a server packet
(docs/fields-p2os-blackboard.md, "Direction")."""

from __future__ import annotations

from pathlib import Path

import pytest

from sharedlink.analysis.sessions import iter_sessions
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file
from tshark_util import fields

REPO = Path(__file__).resolve().parents[2]
EXTRA = ["-X", f"lua_script:{REPO / 'dissector' / 'p2os.lua'}"]


@pytest.mark.parametrize("port,fmt", [(8101, "pcapng"), (9000, "pcap")])
def test_udp_session_sides_agree(tmp_path, port, fmt):
    path = tmp_path / f"p2os-udp.{fmt}"
    stats = generate_p2os_file(P2osGenOptions(duration=6, seed=3, fmt=fmt, transport="udp", port=port), path)
    rows = fields(path, ["p2os.checksum.status", "p2os.direction"], extra=EXTRA)
    assert len(rows) == stats.packets  # a datagram a packet
    assert all(r["p2os.checksum.status"] == ["1"] for r in rows), "a datagram not taken by the heuristic"
    lua = ["client" if r["p2os.direction"] == ["0"] else "robot" for r in rows]
    py = [m.side for m in iter_sessions(path)]
    assert py == lua
    assert {m.label for m in iter_sessions(path)} == {f"udp 127.0.0.1:{port} - 127.0.0.1:45678"}
    assert py.count("robot") > py.count("client") > 10  # (10 SIPs and ENCODERs a second, commands)
