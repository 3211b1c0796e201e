"""The SharedLink codec: the bulletins' examples, real-peer deviations, and properties over
random input (nothing but SharedLinkError escapes; parse(build(x)) == x)."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sl_captures import examples

from sharedlink.protocols.codec import (
    Field,
    Frame,
    SharedLinkError,
    build_fields,
    build_frame,
    checksum,
    declaration_fields,
    declared_list,
    encode_named,
    encode_positional,
    frame_kind,
    iter_segments,
    named_fields,
    named_values,
    parse_frame,
    positional_fields,
    positional_values,
    split_frames,
    typed_value,
)

BUL009 = (
    b"[:AB|N0|T2|QAutoGpsLat|D38.34698779|T2|QAutoGpsLon|D-77.05734791|T2|QAutoGpsHead|D57"
    b"|T2|QAutoGpsVel|D0|CF8]\r\n"
)


def test_bul009_example_checksum_is_f8():
    f = parse_frame(BUL009)
    assert f.checksum is not None
    assert f.checksum.text == "F8" and f.checksum.calculated == 0xF8 and f.checksum.ok
    assert f.deviations == ()
    assert (f.dst, f.src, f.dst_node, f.src_node) == ("A", "B", 1, 2)
    assert f.kind == "full"
    vals = named_values(f.fields)
    assert [(v.name, v.value) for v in vals] == [
        ("AutoGpsLat", 38.34698779),
        ("AutoGpsLon", -77.05734791),
        ("AutoGpsHead", 57.0),
        ("AutoGpsVel", 0.0),
    ]
    assert build_frame(f) == BUL009


def test_checksum_is_byte_sum_mod_256_from_colon_through_c():
    inner = BUL009[1 : BUL009.index(b"|CF8") + 2]
    assert inner.startswith(b":AB") and inner.endswith(b"|C")
    assert checksum(inner) == sum(inner) % 256 == 0xF8


def test_bul049_positional_frame():
    f = Frame("A", "B", positional_fields(["40.12345678", "-113.12345678", "85.6", "22.1"]))
    raw = build_frame(f)
    assert raw.startswith(b"[:AB|N0|D40.12345678|D-113.12345678|D85.6|D22.1|C") and raw.endswith(b"]\r\n")
    back = parse_frame(raw)
    assert back == f and back.checksum.ok and back.kind == "full"
    assert positional_values(back.fields) == (0, ["40.12345678", "-113.12345678", "85.6", "22.1"])


def test_query_and_reply():
    q = parse_frame(build_frame(Frame("A", "B", (Field("Q", "AutoGpsLat"),))))
    r = parse_frame(build_frame(Frame("B", "A", (Field("R", "AutoGpsLat"), Field("D", "40.12345678")))))
    assert q.kind == "query" and r.kind == "reply"
    assert named_values(r.fields)[0].name == "AutoGpsLat"


@pytest.mark.parametrize(
    "fields,kind",
    [
        ((Field("N", "0"), Field("T", "2"), Field("Q", "X"), Field("T", "0"), Field("Q", "Y")), "declaration"),
        ((Field("L", "0"), Field("T", "2"), Field("Q", "X")), "declaration"),
        ((Field("E", "Link"), Field("D", "0, outbound, on")), "command"),
        ((Field("M", "UI"),), "command"),
        ((Field("P", ""),), "ping"),
        ((Field("G", ""),), "pong"),
        ((Field("N", "0"), Field("D", ""), Field("D", "2")), "delta"),
        ((Field("N", "2"), Field("D", "1")), "delta"),
        ((Field("N", "0"),), "delta"),
    ],
)
def test_frame_kinds(fields, kind):
    assert frame_kind(fields) == kind
    assert parse_frame(build_frame(Frame("A", "B", fields))).kind == kind


def test_declared_list():
    fields = (Field("L", "2"), Field("T", "2"), Field("Q", "X"), Field("T", "4"), Field("Q", "Y"))
    assert declared_list(fields) == ("L", 2, [("X", 2), ("Y", 4)])


def test_real_peer_deviations_are_reported_not_fatal():
    # lower-case, unpadded checksum, no CR LF, empty field, unknown letter
    inner = b":AB|N0||D1|Zzz|C"
    ck = sum(inner) & 0xFF
    raw = b"[" + inner + (b"%x" % ck) + b"]"
    f = parse_frame(raw)
    assert f.checksum.ok is True
    assert f.crlf is False
    text = " / ".join(f.deviations)
    assert "no CR LF" in text and "empty field" in text and "unknown field letter 'Z'" in text
    if ck < 16 or any(c in "abcdef" for c in "%x" % ck):
        assert "not two upper-case hex digits" in text
    unpadded = parse_frame(b"[:AB|D|C6]")  # sum is 0x23c -> 3C, not 06: one digit and a bad checksum, but parsed
    assert unpadded.checksum.calculated == sum(b":AB|D|C") % 256 == 0x3C
    assert unpadded.checksum.ok is False and any("checksum mismatch" in d for d in unpadded.deviations)


def test_missing_checksum_is_unverified():
    f = parse_frame(b"[:AB|N0|D1]\r\n")
    assert f.checksum.ok is None and "no checksum field" in f.deviations


@pytest.mark.parametrize(
    "raw,offset,reason",
    [
        (b"", 0, "empty"),
        (b"x[:AB|C00]", 0, "does not start"),
        (b"[:AB|N0|D1", 10, "unterminated"),
        (b"[AB|C00]", 1, "no ':'"),
        (b"[:A]", 1, "no ':'"),
        (b"[:AB|C00]xyz", 9, "after ']'"),
        (b"[:ABX|C00]", 4, "not followed by '|'"),
    ],
)
def test_errors_carry_offset_and_reason(raw, offset, reason):
    with pytest.raises(SharedLinkError) as ei:
        parse_frame(raw)
    assert ei.value.offset == offset
    assert reason in ei.value.reason


def test_typed_values():
    assert typed_value(0, "42") == 42
    assert typed_value(2, "85.60") == 85.6
    assert typed_value(4, "85.60") == "85.60"
    assert typed_value(0, "x") == "x"


def test_segments_two_frames_and_noise():
    a = encode_named("A", "B", [("X", 2, "1.5")])
    b = encode_positional("B", "A", ["1", None])
    data = b"\x00junk" + a + b"noise[" + b + b"[:AB|N0|D"
    segs = split_frames(data)
    kinds = [("frame" if s.is_frame else s.error.reason) for s in segs]
    assert kinds == ["noise between frames", "frame", "noise between frames", "frame", "unterminated frame"]
    assert data[segs[1].start : segs[1].end] == a
    assert data[segs[3].start : segs[3].end] == b
    assert segs[3].frame.checksum.ok


def test_fast_encoders_match_build_frame():
    vals = [("AutoGpsLat", 2, "38.1"), ("Name", 4, "hello world")]
    assert encode_named("C", "D", vals) == build_frame(Frame("C", "D", named_fields(vals)))
    texts = ["1", None, "x", None]
    assert encode_positional("A", "P", texts, crlf=False) == build_frame(Frame("A", "P", positional_fields(texts), crlf=False))


# -- properties ---------------------------------------------------------------------------

letters = st.sampled_from("ABCDEFGHIJKLMNOP")
field_text = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126, blacklist_characters="|[]"), max_size=12)
field_st = st.builds(Field, st.sampled_from("NTQRDELMPGXZ"), field_text)
frame_st = st.builds(Frame, letters, letters, st.lists(field_st, max_size=10).map(tuple), st.booleans())


@given(frame_st)
def test_round_trip(frame):
    raw = build_frame(frame)
    back = parse_frame(raw)
    assert back == frame
    assert back.checksum.ok is True
    assert build_frame(back) == raw
    segs = split_frames(raw)
    assert len(segs) == 1 and segs[0].frame == frame


@settings(max_examples=examples(400), suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=200))
def test_random_bytes_raise_only_sharedlink_error(data):
    try:
        parse_frame(data)
    except SharedLinkError as exc:
        assert 0 <= exc.offset <= len(data)
    segs = split_frames(data)
    assert sum(s.end - s.start for s in segs) == len(data)  # every byte accounted for, in order
    assert all(a.end == b.start for a, b in zip(segs, segs[1:]))


@settings(max_examples=examples(400))
@given(frame_st, st.data())
def test_mutated_frames_raise_only_sharedlink_error(frame, data):
    raw = bytearray(build_frame(frame))
    for _ in range(data.draw(st.integers(1, 4))):
        op = data.draw(st.sampled_from(["flip", "cut", "insert"]))
        i = data.draw(st.integers(0, max(0, len(raw) - 1)))
        if op == "flip" and raw:
            raw[i] = data.draw(st.integers(0, 255))
        elif op == "cut":
            del raw[i:]
        else:
            raw[i:i] = data.draw(st.binary(min_size=1, max_size=3))
    try:
        f = parse_frame(bytes(raw))
        assert f.checksum is not None
    except SharedLinkError as exc:
        assert 0 <= exc.offset <= len(raw)
    list(iter_segments(bytes(raw)))


def test_hostile_64k_payload():
    # linear by construction (each scan starts past the last); the timing is in make fuzz/bench
    for pattern in (b"[|:", b"[:AB|", b"[]", b"[:AB|C00]x"):
        data = (pattern * (65536 // len(pattern) + 1))[:65536]
        segs = split_frames(data)
        assert sum(s.end - s.start for s in segs) == len(data)


def test_small_rules_mutation_testing_found_unchecked():
    """Details a mutation run showed no test looked at (scripts/mutate.py)."""
    # an empty field is Field("", ""); C anywhere but last is an unknown letter
    f = parse_frame(b"[:AB||D1|C5|CFF]")
    assert f.fields[:3] == (Field("", ""), Field("D", "1"), Field("C", "5"))
    assert "unknown field letter 'C'" in " / ".join(f.deviations)
    # noise carries the offset where it starts
    segs = list(iter_segments(b"xx" + encode_positional("A", "B", ["1"]) + b"yyy"))
    noise = [s for s in segs if not s.is_frame]
    assert [(s.start, s.end, s.error.offset) for s in noise] == [(0, 2, 0), (segs[1].end, segs[1].end + 3, segs[1].end)]
    # frames of no known kind
    assert frame_kind((Field("X", "1"),)) == "other"
    assert frame_kind((Field("T", "2"),)) == "other"
    assert frame_kind(()) == "other"
    assert frame_kind((Field("L", "0"),)) == "other"  # an L with nothing declared
    # a name declared without a type has type None; declarations written with their types
    assert declared_list((Field("N", "0"), Field("Q", "A"), Field("T", "4"), Field("Q", "B"))) == ("N", 0, [("A", None), ("B", 4)])
    assert declaration_fields([("A", 2), ("B", 4)], 3) == (
        Field("N", "3"), Field("T", "2"), Field("Q", "A"), Field("T", "4"), Field("Q", "B"))
    assert declaration_fields([("A", 0)], inbound=True)[0] == Field("L", "0")
    # build_fields: CR LF unless asked not to
    assert build_fields((Field("N", "0"), Field("D", "1")), "A", "B") == encode_positional("A", "B", ["1"])
    assert build_fields((Field("N", "0"), Field("D", "1")), crlf=False).endswith(b"]")
