"""Issue 12's property test: the dissector and the Python decoder agree frame by frame.

Issue 29 decided the disagreements this test used to leave out (docs/fields-sharedlink.md,
"Rules for real sessions"); the shared vector streams carry them, and
:func:`test_vector_stream_agrees` runs every stream through both decoders (a strict xfail where
the stream's "pending" names "agreement"; none is). Drawn here since both sides follow them:
replies in a direction that carries data (shown, never stored), declarations that shorten a
list under once-filled slots, positional frames shorter and longer than the list (the a-priori
list names only a frame of its length; past a declared list var.unknown / Update.unknown).

Hypothesis draws captures of several SharedLink conversations at once (named and positional,
compressed, typed and badly typed values, declarations, list requests, queries and replies,
bad and missing checksums, frames lost, the same letters on several source ports), writes
each as a real pcap and decodes it twice: with ``tshark -T json`` and dissector/sharedlink.lua,
and with :func:`sharedlink.analysis.decode.iter_decoded`. For every frame the two must agree on
the kind, the checksum verdict and, for value frames, every variable shown: name, value,
carried flag, (for sent values) the bad-value flag and the typed field, and var.unknown. Many conversations go in one capture so
that each example costs one tshark run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from sl_agreement import frames_of, lua_frames, python_frames
from sl_vectors import load_streams, stream_params, tshark_json, write_stream

from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter

NAMED = (("Lat", 2), ("Lon", 2), ("Mode", 4), ("Cnt", 0))
TEXTS = ["1", "-2", "3.5", "0", "x", "None", "1.5e3", "on", "a\r\nb", "a b"]
T0 = 1_767_268_800 * 1_000_000_000

# -- captures -----------------------------------------------------------------------------

conversation = st.tuples(
    st.sampled_from([("A", "B"), ("A", "C")]),  # (destination, source) letters
    st.sampled_from(["10.0.0.2", "10.0.0.3"]),
    st.sampled_from([7013, 40001, 40002]),  # source port: a new port is a new conversation
    st.booleans(),  # named form
)
text = st.sampled_from(TEXTS)


@st.composite
def positional_body(draw: Any) -> str:
    start = draw(st.sampled_from([0, 0, 0, 1]))
    # as long as the list (N0 + 4, N1 + 3), a bare N0, shorter and longer ones: the a-priori
    # list names only a frame of its length (else #i), a declared one every frame (past its
    # end #i with var.unknown / Update.unknown): issue 29
    n = draw(st.sampled_from([0, 4, 4, 2, 6])) if start == 0 else draw(st.sampled_from([3, 3, 1, 5]))
    vals = [draw(st.one_of(st.just(""), text)) for _ in range(n)]
    return f"N{start}" + "".join(f"|D{v}" for v in vals)


@st.composite
def named_body(draw: Any) -> str:
    ordinal = draw(st.sampled_from(["N0|", "N0|", "N0|", "N1|", ""]))
    picked = [x for x in NAMED if draw(st.booleans())] or [NAMED[0]]
    parts = [f"T{t}|Q{name}|D{draw(st.one_of(st.just(''), text))}" for name, t in picked]
    return ordinal + "|".join(parts)


@st.composite
def other_body(draw: Any, named: bool) -> str:
    names = [n for n, _ in NAMED] if named else ["P0", "P1", "P2", "P3"]
    return draw(
        st.sampled_from(
            [
                "L?",
                "N?",
                f"Q{names[0]}",
                # a reply in a direction that carries data: shown, never stored (issue 29), typed
                # by its direction's list on both sides, a value not of its type a bad value
                # (docs/fields-sharedlink.md, disagreement 2)
                f"R{names[1]}|D{draw(st.sampled_from(['1', '-2', '0', 'x', '1.5', '']))}",
                # declarations: new types for the four positional slots, and one that shortens
                # the list under once-filled slots (slots past it are gone: issue 29)
                "N0|T0|QP0|T2|QP1|T4|QP2|T2|QP3",
                "N0|T4|QP0|T4|QP1|T0|QP2|QP3",
                "N0|T2|QP1|QP0",
                "Xz",
                "N0",
            ]
        )
    )


@st.composite
def captures(draw: Any) -> list[tuple[tuple, str, str]]:
    """(conversation, frame text without checksum, checksum mode) per packet."""
    convs = draw(st.lists(conversation, min_size=1, max_size=5, unique_by=lambda c: c[:3]))
    out = []
    for _ in range(draw(st.integers(5, 60))):
        c = draw(st.sampled_from(convs))
        kind = draw(st.sampled_from(["data"] * 6 + ["other", "switch"]))
        if kind != "other":
            # "switch": a data frame of the other form (a direction that changes form: a bare N0
            # takes the form of its direction's last good data frame, issue 40)
            body = draw(named_body() if c[3] == (kind == "data") else positional_body())
        else:
            body = draw(other_body(c[3]))
        ck = draw(st.sampled_from(["good"] * 8 + ["bad", "missing"]))
        if draw(st.integers(0, 9)) == 0:
            continue  # a frame lost on the way
        out.append((c, body, ck))
    return out


def write_capture(path: Path, packets: list[tuple[tuple, str, str]]) -> Path:
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for i, ((letters, ip, sport, _named), body, ck) in enumerate(packets):
            head = f":{letters[0]}{letters[1]}|{body}"
            if ck == "missing":
                raw = f"[{head}]\r\n".encode("latin-1")
            else:
                calc = sum(f"{head}|C".encode("latin-1")) % 256
                if ck == "bad":
                    calc = (calc + 0x5A) % 256
                raw = f"[{head}|C{calc:02X}]\r\n".encode("latin-1")
            w.write(T0 + i * 100_000_000, UdpBuilder(ip, "10.0.0.1", sport, 7013).frame(raw, i + 1))
    return path


# -- the two decoders -----------------------------------------------------------------------












# no shrinking: each step would be a tshark run; the failing capture is reported as drawn
# Derandomized: CI runs the same 12 streams every time.
@settings(
    max_examples=12,
    derandomize=True,  # CI sees the same 12 streams every run; see the note above the test
    deadline=None,
    suppress_health_check=list(HealthCheck),
    phases=(Phase.explicit, Phase.reuse, Phase.generate),
)
@given(captures())
def test_dissector_and_python_decoder_agree(tmp_path_factory, packets):
    cap = write_capture(tmp_path_factory.mktemp("agree") / "x.pcap", packets)
    lua = lua_frames(cap)
    py = python_frames(cap, len(packets))
    assert len(lua) == len(packets)
    for i, (lf, pf) in enumerate(zip(lua, py), 1):
        assert lf == pf, f"packet {i}: {packets[i - 1][1]!r} ({packets[i - 1][2]} checksum)"


def test_carried_empty_named_value(tmp_path):
    conv = (("A", "B"), "10.0.0.2", 7013, True)
    cap = write_capture(tmp_path / "e.pcap", [(conv, "N0|T4|QNote|D|T4|QMode|Dx", "good"), (conv, "N0|T4|QMode|Dy", "good")])
    assert python_frames(cap, 2)[1][0]["vars"] == [("Mode", "y", False, False, "string", False),
                                                   ("Note", "", True, False, None, False)]
    note = [v for v in lua_frames(cap)[1][0]["vars"] if v[0] == "Note"]
    assert note == [("Note", "", True, False, None, False)]


def test_declared_untyped_slot_after_typed_list(tmp_path):
    # conversation y (port 40002) declares P3 a double; x (same letters, port 40001) declares
    # the same names untyped after it (no T in its frame: issue 40's rule gives none), so x
    # starts from y's list and then replaces it: its own declaration types its slots, and an
    # untyped name stays untyped (no bad double), while y's slot stays a double
    x = (("A", "B"), "10.0.0.2", 40001, False)
    y = (("A", "B"), "10.0.0.2", 40002, False)
    packets = [
        (y, "N0|T0|QP0|T2|QP1|T4|QP2|T2|QP3", "good"),
        (x, "N0|QP0|QP1|QP2|QP3", "good"),
        (x, "N1|D|D|Dx", "good"),
        (y, "N1|D|D|Dx", "good"),
    ]
    cap = write_capture(tmp_path / "d.pcap", packets)
    carried = [("P1", None, True, False, None, False), ("P2", None, True, False, None, False)]
    want = [carried + [("P3", "x", False, False, None, False)], carried + [("P3", "x", False, True, None, False)]]
    assert [f[0]["vars"] for f in python_frames(cap, 4)[2:]] == want
    assert [f[0]["vars"] for f in lua_frames(cap)[2:]] == want


VECTOR_STREAMS = load_streams()


# (the two-pass run of each stream is test_vectors.py's: the same worker, sl_vectors.tshark_json)
@pytest.mark.xdist_group("vectors")
@pytest.mark.parametrize("stream", stream_params(VECTOR_STREAMS, "agreement"))
def test_vector_stream_agrees(stream: dict[str, Any], tmp_path: Path) -> None:
    """Every shared vector stream (the real-session ones of issue 29 included) through both
    decoders: the same kinds, checksum verdicts and shown variables, frame by frame. A malformed
    frame (noise to Python's reader) is left out of both."""
    ext = "pcapng" if stream.get("transport") == "serial" else "pcap"
    cap = write_stream(stream, tmp_path / f"s.{ext}")
    variables = stream.get("variables")   # none: each side's own default (issue 29: the same list)
    lua = [[f for f in p if f["kind"] != "malformed"] for p in frames_of(tshark_json(stream, two_pass=True))]
    py = python_frames(cap, len(stream["packets"]), variables)
    assert len(lua) == len(stream["packets"])
    for i, (lf, pf) in enumerate(zip(lua, py), 1):
        assert lf == pf, f"{stream['name']} packet {i}: {stream['packets'][i - 1]['payload']!r}"
