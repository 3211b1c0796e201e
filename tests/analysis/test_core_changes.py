"""The decoding core's changes-only mode (what ``diff`` reads: analysis.changes.ChangeReader over
Decoder.compiled / _Compiled.take) against the reference decoder (``fast=False``: every frame
through ReferenceDecoder), on streams built to catch a wrong reuse.

The compiled layouts keep each variable's text as bytes (``cur``) beside the table and take whole
runs of one direction's records; what can make them stale is a frame the reference path decodes
between two fast frames (a second frame in the datagram, a declaration, a reply, another type,
a positional frame), a first value a fast frame gives, another conversation's list. Every chunk
is compared whole (times, numbers, change records, first-value events, the snapshot of every
table) and so are the capture's statistics.
"""

from __future__ import annotations

import pytest
from core_streams import one_sender, positional_streams, streams, vector_capture, write_udp
from hypothesis import HealthCheck, given, settings
from sl_captures import captures, examples, write_capture
from sl_checks import change_records, flat_changes, same_changes
from sl_vectors import load_streams

from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named, encode_positional


def test_a_value_a_reference_frame_changed_is_not_reported_again(tmp_path):
    """Lon changes to 5 in the second frame of a datagram (the reference path); the fast full
    frames after it carry Lon 5 again: no change, whatever the compiled layouts held before."""
    full = encode_named("A", "B", [("Lat", 2, "1"), ("Lon", 2, "1")])
    lat2 = encode_named("A", "B", [("Lat", 2, "2")])
    full5 = encode_named("A", "B", [("Lat", 2, "2"), ("Lon", 2, "5")])
    lon5 = encode_named("A", "B", [("Lon", 2, "5")])
    path = write_udp(tmp_path / "v.pcap", one_sender(full, full, lat2, lat2 + lon5, full5, full5, lat2))
    assert same_changes(path) >= 4
    assert change_records(path)[4:] == [b"AB\x1fLon\x1e5", b"AB", b"AB", b"AB"]


def test_positional_slot_values_a_reference_frame_changed(tmp_path):
    full = encode_positional("A", "B", ["1", "1"])
    lat = encode_positional("A", "B", ["2", None])
    lon5 = encode_positional("A", "B", [None, "5"])
    full5 = encode_positional("A", "B", ["2", "5"])
    path = write_udp(tmp_path / "p.pcap", one_sender(full, full, lat, lat + lon5, full5, lat, full5))
    assert same_changes(path) >= 4
    assert change_records(path)[4:] == [b"AB\x1f#1\x1e5", b"AB", b"AB", b"AB"]


def test_a_type_a_reference_frame_changed_makes_new_layouts(tmp_path):
    """Lat sent as type 0 (a layout the compiled pattern of type 2 does not match) moves the
    variable's type; the type-2 frames after it are matched by layouts made again."""
    a, b = (encode_named("A", "B", [("Lat", 2, x)]) for x in ("1", "2"))
    t0 = encode_named("A", "B", [("Lat", 0, "3")])
    path = write_udp(tmp_path / "t.pcap", one_sender(a, b, a, t0, a, b, t0, t0, a))
    assert same_changes(path) >= 3


def test_a_first_value_in_a_fast_frame_changes_the_full_rule(tmp_path):
    """Vel gets its first value in a frame the compiled layouts take: it is sent from then on,
    so a frame without it is a delta, one with it full (a first-value event, then layouts
    made again)."""
    two = encode_named("A", "B", [("Lat", 2, "1"), ("Lon", 2, "1")])
    three = encode_named("A", "B", [("Lat", 2, "1"), ("Lon", 2, "2"), ("Vel", 2, "7")])
    three_b = encode_named("A", "B", [("Lat", 2, "1"), ("Lon", 2, "3"), ("Vel", 2, "8")])
    path = write_udp(tmp_path / "f.pcap", one_sender(two, two, three, two, three_b, two))
    assert same_changes(path) >= 4
    st = flat_changes(path, True)[5]
    assert st["full"] == 4  # two, two, three, three_b (the last two-name frame is a delta)


def test_positional_first_values_fill_slots(tmp_path):
    one = encode_positional("A", "B", ["1", None, None])
    two = encode_positional("A", "B", ["1", "2", None])
    path = write_udp(tmp_path / "s.pcap", one_sender(one, one, two, one, two, one))
    assert same_changes(path) >= 3
    assert flat_changes(path, True)[5]["full"] == 4


def test_a_declaration_renames_the_slots_of_compiled_positional_frames(tmp_path):
    decl = build_frame(Frame("A", "B", (Field("N", "0"), Field("T", "2"), Field("Q", "AutoGpsLon"),
                                        Field("T", "2"), Field("Q", "AutoGpsLat"))))
    a, b = encode_positional("A", "B", ["1", "2"]), encode_positional("A", "B", ["1", None])
    path = write_udp(tmp_path / "d.pcap", one_sender(a, b, a, b, decl, a, b, a, b))
    assert same_changes(path) >= 4


def test_a_bare_n0_follows_the_form_of_the_direction(tmp_path):
    bare = build_frame(Frame("A", "B", (Field("N", "0"),)))
    named = encode_named("A", "B", [("Lat", 2, "1")])
    pos = encode_positional("A", "B", [None])
    path = write_udp(tmp_path / "b.pcap", one_sender(named, bare, bare, pos, bare, bare, named, bare, bare))
    assert same_changes(path) >= 2


def test_two_senders_interleaved_keep_their_own_layouts(tmp_path):
    """Two conversations of the same letters, interleaved record by record: a run of one
    direction ends at the other's record."""
    a1, a2 = (encode_named("A", "B", [("Lat", 2, x), ("Lon", 2, "1")]) for x in ("1", "2"))
    b1, b2 = (encode_named("A", "B", [("Lat", 2, "9"), ("Lon", 2, x)]) for x in ("3", "4"))
    stream = []
    for i in range(12):
        stream.append((0, 10**18 + i * 200_000_000, (a1, a2)[i % 2]))
        stream.append((1, 10**18 + i * 200_000_000 + 1000, (b1, b2)[i // 3 % 2]))
    assert same_changes(write_udp(tmp_path / "i.pcap", stream)) >= 18


@settings(max_examples=examples(120), deadline=None, suppress_health_check=list(HealthCheck))
@given(streams())
def test_core_changes_equal_the_reference_on_generated_streams(tmp_path_factory, stream):
    same_changes(write_udp(tmp_path_factory.mktemp("ch") / "s.pcap", stream))


@settings(max_examples=examples(100), deadline=None, suppress_health_check=list(HealthCheck))
@given(positional_streams())
def test_core_changes_equal_the_reference_on_positional_streams(tmp_path_factory, stream):
    same_changes(write_udp(tmp_path_factory.mktemp("chp") / "s.pcap", stream))


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(captures())
def test_core_changes_equal_the_reference_on_varied_captures(tmp_path_factory, dgs):
    same_changes(write_capture(tmp_path_factory.mktemp("chv") / "x.pcap", dgs))


@pytest.mark.parametrize("stream", load_streams(), ids=lambda s: s["name"])
def test_core_changes_equal_the_reference_on_the_shared_vectors(tmp_path, stream):
    path, variables = vector_capture(stream, tmp_path)
    same_changes(path, variables)


@pytest.mark.parametrize("variant", [
    dict(compress=True, bad_checksum=0.05, drop=0.3, seed=2),
    dict(compress=True, bad_checksum=0.1, drop=0.1, jitter_ms=300.0),
    dict(),
    dict(form="positional", compress=True, bad_checksum=0.05),
    dict(fmt="pcapng", compress=True),
    dict(sync_interval=0.6, compress=True),
], ids=["faults", "jitter", "full", "positional", "pcapng", "sync06"])
def test_core_changes_equal_the_reference_on_fault_drives(tmp_path, variant):
    variant = dict(variant)
    path = tmp_path / f"d.{variant.get('fmt', 'pcap')}"
    generate_file(GenOptions(duration=60, seed=variant.pop("seed", 5), **variant), path)
    n = same_changes(path)
    assert n > 100


def test_the_compressed_beacon_is_taken_by_the_compiled_layouts(tmp_path):
    path = tmp_path / "c.pcap"
    generate_file(GenOptions(frames=3000, compress=True, seed=1), path)
    assert same_changes(path, blocks=()) >= 2990
