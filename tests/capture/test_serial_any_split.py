"""Any split of a P2OS or blackboard serial stream into records gives the pieces of the whole
stream read as one record (the SharedLink stream's any-split test, test_serial.py, drawing the
other two protocols): the same frames, nothing lost, nothing doubled, in order, and each frame
decodes as its codec decodes it alone."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sl_captures import chunked

from sharedlink.capture.serial_format import Deframer
from sharedlink.protocols import blackboard, p2os

_noise = st.one_of(st.binary(min_size=1, max_size=12),
                   st.sampled_from([b"\xfa", b"\xfa\xfb", b"\xfa\xfb\x03", b":", b"\r", b"\r\n", b":03"]))


@st.composite
def p2os_packet(draw: st.DrawFn) -> bytes:
    kind = draw(st.integers(0, 2))
    if kind == 0:
        return p2os.encode_message(p2os.command(draw(st.integers(0, 120))))
    if kind == 1:
        return p2os.encode_message(p2os.command(draw(st.integers(0, 120)), draw(st.integers(-3000, 3000))))
    return p2os.encode_message(p2os.Sip(moving=draw(st.booleans()),
                                        sonars=tuple((i, draw(st.integers(0, 5000))) for i in range(draw(st.integers(0, 3))))))


@st.composite
def blackboard_message(draw: st.DrawFn) -> bytes:
    if draw(st.booleans()):
        return blackboard.build_message(blackboard.SetMessage(draw(st.integers(0, 0xFFFF)), draw(st.integers(0, 255)),
                                                              draw(st.binary(max_size=8))))
    return blackboard.build_message(blackboard.RequestMessage(draw(st.integers(0, 0xFFFF)), draw(st.integers(0, 255)),
                                                              draw(st.integers(0, 255))))


@st.composite
def stream(draw: st.DrawFn, protocol: str) -> tuple[bytes, list[bytes] | None]:
    """Messages with noise and truncated messages between them (or none: a clean stream, one
    time in four), ending with a whole message; and the messages when the stream is clean."""
    message = p2os_packet() if protocol == "p2os" else blackboard_message()
    clean = draw(st.integers(0, 3)) == 0
    parts, messages = [], []
    for _ in range(draw(st.integers(1, 10))):
        k = 0 if clean else draw(st.integers(0, 9))
        if k < 6:
            messages.append(draw(message))
            parts.append(messages[-1])
        elif k < 8:
            parts.append(draw(_noise))
        else:
            m = draw(message)
            parts.append(m[: draw(st.integers(1, len(m) - 1))])
    messages.append(draw(message))
    parts.append(messages[-1])
    return b"".join(parts), (messages if clean else None)


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
    data, messages = draw(stream(protocol))
    return protocol, data, messages, draw(st.lists(st.integers(0, 10_000), max_size=40))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
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
