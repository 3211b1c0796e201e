"""The decoding core (analysis.decode.Decoder) against the plain reference decoder, on streams
built to catch a wrong reuse.

The core's fast path takes a datagram that is one named N0 frame in a layout seen before, and
reuses the Update it made for a carried value while that value holds. These streams mix such
frames with what can change a value behind the fast path's back without making it forget the
direction: frames of a datagram holding two frames (each decoded by the reference path, each
learnt), replies, declarations, positional frames, bad checksums, several directions and
conversations. Every item is compared field by field (text, carried, carried_from, changed,
index, type, bad; kind, late, gap, the table after it) with the reference decoder's.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from core_streams import (
    one_sender,
    positional_streams,
    reference_items,
    stats_by_reference,
    streams,
    vector_capture,
    write_udp,
)
from hypothesis import HealthCheck, example, given, settings
from sl_captures import captures, examples, write_capture
from sl_vectors import load_streams

from sharedlink.analysis.decode import Decoded, Decoder, ReferenceDecoder, iter_decoded
from sharedlink.capture.stream import StreamFrame
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named, encode_positional
from sharedlink.protocols.state import BEACON_VARIABLES


def _key(item) -> tuple:
    """Everything a caller can read of an item, the table after it included."""
    if isinstance(item, Decoded):
        t = item.table
        return (item.number, item.ts_ns, item.conv, item.raw, item.src, item.dst, item.pair, item.kind,
                item.checksum_ok, item.updates, item.late, item.sync_gap_ns, item.shown, item.response_to,
                item.frame if item.kind != "malformed" else None,
                {n: (v.text, v.type_code, v.set_in, v.set_at) for n, v in t.vars.items()},
                (t.last_full_at, t.last_full_in, t.named, dict(t.sent_names), tuple(t.names), sorted(t.filled)))
    if isinstance(item, StreamFrame):
        return ("noise", item.number, item.raw)
    return ("other", item)


def _reference(path: Path, carried: bool = True, variables=BEACON_VARIABLES) -> list[tuple]:
    dec = ReferenceDecoder(variables, carried=carried)
    return [_key(item) for item in reference_items(dec, path)]  # (keys taken item by item: tables are live)


def compare(path: Path, carried: bool = True, variables=BEACON_VARIABLES) -> int:
    """The core and the reference give the same items; returns how many the fast path took."""
    dec = Decoder(variables, carried=carried)
    got = [_key(item) for item in dec.capture(path)]  # (keys taken item by item: tables are live)
    want = _reference(path, carried, variables)
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert g == w
    return dec.fast


def test_two_frames_in_a_datagram_change_a_value_between_fast_frames(tmp_path):
    """The case a planted bug slipped through: a value carried by two fast frames, changed in
    between by a frame the reference path decodes (one of two frames in a datagram) while the
    direction's layouts stay learnt. Reusing the first carried Update gives the old text."""
    B = "B"
    full = encode_named("A", B, [("Lat", 2, "1"), ("Lon", 2, "1")])
    lat_only = encode_named("A", B, [("Lat", 2, "2")])
    lat_only2 = encode_named("A", B, [("Lat", 2, "3")])
    lon_changed = encode_named("A", B, [("Lon", 2, "5")])
    stream = [(0, 10**18 + i * 200_000_000, p) for i, p in enumerate(
        [full, lat_only, full, lat_only, lat_only2, lat_only + lon_changed, lat_only2, lat_only])]
    path = write_udp(tmp_path / "reuse.pcap", stream)
    assert compare(path) >= 3
    last = [d for d in iter_decoded(path) if isinstance(d, Decoded)]
    lon = [u for u in last[-1].updates if u.name == "Lon"]
    assert lon and lon[0].text == "5" and lon[0].carried and lon[0].carried_from == 6


def _decoded(path: Path) -> list[Decoded]:
    return [d for d in iter_decoded(path) if isinstance(d, Decoded)]


def test_positional_fast_frames_carry_a_value_a_reference_frame_changed(tmp_path):
    """The positional form of the reuse case: Lon is carried (empty slot) by fast frames before
    and after a datagram of two frames (reference path) whose second sets it; the later carried
    Updates must say 5, from frame 6, not reuse the Update made before."""
    full = encode_positional("A", "B", ["1", "1"])
    lat, lat3 = encode_positional("A", "B", ["2", None]), encode_positional("A", "B", ["3", None])
    lon5 = encode_positional("A", "B", [None, "5"])
    path = write_udp(tmp_path / "pos.pcap", one_sender(full, lat, full, lat, lat3, lat + lon5, lat3, lat))
    assert compare(path) >= 4
    d = _decoded(path)
    assert d[-1].kind == "delta" and d[-1].frame.fields[0].letter == "N"
    lon = [u for u in d[-1].updates if u.name == "#1"]  # 2 slots: the 4-name default list names none (issue 29)
    assert lon == [lon[0]] and (lon[0].text, lon[0].carried, lon[0].carried_from, lon[0].index) == ("5", True, 6, 1)


def test_a_type_a_reference_frame_changed_is_not_reused(tmp_path):
    """A named frame with another type (a layout learnt anew) moves the variable's type: the
    fast frames after it, in either layout, must not reuse the Update of the old type."""
    t2, t0 = encode_named("A", "B", [("Lat", 2, "1")]), encode_named("A", "B", [("Lat", 0, "1")])
    path = write_udp(tmp_path / "type.pcap", one_sender(t2, t2, t0, t2, t0, t0))
    assert compare(path) >= 1
    assert [d.updates[0].type_code for d in _decoded(path)] == [2, 2, 0, 2, 0, 0]


def test_a_declaration_renames_the_slots_of_fast_positional_frames(tmp_path):
    """Positional frames are named by the list in force: after a declaration that swaps the
    names, the same slots carry the other variables."""
    decl = build_frame(Frame("A", "B", (Field("N", "0"), Field("T", "2"), Field("Q", "AutoGpsLon"),
                                        Field("T", "2"), Field("Q", "AutoGpsLat"))))
    a, b = encode_positional("A", "B", ["1", "2"]), encode_positional("A", "B", ["1", None])
    path = write_udp(tmp_path / "decl.pcap", one_sender(a, b, a, b, decl, a, b, a, b))
    assert compare(path) >= 4
    last = _decoded(path)[-1]
    assert [(u.name, u.text, u.carried) for u in last.updates] == [("AutoGpsLon", "1", False), ("AutoGpsLat", "2", True)]


def test_a_bare_n0_follows_the_form_the_direction_uses_now(tmp_path):
    """A bare N0 is read in the direction's form: named after named frames (carried values),
    positional (no values) once a positional frame came, even though the named layout of the
    bare frame was learnt before."""
    bare = build_frame(Frame("A", "B", (Field("N", "0"),)))
    named = encode_named("A", "B", [("Lat", 2, "1")])
    pos = encode_positional("A", "B", [None])
    path = write_udp(tmp_path / "bare.pcap", one_sender(named, bare, bare, pos, bare, bare, named, bare, bare))
    assert compare(path) >= 2
    assert [len(d.updates) for d in _decoded(path)] == [1, 1, 1, 1, 0, 0, 1, 1, 1]


def test_positional_fast_frames_fill_slots_for_the_full_rule(tmp_path):
    """A slot is required once a frame gave it a value: a fast frame that fills a slot first
    makes later frames without it deltas (the fast path keeps ``filled`` as the table does)."""
    one = encode_positional("A", "B", ["1", None, None])
    two = encode_positional("A", "B", ["1", "2", None])
    path = write_udp(tmp_path / "fill.pcap", one_sender(one, one, two, one, two, one))
    assert compare(path) >= 3
    assert [d.kind for d in _decoded(path)] == ["full", "full", "full", "delta", "full", "delta"]


@settings(max_examples=examples(150), deadline=None, suppress_health_check=list(HealthCheck))
@given(streams())
def test_core_equals_reference_on_generated_streams(tmp_path_factory, stream):
    path = write_udp(tmp_path_factory.mktemp("core") / "s.pcap", stream)
    compare(path)
    compare(path, carried=False)


# The full/delta rule's bug (the fast path not marking the slot a fast frame fills first, so a
# later frame without it came out "full"): found by the draw in 6 of 8 seeds, so its input is
# kept. Frame 1 goes the reference path, frame 2 fills slot 1 on the fast path, frame 3 is a delta.
FILLS_A_SLOT = [(0, 1_700_000_000_200_000_000, b"[:AB|N0|D1|D|C27]\r\n"),
                (0, 1_700_000_000_400_000_000, b"[:AB|N0|D1|D2|C59]\r\n"),
                (0, 1_700_000_000_600_000_000, b"[:AB|N0|D1|D|C27]\r\n")]


@settings(max_examples=examples(100), deadline=None, suppress_health_check=list(HealthCheck))
@given(positional_streams())
@example(FILLS_A_SLOT)
def test_core_equals_reference_on_positional_streams(tmp_path_factory, stream):
    path = write_udp(tmp_path_factory.mktemp("pos") / "s.pcap", stream)
    compare(path)
    compare(path, carried=False)


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(captures())
def test_core_equals_reference_on_varied_captures(tmp_path_factory, dgs):
    """diff's varied captures (named and positional, compressed, unusual fields, noise)."""
    compare(write_capture(tmp_path_factory.mktemp("var") / "x.pcap", dgs))


@pytest.mark.parametrize("stream", load_streams(), ids=lambda s: s["name"])
def test_core_equals_reference_on_the_shared_vectors(tmp_path, stream):
    """Every stream of the shared vectors (issue 29's pending ones too: whatever rule the
    reference follows, the core follows it), with its variable list."""
    path, variables = vector_capture(stream, tmp_path)
    compare(path, variables=variables)


@pytest.mark.parametrize("variant", [dict(compress=True, bad_checksum=0.1, drop=0.1, jitter_ms=300.0), dict(),
                                     dict(form="positional", compress=True, bad_checksum=0.05)])
def test_core_equals_reference_on_drives(tmp_path, variant):
    path = tmp_path / "d.pcap"
    generate_file(GenOptions(duration=30, seed=5, **variant), path)
    n = compare(path)
    assert n > 50 or variant.get("form") == "positional"


def test_core_takes_the_compressed_beacon_fast(tmp_path):
    path = tmp_path / "c.pcap"
    generate_file(GenOptions(frames=2000, compress=True, seed=1), path)
    dec = Decoder()
    n = sum(isinstance(d, Decoded) for d in dec.capture(path))
    assert n == 2000 and dec.fast >= 1990  # only the first frames of each layout go the reference way


def _same_stats(path: Path) -> None:
    from sharedlink.analysis.stats import capture_stats

    got, want = capture_stats(path).to_dict(), stats_by_reference(path).to_dict()
    assert got == want


@settings(max_examples=80, deadline=None, suppress_health_check=list(HealthCheck))
@given(streams())
def test_counted_stats_equal_the_reference_on_generated_streams(tmp_path_factory, stream):
    """stats takes the fast path's frames as counted batches (no Decoded, no Updates): the same
    statistics as every frame through the reference decoder and CaptureStats.add."""
    _same_stats(write_udp(tmp_path_factory.mktemp("st") / "s.pcap", stream))


def test_a_reply_between_counted_frames_is_not_in_the_full_size(tmp_path):
    """Found by the test above after issue 29's rules met the counted path: a reply's value is
    shown, never stored, so the full-set size ('compression') of the frames after it must not
    take it (stats' size tracker applied the reply's update: 717 against the counted 715)."""
    bare, lat = b"[:AB|N0|C76]\r\n", encode_named("A", "B", [("Lat", 2, "1")])
    reply = b"[:AB|RLat|D2.5|CC0]\r\n"
    path = write_udp(tmp_path / "r.pcap", one_sender(*[bare * 2] * 14, bare + lat, reply + bare, bare))
    _same_stats(path)


@pytest.mark.parametrize("variant", [dict(compress=True, bad_checksum=0.05, drop=0.3, seed=2), dict(jitter_ms=300.0),
                                     dict(form="positional", compress=True)])
def test_counted_stats_equal_the_reference_on_drives(tmp_path, variant):
    path = tmp_path / "d.pcap"
    variant = dict(variant)
    generate_file(GenOptions(duration=60, seed=variant.pop("seed", 5), **variant), path)
    _same_stats(path)


def _same_jsonl(path: Path) -> int:
    """export jsonl's line builder against json.dumps of the row dict, frame by frame."""
    import io
    import json

    from sharedlink.analysis.export import ExportOptions, _Jsonl

    w = _Jsonl(io.StringIO(), ExportOptions(fmt="jsonl"), [])
    n = 0
    for d in iter_decoded(path, carried=False):
        if isinstance(d, Decoded):
            assert w.line(d) == json.dumps(w.row(d)) + "\n"
            n += 1
    return n


@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
@given(streams())
def test_jsonl_lines_equal_json_dumps_on_generated_streams(tmp_path_factory, stream):
    _same_jsonl(write_udp(tmp_path_factory.mktemp("js") / "s.pcap", stream))


def test_jsonl_lines_equal_json_dumps_on_a_drive(tmp_path):
    path = tmp_path / "d.pcap"
    generate_file(GenOptions(duration=30, seed=3, compress=True, bad_checksum=0.05), path)
    assert _same_jsonl(path) > 100
