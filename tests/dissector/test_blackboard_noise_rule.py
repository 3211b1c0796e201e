"""The blackboard rule for noise (docs/fields-p2os-blackboard.md, "Noise"): a message starts at
the last ``:`` or ``;`` before its CR; the text before it is outside any message. The serial
readers (serial.lua, the Python reader) always cut so; blackboard.lua read a ``:`` to the CR as
one (malformed) message, so on TCP and UDP it showed ``:01013CF725A6;49;5E06ED812E`` as a
malformed set where the Python session reader has the request ``;5E06ED812E`` (and serial.lua,
once its region held the noise, handed blackboard.lua the same bytes: the noise of
test_serial_split_blackboard_noise.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from sl_robots import OTHERS

import tshark_util as tu
from sharedlink.analysis.sessions import iter_sessions
from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import PcapWriter

LEAD = b":0611716CF34578DB49E751\r"
NOISY = b":01013CF725A6;49;5E06ED812E\r"
NOISE, MESSAGE = NOISY[:16], NOISY[16:]


@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_noise_before_the_last_type_character_is_outside_any_message(tmp_path: Path, transport: str) -> None:
    cap = tmp_path / f"bb-{transport}.pcap"
    with open(cap, "wb") as fh:
        w = PcapWriter(fh)
        evs = [(10**18, True, LEAD), (10**18 + 10_000_000, True, NOISY)]
        for ts, _c, frame in session_frames(evs, transport, ("127.0.0.1", 40000), ("127.0.0.1", 9100)):
            w.write(ts, frame)
    rows = tu.fields(cap, ["blackboard.type", "blackboard.hex", "blackboard.junk"], extra=OTHERS, two_pass=True)
    assert [t for r in rows for t in r["blackboard.type"]] == ["set", "request"]
    assert [h for r in rows for h in r["blackboard.hex"]] == [LEAD[1:-1].decode(), MESSAGE[1:-1].decode()]
    assert [bytes.fromhex(j.replace(":", "")) for r in rows for j in r["blackboard.junk"]] == [NOISE]
    assert [m.raw for m in iter_sessions(cap)] == [LEAD, MESSAGE]
