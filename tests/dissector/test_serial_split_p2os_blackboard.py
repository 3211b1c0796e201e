"""dissector/serial.lua against the Python reader on P2OS and blackboard serial streams cut into
records anywhere (the SharedLink streams' test is test_serial_dissector.py's): tshark shows in each
direction the frames the Python reader finds, whatever the record boundaries. One capture a
protocol, six streams a direction, each starting with a whole message (so that both sides detect
the protocol), with noise and truncated messages between messages."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st
from sl_captures import blackboard_message, chunked, p2os_packet, serial_stream, write_interleaved
from sl_robots import serial_frames as _frames
from sl_robots import write_serial

import tshark_util as tu
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT, read_capture

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = [a for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua"
           for a in ("-X", f"lua_script:{s}")]
P2P = {DIR_IN: "1", DIR_OUT: "0"}


@st.composite
def cases(draw: st.DrawFn, protocol: str) -> tuple[bytes, list[tuple[bytes, list[int]]]]:
    """A whole message (each direction starts with it), then twelve streams with their cuts."""
    lead = draw(p2os_packet() if protocol == "p2os" else blackboard_message())
    out = []
    for _ in range(12):
        data, _messages = draw(serial_stream(protocol, max_items=6))
        out.append((data, draw(st.lists(st.integers(0, 10_000), max_size=12))))
    return lead, out




# inputs that once made the two disagree, each run under both protocol parameters (the streams
# say which protocol they are): blackboard noise between a talking direction's messages given
# out by serial.lua as a one-byte answer (test_serial_split_blackboard_noise.py); a cut-off P2OS
# packet whose claimed span ends on the next good packet's FA, cut right after it
# (tests/vectors/p2os-resync.json)
BB_LEAD = b":0611716CF34578DB49E751\r"
BB_NOISE = ((BB_LEAD, [
    (b";A52E4F3EA0\r:0027A4AC89\r:08070800AE60D9E4D95DF6E50D\r:081508FF194CD4EE7310C381EE\rO:00070438BD\r",
     [2763, 126, 6562, 1073]),
    (b";1D122CEBBA\r:089C251B25A5B276D22DCDBBA3\r;D8010A120B\r:07017BFF54B20F70C80C60C5\r",
     [159, 3434, 2142, 6405, 258, 208, 933, 1080, 247, 7092, 6989, 8240]),
    (b";770127E978\r;6E3C31A67F\r:02FFFEDAC7B7A9\r:024836A35BCAB8\r:000C9193D0\r",
     [894, 8192, 260, 1259, 110, 1826, 618, 5591, 81, 163, 606, 979]),
    (b":003A75FC55\r\x1d\xc0}[\xddO%P:01013CF725A6;49;5E06ED812E\r;CA019D7721\r:033A37002648EC32\r",
     [9999, 2547, 324, 337, 180, 450, 1228, 279, 2642, 477, 734, 1066]),
]), 91)
P2OS_SPAN_ON_FA = ((bytes.fromhex("FAFB03000000"), [
    (bytes.fromhex("FAFB06003B000000" "FAFB03000000"), [9]),
    (bytes.fromhex("FAFB03010001"), []),
]), 0)


# one tshark run an example, two examples a protocol (the same every run) and the examples above;
# no shrinking (each step a tshark run)
@pytest.mark.parametrize("protocol", ["p2os", "blackboard"])
def test_split_p2os_and_blackboard_streams_decode_alike_in_tshark_and_python(tmp_path_factory, protocol):
    @settings(max_examples=2, deadline=None, phases=[Phase.explicit, Phase.reuse, Phase.generate],
              suppress_health_check=list(HealthCheck), derandomize=True, database=None)
    @given(cases(protocol), st.integers(0, 99))
    @example(*BB_NOISE)
    @example(*P2OS_SPAN_ON_FA)
    def check(case: tuple[bytes, list[tuple[bytes, list[int]]]], seed: int) -> None:
        lead, items = case  # a whole message first in each direction: both sides detect the protocol
        streams: dict[int, list[bytes]] = {DIR_IN: [lead], DIR_OUT: [lead]}
        for i, (data, cuts) in enumerate(items):
            streams[DIR_IN if i % 2 == 0 else DIR_OUT] += chunked(data, cuts)
        cap = write_interleaved(tmp_path_factory.mktemp("split") / "split.pcapng", streams, seed)
        py: dict[str, list[bytes]] = {"0": [], "1": []}
        for _rec, d, piece in read_capture(cap):
            if piece.is_frame:
                py[P2P[d]].append(piece.data)
        assert py["0"] and py["1"]
        rows = tu.fields(cap, ["slserial.direction", "slserial.frame"], extra=SCRIPTS, two_pass=True)
        lua: dict[str, list[bytes]] = {"0": [], "1": []}
        for r in rows:
            for h in r["slserial.frame"]:
                lua[r["slserial.direction"][0]].append(bytes.fromhex(h.replace(":", "")))
        assert lua == py

    check()


def test_blackboard_direction_that_starts_second(tmp_path: Path) -> None:
    """One blackboard message out, then one in: each direction's one frame is the whole message
    (serial.lua took the in direction's first byte alone for the answer the out message asked
    for, where the Python reader gives the whole message; found by the test above)."""
    message = b";0000000000\r"
    cap = write_interleaved(tmp_path / "bb.pcapng", {DIR_OUT: [message]}, 0)
    cap2 = write_serial(tmp_path / "bb2.pcapng", [(message, DIR_OUT), (message, DIR_IN)], step_ns=1000)
    assert _frames(cap)[0] == _frames(cap)[1]  # one direction alone: alike
    py, lua = _frames(cap2)
    assert py == {"0": [message], "1": [message]}
    assert lua == py


def test_blackboard_second_direction_cut_around_the_answer(tmp_path: Path) -> None:
    """The in direction's first message cut into records before, at and after the point where
    the out message asks for its answer: always the whole message, as the Python reader has it."""
    message = b";0000000000\r"
    for cuts in ([3], [6], [1, 7], [11]):
        bounds = [0, *cuts, len(message)]
        parts = [message[a:b] for a, b in zip(bounds, bounds[1:])]
        t = 1_700_000_000 * 10**9
        # part of the in message before the out one asks, the out message, the rest of the in one
        cap = write_serial(tmp_path / f"bb-{'-'.join(map(str, cuts))}.pcapng",
                           [(parts[0], DIR_IN), (message, DIR_OUT), *((part, DIR_IN) for part in parts[1:])],
                           times=[t, t + 1000, *(t + 2000 + i for i in range(len(parts) - 1))])
        py, lua = _frames(cap)
        assert py == {"0": [message], "1": [message]}, cuts
        assert lua == py, cuts
