"""Serial detection of a P2OS stream that starts with a server packet counting 201..255 bytes
(ARIA reads server packets up to 255; the 200-byte limit is the robot's, for client commands):
serial.lua and the Python reader both detect P2OS from it, and p2os.lua decodes it without the
"P2OS ignores this packet" expert. A stream that starts with a client command over 200 bytes is
not detected from that packet (the robot ignores it)."""

from __future__ import annotations

from pathlib import Path

from sl_robots import write_serial

import tshark_util as tu
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT, read_capture
from sharedlink.protocols import p2os

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = [a for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua"
           for a in ("-X", f"lua_script:{s}")]


def _long_sip() -> bytes:
    sonars = 0
    while True:  # enough sonar readings for a count over 200
        pkt = p2os.encode_message(p2os.Sip(moving=True, sonars=tuple((i, 1000 + i) for i in range(sonars))))
        if pkt[2] > 200:
            assert pkt[2] <= 255
            return pkt
        sonars += 1


def _lua(cap: Path) -> list[dict[str, list[str]]]:
    return tu.fields(cap, ["slserial.protocol", "slserial.frame", "p2os.count", "_ws.expert.message"], extra=SCRIPTS,
                     two_pass=True)


def test_a_server_packet_over_200_bytes_is_detected_by_both_decoders(tmp_path: Path) -> None:
    sip = _long_sip()  # the stream's only packet: detection has nothing else to go by
    cap = write_serial(tmp_path / "s.pcapng", [(sip, DIR_IN)])
    py = [(p.protocol, p.data) for _r, _d, p in read_capture(cap) if p.is_frame]
    assert py == [("p2os", sip)]
    rows = _lua(cap)
    frames = [bytes.fromhex(h.replace(":", "")) for r in rows for h in r["slserial.frame"]]
    assert frames == [sip]
    assert {p for r in rows for p in r["slserial.protocol"]} == {"p2os"}
    assert str(sip[2]) in [c for r in rows for c in r["p2os.count"]]
    assert not any("ignores" in m for r in rows for m in r["_ws.expert.message"])


def test_a_client_command_over_200_bytes_does_not_detect_p2os(tmp_path: Path) -> None:
    cmd = p2os.encode_message(p2os.Command(p2os.COMMAND_NUMBERS["SAY"], p2os.ARG_STRING, b"x" * 10, b"y" * 200))
    assert cmd[2] > 200
    cap = write_serial(tmp_path / "c.pcapng", [(cmd, DIR_OUT)])
    assert not [p for _r, _d, p in read_capture(cap) if p.is_frame]
    rows = _lua(cap)
    assert not [f for r in rows for f in r["slserial.frame"]]
    assert not [p for r in rows for p in r["slserial.protocol"] if p == "p2os"]
