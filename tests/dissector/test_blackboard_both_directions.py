"""Blackboard when both directions send messages (docs/fields-p2os-blackboard.md, "Both
directions"): each side may send sets and requests, and the other side's next bytes answer them,
per direction, as blackboard.lua (and serial.lua) read it. Before the rule the Python session
reader fixed the first side to send a message as the master and read every byte of the other
side as an answer: it lost the other side's messages and their answers, and its message counts
differed from the dissector's on such captures (serial, UDP and TCP)."""

from __future__ import annotations

from pathlib import Path

import pytest
from sl_robots import OTHERS, SERIAL, write_serial

import tshark_util as tu
from sharedlink.analysis.sessions import Ack, iter_sessions
from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT
from sharedlink.protocols.blackboard import ReadResponse, RequestMessage, SetMessage

S1, S2 = SetMessage(0x1F00, 1, b"\x01\x02\x03"), SetMessage(0x2000, 2, b"\x09")
R1, R2 = RequestMessage(0xE000, 1, 3), RequestMessage(0xE100, 2, 2)
#: (sent by side A, bytes): A sets, B acknowledges; B sets, A acknowledges; A requests, B
#: answers; B requests, A answers; then A and B each set, answered in turn
SEQUENCE = [
    (True, S1.encode()), (False, S1.ack), (False, S2.encode()), (True, S2.ack),
    (True, R1.encode()), (False, R1.response(b"\x10\x20\x30")), (False, R2.encode()),
    (True, R2.response(b"\x41\x42")), (True, S2.encode()), (False, S2.ack), (False, S1.encode()), (True, S1.ack),
    (True, R1.encode()), (False, S2.encode()), (True, S2.ack),  # B talks instead of answering: A answers it
]
KIND = {SetMessage: "set", RequestMessage: "request", Ack: "ack", ReadResponse: "response"}
WANT = ["set", "ack", "set", "ack", "request", "response", "request", "response", "set", "ack", "set", "ack",
        "request", "set", "ack"]


def _capture(path: Path, transport: str) -> Path:
    if transport == "serial":
        return write_serial(path, [(data, DIR_OUT if a else DIR_IN) for a, data in SEQUENCE], step_ns=10**7)
    with open(path, "wb") as fh:
        pw = PcapWriter(fh)
        evs = [(10**18 + i * 10**7, a, data) for i, (a, data) in enumerate(SEQUENCE)]
        for ts, _a, frame in session_frames(evs, transport, ("127.0.0.1", 40000), ("127.0.0.1", 9100)):
            pw.write(ts, frame)
    return path


@pytest.mark.parametrize("transport", ["serial", "udp", "tcp"])
def test_both_directions_lua_and_python_agree(tmp_path: Path, transport: str) -> None:
    cap = _capture(tmp_path / f"bb-{transport}.{'pcapng' if transport == 'serial' else 'pcap'}", transport)
    rows = tu.fields(cap, ["blackboard.type", "blackboard.checksum.status"], extra=OTHERS, two_pass=True,
                     prefs=SERIAL if transport == "serial" else None)
    lua = [t for r in rows for t in r["blackboard.type"]]
    msgs = list(iter_sessions(cap))
    py = [KIND[type(m.message)] for m in msgs]
    assert (lua, py) == (WANT, WANT)
    assert all(m.ok for m in msgs)
    assert [m.side for m in msgs] == ["master" if k in ("set", "request") else "slave" for k in WANT]
    assert [m.raw for m in msgs] == [data for _a, data in SEQUENCE]
