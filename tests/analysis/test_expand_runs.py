"""`sharedlink expand`'s run taker (analysis/core/expand.py) against the frame-at-a-time rewriter
it stands in front of: the same output byte for byte, the same counts, on generated captures
and on hypothesis streams built to catch a wrong reuse (first values, declarations, replies,
positional frames, bad checksums and two frames in a datagram between the runs' frames)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from core_streams import frames, streams, write_udp
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from sl_captures import captures, write_capture

from sharedlink.analysis.core.expand import FullSets
from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.transform import Rewriter, TransformError, TransformStats, rewrite_capture
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.errors import OutputError
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import encode_named

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))


def both(src: Path, out: Path) -> tuple[TransformStats, int]:
    """Expand ``src`` with the run taker and without; assert the same bytes and counts; return
    the stats and the frames the run taker took."""
    rw, each = Rewriter("expand"), Rewriter("expand")
    taker = FullSets(rw.src_decoder, rw.named_form)
    fast = rewrite_capture(rw, src, out / "runs.pcap", taker)
    slow = rewrite_capture(each, src, out / "each.pcap")
    assert (out / "runs.pcap").read_bytes() == (out / "each.pcap").read_bytes()
    assert fast == slow
    assert state(rw.src_decoder) == state(each.src_decoder)  # (the rewriter numbers every frame 0)
    return fast, taker.taken


def state(dec: Decoder) -> tuple:
    """What the input's core knows at the end: each table's values (when set, not by which
    record: the rewriter numbers frames 0), its last full set and form, each sync clock."""
    tables = {k: ({n: (v.text, v.type_code, v.set_at) for n, v in t.vars.items()},
                  (t.last_full_at, t.named, dict(t.sent_names), tuple(t.names), sorted(t.filled)))
              for k, t in dec.link.tables.items()}
    return tables, dict(dec._sync)


@pytest.mark.parametrize("opts", [
    GenOptions(frames=3000, compress=True),
    GenOptions(frames=3000),
    GenOptions(frames=2000, compress=True, drop=0.05, bad_checksum=0.02, seed=3),
    GenOptions(frames=2000, compress=True, jitter_ms=40, outages=((100.0, 3.0),), seed=4),
    GenOptions(frames=500, compress=True, form="positional"),
])
def test_runs_write_what_the_rewriter_writes(tmp_path, opts):
    src = tmp_path / "in.pcap"
    generate_file(opts, src)
    st_, taken = both(src, tmp_path)
    assert st_.rewritten >= opts.frames * 0.9
    if opts.form == "named":
        assert taken > st_.rewritten * 0.9  # (the runs took most: this test compares something)


def test_long_frames_odd_payloads_and_no_udp_checksum(tmp_path):
    """Full sets past adler32's 256 bytes and past its wrap (the checksum summed), odd and even payload lengths,
    a packet without a UDP checksum (none is made), a bare N0, a value's type-0 text."""
    b = UdpBuilder("10.0.0.1", "10.0.0.9", 7013, 7013)
    names = [("Lat", 2), ("Lon", 2), ("Label", 4), ("Count", 0)]
    payloads = [encode_named("A", "B", [(n, t, v) for n, t in names for v in ["1"]])]
    for i in range(60):
        vals = {"Lat": str(i % 7), "Lon": "-" + "9" * (i % 3), "Label": "x" * (i * 13 % 700), "Count": str(i)}
        pick = [(n, t, vals[n]) for k, (n, t) in enumerate(names) if (i + k) % 3]
        payloads.append(encode_named("A", "B", pick))
    src = tmp_path / "in.pcap"
    with open(src, "wb") as fh:
        w = PcapWriter(fh)
        for i, p in enumerate(payloads):
            pkt = b.frame(p, i + 1)
            if i % 5 == 4:
                pkt = pkt[:40] + b"\0\0" + pkt[42:]  # (no UDP checksum)
            w.write(10**18 + i * 200_000_000, pkt)
    st_, taken = both(src, tmp_path)
    assert taken > 40


@SETTINGS
@given(streams(max_datagrams=60))
@example([(0, 10**18, encode_named("A", "B", [("Lat", 2, "1")])), (0, 10**18 + 1, b"[:AB|N0|C76]\r\n"),
          (0, 10**18 + 2, encode_named("A", "B", [("Lat", 2, "2")])), (0, 10**18 + 3, b"[:AB|N0|C76]\r\n")])
def test_runs_agree_on_streams_built_to_catch_a_wrong_reuse(tmp_path_factory, stream):
    d = tmp_path_factory.mktemp("runs")
    both(write_udp(d / "in.pcap", stream), d)


@SETTINGS
@given(st.lists(frames("B", "A", kinds=("named",) * 8 + ("declaration", "reply", "bad", "positional")),
                min_size=1, max_size=80))
def test_runs_agree_on_one_sender_mostly_named(tmp_path_factory, payloads):
    d = tmp_path_factory.mktemp("one")
    both(write_udp(d / "in.pcap", [(0, 10**18 + i * 200_000_000, p) for i, p in enumerate(payloads)]), d)


@SETTINGS
@given(captures())
def test_runs_agree_on_any_capture(tmp_path_factory, dgs):
    d = tmp_path_factory.mktemp("any")
    both(write_capture(d / "x.pcap", dgs), d)


def test_a_full_set_past_one_datagram_is_refused_at_the_same_record(tmp_path):
    b = UdpBuilder("10.0.0.1", "10.0.0.9", 7013, 7013)
    big = "x" * 33000
    payloads = [encode_named("A", "B", [("Lat", 2, "1"), ("Label", 4, big[:10])])]
    payloads += [encode_named("A", "B", [("Lat", 2, str(i))]) for i in range(30)]
    payloads += [encode_named("A", "B", [("Label", 4, big)]), encode_named("A", "B", [("Lat", 2, big)])]
    src = tmp_path / "in.pcap"
    with open(src, "wb") as fh:
        w = PcapWriter(fh)
        for i, p in enumerate(payloads):
            w.write(10**18 + i * 200_000_000, b.frame(p, i + 1))
    errors = []
    for taker in (True, False):
        rw = Rewriter("expand")
        with pytest.raises(TransformError) as exc:
            rewrite_capture(rw, src, tmp_path / f"{taker}.pcap", FullSets(rw.src_decoder, rw.named_form) if taker else None)
        errors.append(str(exc.value).replace(f"{taker}.pcap", ""))
    assert errors[0] == errors[1] and "record 33" in errors[0]


def test_a_time_past_the_nanosecond_pcap_is_refused_at_the_same_record(tmp_path):
    """A microsecond pcap whose last second is 2**32 - 1 with a fraction past a second (a damaged
    one): its time is past what a nanosecond pcap holds."""
    b = UdpBuilder("10.0.0.1", "10.0.0.9", 7013, 7013)
    src = tmp_path / "in.pcap"
    with open(src, "wb") as fh:
        fh.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
        for i in range(40):
            pkt = b.frame(encode_named("A", "B", [("Lat", 2, str(i % 3))]), i + 1)
            frac = 1_500_000 if i >= 30 else i
            fh.write(struct.pack("<IIII", 0xFFFFFFFF, frac, len(pkt), len(pkt)) + pkt)
    errors = []
    for taker in (True, False):
        rw = Rewriter("expand")
        with pytest.raises(OutputError) as exc:
            rewrite_capture(rw, src, tmp_path / f"{taker}.pcap", FullSets(rw.src_decoder, rw.named_form) if taker else None)
        errors.append(str(exc.value))
    assert errors[0] == errors[1] and "record 31" in errors[0]
