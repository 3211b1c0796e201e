"""Any split of a P2OS or blackboard serial stream into records gives the pieces of the whole
stream read as one record (the SharedLink stream's any-split test, test_serial.py, drawing the
other two protocols): the same frames, nothing lost, nothing doubled, in order, and each frame
decodes as its codec decodes it alone; with the protocol named, and left to detection ("auto",
as a serial capture is read)."""

from __future__ import annotations

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from sl_captures import chunked, examples, serial_stream

from sharedlink.capture.serial_format import Deframer
from sharedlink.protocols import blackboard, p2os


def pieces(protocol: str, chunks: list[bytes]) -> list:
    d = Deframer(protocol)
    out = []
    for i, c in enumerate(chunks):
        out += d.feed(c, i + 1)
    return out + d.flush()


def decode(protocol: str, data: bytes) -> object:
    return p2os.parse_packet(data) if protocol == "p2os" else blackboard.parse_message(data)


@st.composite
def cases(draw: st.DrawFn) -> tuple[str, bytes, list[bytes] | None, list[int]]:
    protocol = draw(st.sampled_from(["p2os", "blackboard"]))
    data, messages = draw(serial_stream(protocol))
    return protocol, data, messages, draw(st.lists(st.integers(0, 10_000), max_size=40))


#: a cut-off P2OS packet whose claimed span ends on the FA of the next good packet's header, cut
#: right after that FA (the reader waits for the next byte; tests/vectors/p2os-resync.json)
SPAN_ON_FA = ("p2os", bytes.fromhex("FAFB06003B000000" "FAFB03000000"), None, [9])


@settings(max_examples=examples(300), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
@example(SPAN_ON_FA)
def test_any_split_of_a_p2os_or_blackboard_stream_gives_the_frames_of_the_whole(case):
    protocol, data, messages, cuts = case
    whole = pieces(protocol, [data])
    split = pieces(protocol, chunked(data, cuts))
    assert [p.data for p in split if p.is_frame] == [p.data for p in whole if p.is_frame]
    if messages is not None:  # a clean stream: every message is a frame
        assert [p.data for p in split if p.is_frame] == messages
    # nothing lost, nothing doubled, in order
    assert b"".join(p.data for p in split) == data
    assert all(a.end == b.start for a, b in zip(split, split[1:]))
    for p in split:
        if p.is_frame:
            assert p.records and decode(protocol, p.data) is not None


@settings(max_examples=examples(300), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
@example(SPAN_ON_FA)
def test_any_split_with_the_protocol_detected_gives_the_frames_of_the_whole(case):
    """The same with the protocol left to detection ("auto", as serial captures are read): the
    frames of the whole stream read so, whatever the cuts; a clean stream's messages, its
    protocol detected."""
    protocol, data, messages, cuts = case
    whole = pieces("auto", [data])
    split = pieces("auto", chunked(data, cuts))
    assert [p.data for p in split if p.is_frame] == [p.data for p in whole if p.is_frame]
    assert b"".join(p.data for p in split) == data  # (nothing lost, nothing doubled)
    if messages is not None:
        assert [p.data for p in split if p.is_frame] == messages
        assert {p.protocol for p in split} == {protocol}
