"""Every P2OS and blackboard input of golden_small (generated sessions over TCP, UDP and serial,
the hand-made edge cases, their editcap mutations): the messages tshark shows in each frame with
p2os.lua, blackboard.lua and serial.lua are those of the Python session reader and of the
decoding core's robot links (what `stats`, `export`, `ingest` read), frame by frame: protocol,
side or kind (malformed ones named so), checksum verdict (tests/sl_robot_frames.py).

serial-edge.pcapng carries P2OS one way and blackboard the other on one serial interface: each
direction of a serial line finds its own protocol (docs/serial-capture-format.md, "Protocol per
direction"); the Python reader gave the interface the first protocol it found and none of the 6
blackboard messages serial.lua shows."""

from __future__ import annotations

from pathlib import Path

import pytest
from sl_robot_frames import core_frames, differences, lua_frames, python_frames

HERE = Path(__file__).resolve().parent / "golden_small"
INPUTS = sorted(p.name for p in HERE.iterdir() if p.suffix in (".pcap", ".pcapng") and p.name != "sl-serial.pcapng")
#: blackboard.lua's UDP port preference golden_small's outputs are recorded with
PREFS = {"bb-edge.pcap": {"blackboard.udp_port": "7100"}}


@pytest.mark.parametrize("name", INPUTS)
def test_lua_python_and_the_core_give_the_same_messages_frame_by_frame(name: str) -> None:
    path = HERE / name
    lua = lua_frames(path, PREFS.get(name))
    py = python_frames(path)
    assert differences(lua, py) == {}
    assert differences(py, core_frames(path)) == {}
    assert sum(map(len, py.values())) >= 14


def test_serial_edge_carries_both_protocols_one_a_direction() -> None:
    py = python_frames(HERE / "serial-edge.pcapng")
    msgs = [m for ms in py.values() for m in ms]
    assert sum(m[0] == "blackboard" for m in msgs) == 6
    assert sum(m[0] == "p2os" for m in msgs) == 8
    # the blackboard direction's messages talk to nobody: the P2OS direction owes no answer
    assert {m[1] for m in msgs if m[0] == "blackboard"} == {"set", "request"}


#: a fuzz capture of SharedLink-like datagrams on UDP 8101, P2OS packets among them later
FUZZ = HERE.parents[1] / "fuzz" / "fuzz-regressions" / "random-udp-8101-2-fields-a9cb864b7c43.pcap"


def test_a_conversation_sharedlink_took_first_shows_no_p2os_in_tshark_and_the_session_reader() -> None:
    assert lua_frames(FUZZ) == {} == python_frames(FUZZ)


def test_the_core_shows_none_either() -> None:
    assert core_frames(FUZZ) == {}
