"""The block tier of the core's compiled layouts (analysis.compiled_blocks, under _Compiled.take)
against the reference decoder, on long runs of one direction (the tier starts after 16 records in a
row) broken by every kind of record it must not take or must not read past: a datagram of two
frames that changes a carried value (reference path), a bad checksum, another sender's record, a
value with a byte the layouts leave out, a frame over 256 bytes, a record with bytes after its
datagram, a declaration, a first value, a type change. Each test also checks that the block tier
took frames (so a stream the per-record loop alone decodes cannot pass for it).
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sl_checks import change_records, same_changes

import sharedlink.analysis.compiled_blocks as compiled_blocks
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PCAP_MAGIC_US, PcapWriter
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named, encode_positional

T0 = 1_700_000_000 * 10**9


@pytest.fixture
def block_frames(monkeypatch) -> list[int]:
    """Counts the frames the block tier takes (``[n]``)."""
    taken = [0]
    make = compiled_blocks.block_taker

    def counting(*args, **kwargs):
        take = make(*args, **kwargs)

        def counted(*a):
            got = take(*a)
            if got is not None:
                taken[0] += got[2]
            return got

        return counted

    monkeypatch.setattr(compiled_blocks, "block_taker", counting)
    return taken


def _write(path: Path, stream: list[tuple[int, bytes, bytes]], micro: bool = False) -> Path:
    """(sender, payload, bytes after the datagram in the record), 200 ms apart."""
    senders = [UdpBuilder(f"10.0.0.{i + 1}", "10.0.0.9", 7013, 7013) for i in range(2)]
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        head = b""
        for i, (sender, payload, pad) in enumerate(stream):
            rec = w.record(T0 + i * 200_000_000, senders[sender].frame(payload, i + 1) + pad)
            if micro:
                sec, frac, n, orig = struct.unpack_from("<IIII", rec)
                rec = struct.pack("<IIII", sec, frac // 1000, n, orig) + rec[16:]
            head += rec
        if micro:
            fh.seek(0)
            fh.write(struct.pack("<I", PCAP_MAGIC_US))
        fh.seek(24)
        fh.write(head)
    return path


def _full(i: int, lon: str = "1", vel: str = "0") -> bytes:
    return encode_named("A", "B", [("Lat", 2, f"{38 + i / 1000:.4f}"), ("Lon", 2, lon), ("Vel", 2, vel)])


def _run(n: int, start: int = 0, lon: str = "1") -> list[tuple[int, bytes, bytes]]:
    return [(0, _full(start + i, lon), b"") for i in range(n)]


def test_a_value_a_reference_frame_changed_between_two_blocks_is_not_reported_again(tmp_path, block_frames):
    """Lon is 1 in a long run, then a datagram of two frames (the reference path) sets it to 5;
    the long run after it carries Lon 5 in every frame: one change (in the datagram), none after,
    whatever the block tier held before."""
    two = encode_named("A", "B", [("Lat", 2, "1")]) + encode_named("A", "B", [("Lon", 2, "5")])
    stream = _run(60) + [(0, two, b"")] + _run(60, 100, lon="5")
    path = _write(tmp_path / "r.pcap", stream)
    assert same_changes(path, blocks=(700, 4096)) == 120 - 1  # (the first frame: reference path)
    assert block_frames[0] >= 80
    recs = change_records(path)
    assert [r for r in recs if b"Lon" in r] == [recs[0], b"AB\x1fLon\x1e5"]  # (the datagram's second frame)


def test_a_carried_value_a_reference_frame_changed_in_a_compressed_run(tmp_path, block_frames):
    """The same with the value carried (left out) by the frames around the datagram, then sent
    again in full frames: Lon 5 is no change there."""
    delta = [(0, encode_named("A", "B", [("Lat", 2, f"{i}")]), b"") for i in range(40)]
    two = encode_named("A", "B", [("Lat", 2, "x1")]) + encode_named("A", "B", [("Lon", 2, "5")])
    stream = _run(20) + delta + [(0, two, b"")] + delta + _run(40, 200, lon="5")
    path = _write(tmp_path / "c.pcap", stream)
    assert same_changes(path, blocks=(700, 4096)) >= 130
    assert block_frames[0] >= 60
    assert sum(b"Lon\x1e5" in r for r in change_records(path)) == 1


@pytest.mark.parametrize("odd", ["bad_checksum", "other_sender", "control_byte", "bracket", "long_frame", "padding",
                                 "declaration", "first_value", "apriori_first_value", "type", "positional", "bare"])
def test_the_block_tier_stops_at_a_record_it_must_not_take(tmp_path, block_frames, odd):
    """A long run, a record of each kind in its middle, the run again: the same chunks as the
    reference decoder (the odd record and every value after it)."""
    good = _full(7, lon="3")
    row = (0, good, b"")
    if odd == "bad_checksum":
        row = (0, good[:-5] + (b"00" if good[-5:-3] != b"00" else b"01") + good[-3:], b"")
    elif odd == "other_sender":
        row = (1, good, b"")
    elif odd == "control_byte":
        row = (0, encode_named("A", "B", [("Lat", 2, "1"), ("Lon", 2, "3\x01"), ("Vel", 2, "0")]), b"")
    elif odd == "bracket":
        row = (0, encode_named("A", "B", [("Lat", 2, "1"), ("Lon", 2, "3]"), ("Vel", 2, "0")]), b"")
    elif odd == "long_frame":
        row = (0, encode_named("A", "B", [("Lat", 2, "1" * 150), ("Lon", 2, "3" * 100), ("Vel", 2, "0")]), b"")
    elif odd == "padding":  # bytes after the datagram (Ethernet padding): the IP length is not the record's
        row = (0, good, b"\x00" * 6)
    elif odd == "declaration":
        row = (0, build_frame(Frame("A", "B", (Field("N", "0"), Field("T", "2"), Field("Q", "Vel"),
                                               Field("T", "2"), Field("Q", "Lat")))), b"")
    elif odd == "first_value":
        row = (0, encode_named("A", "B", [("Lat", 2, "1"), ("Lon", 2, "3"), ("Vel", 2, "0"), ("Head", 2, "9")]), b"")
    elif odd == "apriori_first_value":  # a name of the a-priori list (typed, in the layouts) gets its first value
        row = (0, encode_named("A", "B", [("AutoGpsHead", 2, "9"), ("Lat", 2, "1"), ("Lon", 2, "3"), ("Vel", 2, "0")]), b"")
    elif odd == "type":
        row = (0, encode_named("A", "B", [("Lat", 0, "1"), ("Lon", 2, "3"), ("Vel", 2, "0")]), b"")
    elif odd == "positional":
        row = (0, encode_positional("A", "B", ["1", "3", None]), b"")
    elif odd == "bare":
        row = (0, build_frame(Frame("A", "B", (Field("N", "0"),))), b"")
    stream = _run(40) + [row] + _run(40, 50, lon="3") + [row] + _run(40, 100)
    path = _write(tmp_path / "o.pcap", stream)
    assert same_changes(path, blocks=(700, 4096)) >= 39
    assert block_frames[0] >= 20


@pytest.mark.parametrize("variant", [dict(), dict(compress=True), dict(form="positional"),
                                     dict(form="positional", compress=True), dict(compress=True, bad_checksum=0.01)],
                         ids=["full", "compressed", "positional", "positional-compressed", "bad-checksums"])
def test_long_drives_through_the_block_tier(tmp_path, block_frames, variant):
    path = tmp_path / "d.pcap"
    generate_file(GenOptions(frames=3000, seed=3, **variant), path)
    assert same_changes(path, blocks=(700, 65536)) >= 2900
    assert block_frames[0] >= 2000


def test_a_microsecond_capture_through_the_block_tier(tmp_path, block_frames):
    delta = [(0, encode_named("A", "B", [("Lat", 2, f"{i}")]), b"") for i in range(30)]
    stream = (_run(30) + delta) * 4
    path = _write(tmp_path / "us.pcap", stream, micro=True)
    assert same_changes(path, blocks=(700, 4096)) == len(stream) - 1
    assert block_frames[0] >= 100


def test_two_senders_in_long_alternating_runs(tmp_path, block_frames):
    """Runs of 30 records of each of two conversations (same letters): each run a block of its
    own direction, stopped at the other's record."""
    stream = []
    for r in range(6):
        stream += [(r % 2, _full(100 * r + i, lon=str(r)), b"") for i in range(30)]
    path = _write(tmp_path / "two.pcap", stream)
    assert same_changes(path, blocks=(700, 4096)) == len(stream) - 2  # (each conversation's first frame)
    assert block_frames[0] >= 60


_ODD = st.sampled_from(["two", "bad", "other", "control", "long", "pad", "decl", "type", "positional", "first"])


@st.composite
def _block_streams(draw) -> list[tuple[int, bytes, bytes]]:
    """Long runs (17 to 60 records) of full and delta frames of one direction, few values (so
    unchanged values are the rule), each run followed by one odd record."""
    vals = ("1", "2", "2.5")
    out: list[tuple[int, bytes, bytes]] = []
    for _ in range(draw(st.integers(2, 5))):
        for _ in range(draw(st.integers(17, 60))):
            names = ["Lat", "Lon", "Vel"] if draw(st.booleans()) else draw(
                st.lists(st.sampled_from(["Lat", "Lon", "Vel"]), unique=True, max_size=3))
            names.sort(key=["Lat", "Lon", "Vel"].index)
            out.append((0, encode_named("A", "B", [(n, 2, draw(st.sampled_from(vals))) for n in names]), b""))
        odd, v = draw(_ODD), draw(st.sampled_from(vals))
        if odd == "two":
            out.append((0, encode_named("A", "B", [("Lat", 2, v)]) + encode_named("A", "B", [("Lon", 2, v + "0")]), b""))
        elif odd == "bad":
            f = encode_named("A", "B", [("Lon", 2, v + "9")])
            out.append((0, f[:-5] + (b"00" if f[-5:-3] != b"00" else b"01") + f[-3:], b""))
        elif odd == "other":
            out.append((1, encode_named("A", "B", [("Lon", 2, v + "7")]), b""))
        elif odd == "control":
            out.append((0, encode_named("A", "B", [("Lon", 2, v + "\x02")]), b""))
        elif odd == "long":
            out.append((0, encode_named("A", "B", [("Lon", 2, v * 120)]), b""))
        elif odd == "pad":
            out.append((0, encode_named("A", "B", [("Lon", 2, v + "1")]), b"\x00" * 4))
        elif odd == "decl":
            out.append((0, build_frame(Frame("A", "B", (Field("N", "0"), Field("T", "2"), Field("Q", "Lon")))), b""))
        elif odd == "type":
            out.append((0, encode_named("A", "B", [("Vel", 0, v)]), b""))
        elif odd == "positional":
            out.append((0, encode_positional("A", "B", [v, None, v]), b""))
        else:
            out.append((0, encode_named("A", "B", [("AutoGpsVel", 2, v), ("Lat", 2, v)]), b""))  # a first value
    return out


@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
@given(_block_streams())
def test_block_tier_equals_the_reference_on_generated_long_runs(tmp_path_factory, stream):
    same_changes(_write(tmp_path_factory.mktemp("blk") / "s.pcap", stream), blocks=(700, 4096))
