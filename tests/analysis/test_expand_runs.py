"""`sharedlink expand`'s run taker (analysis/core/expand.py) against the frame-at-a-time rewriter
it stands in front of: the same output byte for byte, the same counts, on generated captures
(named and positional, pcap and pcapng) and on hypothesis streams built to catch a wrong reuse
(first values, declarations, replies, positional frames of other slot counts, bad checksums and
two frames in a datagram between the runs' frames; in pcapng, records on a second interface
and with flags too)."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest
from core_streams import frames, one_sender, positional_streams, streams, write_udp
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from sl_captures import captures, write_capture

from sharedlink.analysis.core.expand import FullSets
from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.transform import Rewriter, TransformError, TransformStats, rewrite_capture
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapngWriter, PcapWriter, read_records
from sharedlink.errors import OutputError
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named, encode_positional

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))


def both(src: Path, out: Path) -> tuple[TransformStats, int]:
    """Expand ``src`` with the run taker and without; assert the same bytes and counts; return
    the stats and the frames the run taker took."""
    rw, each = Rewriter("expand"), Rewriter("expand")
    taker = FullSets(rw.src_decoder, rw.named_form)
    fast = rewrite_capture(rw, src, out / f"runs{src.suffix}", taker)
    slow = rewrite_capture(each, src, out / f"each{src.suffix}")
    assert (out / f"runs{src.suffix}").read_bytes() == (out / f"each{src.suffix}").read_bytes()
    assert fast == slow
    assert state(rw.src_decoder) == state(each.src_decoder)  # (the rewriter numbers every frame 0)
    return fast, taker.taken


def as_pcapng(src: Path, second: int | None = None) -> Path:
    """``src`` (a pcap) as a pcapng file; with ``second``, from record ``second`` on every other
    record on a second interface (the output's is made at its first record) and every third
    record with flags (inbound)."""
    dst = src.with_suffix(".pcapng")
    with open(dst, "wb") as fh:
        w = PcapngWriter(fh)
        if second is not None:
            fh.write(w.interface(1))
        for i, r in enumerate(read_records(src)):
            other = second is not None and i >= second and i % 2 == 1
            fh.write(w.record(r.ts_ns, r.data, 1 if second is not None and i % 3 == 0 else 0, int(other)))
    return dst


def state(dec: Decoder) -> tuple:
    """What the input's core knows at the end: each table's values (when set, not by which
    record: the rewriter numbers frames 0), its last full set and form, each sync clock."""
    tables = {k: ({n: (v.text, v.type_code, v.set_at) for n, v in t.vars.items()},
                  (t.last_full_at, t.named, dict(t.sent_names), tuple(t.names), sorted(t.filled)))
              for k, t in dec.link.tables.items()}
    return tables, dict(dec._sync)


@pytest.mark.parametrize("ext", ["pcap", "pcapng"])
@pytest.mark.parametrize("opts", [
    GenOptions(frames=3000, compress=True),
    GenOptions(frames=3000),
    GenOptions(frames=2000, compress=True, drop=0.05, bad_checksum=0.02, seed=3),
    GenOptions(frames=2000, compress=True, jitter_ms=40, outages=((100.0, 3.0),), seed=4),
    GenOptions(frames=1500, compress=True, form="positional"),
    GenOptions(frames=1500, form="positional", seed=2),
    GenOptions(frames=1500, compress=True, form="positional", drop=0.05, bad_checksum=0.02, seed=3),
], ids=["compressed", "full", "faults", "jitter-outage", "positional", "positional-full", "positional-faults"])
def test_runs_write_what_the_rewriter_writes(tmp_path, opts, ext):
    src = tmp_path / f"in.{ext}"
    generate_file(opts, src)
    st_, taken = both(src, tmp_path)
    assert st_.rewritten >= opts.frames * 0.9
    assert taken > st_.rewritten * 0.85  # (the runs took most: this test compares something)


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
@given(streams(max_datagrams=60), st.one_of(st.none(), st.integers(0, 40)))
def test_pcapng_runs_agree_on_streams_built_to_catch_a_wrong_reuse(tmp_path_factory, stream, second):
    """In a pcapng file, records on a second interface and with flags between a run's records."""
    d = tmp_path_factory.mktemp("ng")
    both(as_pcapng(write_udp(d / "in.pcap", stream), second), d)


@SETTINGS
@given(positional_streams(), st.booleans())
def test_positional_runs_agree_on_streams_built_to_catch_a_wrong_reuse(tmp_path_factory, stream, pcapng):
    d = tmp_path_factory.mktemp("pos")
    src = write_udp(d / "in.pcap", stream)
    both(as_pcapng(src) if pcapng else src, d)


def test_a_pcapng_interface_first_seen_inside_a_run(tmp_path):
    """From record 150 on every other record on a second interface, the first of them amid a
    run: the output's interface is made where the rewriter makes it, the records keep their flags."""
    src = tmp_path / "in.pcap"
    generate_file(GenOptions(frames=300, compress=True), src)
    st_, taken = both(as_pcapng(src, 150), tmp_path)
    assert taken > 250 and st_.rewritten == 300


def positional(*slots: str | None) -> bytes:
    return encode_positional("A", "B", list(slots))


@pytest.mark.parametrize("ext", ["pcap", "pcapng"])
def test_slots_past_the_full_set_make_no_frame_full(tmp_path, ext):
    """A 5-slot frame then 4-slot ones, the beacon's list naming a frame of 4 (BUL-049's a-priori
    list): slot 4 has held a value and no 4-slot frame has one there, so none is a full set."""
    stream = one_sender(positional("1", "2", "3", "4", "5"), *(positional("1", "2", "3", str(i)) for i in range(12)))
    src = write_udp(tmp_path / "in.pcap", stream)
    st_, taken = both(as_pcapng(src) if ext == "pcapng" else src, tmp_path)
    assert taken >= 9 and st_.full == 13


@pytest.mark.parametrize("ext", ["pcap", "pcapng"])
def test_a_slot_never_filled_writes_the_value_a_named_frame_gave(tmp_path, ext):
    """A declared list, a named frame giving its names values, then positional frames that leave
    the first slot empty: the full sets carry the named frame's value there."""
    decl = build_frame(Frame("A", "B", (Field("N", "0"), Field("T", "2"), Field("Q", "Lat"), Field("T", "2"),
                                        Field("Q", "Lon"))))
    named = encode_named("A", "B", [("Lat", 2, "1.5"), ("Lon", 2, "2")])
    stream = one_sender(decl, named, *(positional(None, str(i)) for i in range(12)))
    src = write_udp(tmp_path / "in.pcap", stream)
    st_, taken = both(as_pcapng(src) if ext == "pcapng" else src, tmp_path)
    assert taken >= 9 and b"[:AB|N0|D1.5|D11|C" in (tmp_path / f"runs.{ext}").read_bytes()


def test_a_direction_written_named_is_not_taken_positional(tmp_path):
    """Named frames, then a positional frame in IP fragments (followed, never rewritten: the
    direction is still written named), then positional frames and a bare ``N0``: the first
    positional frame the rewriter writes makes the direction positional, so the bare ``N0`` is a
    positional full set."""
    from scapy.all import fragment  # noqa: PLC0415
    from sl_checks import ether, udp  # noqa: PLC0415

    payloads = [encode_named("A", "B", [("AutoGpsLat", 2, str(i))]) for i in range(3)]
    recs = [ether(udp("10.0.0.1", p, ip_id=i + 1)) for i, p in enumerate(payloads)]
    recs += [ether(f) for f in fragment(udp("10.0.0.1", positional("1", "2", "3", "4"), ip_id=9), fragsize=16)]
    payloads = [positional("1", "2", str(i), None) for i in range(12)] + [b"[:AB|N0|C76]\r\n"]
    recs += [ether(udp("10.0.0.1", p, ip_id=20 + i)) for i, p in enumerate(payloads)]
    src = tmp_path / "in.pcap"
    with open(src, "wb") as fh:
        w = PcapWriter(fh)
        for i, data in enumerate(recs):
            w.write(10**18 + i * 200_000_000, data)
    st_, taken = both(src, tmp_path)
    assert taken >= 9 and re.search(rb"\|N0\|D1\|D2\|D11\|D4\|C..\]\r\n\Z", (tmp_path / "runs.pcap").read_bytes())


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


def _refused_alike(src, out, error: type[Exception], record: int) -> None:
    """Expand of src with the run taker and without it (into out, a name each): the same error,
    the output's name aside, at the same record."""
    errors = []
    for taker in (True, False):
        rw = Rewriter("expand")
        dst = out.with_stem(f"{out.stem}-{taker}")
        with pytest.raises(error) as exc:
            rewrite_capture(rw, src, dst, FullSets(rw.src_decoder, rw.named_form) if taker else None)
        errors.append(str(exc.value).replace(dst.name, ""))
    assert errors[0] == errors[1] and f"record {record}" in errors[0]


@pytest.mark.parametrize("ext", ["pcap", "pcapng"])
def test_a_full_set_past_one_datagram_is_refused_at_the_same_record(tmp_path, ext):
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
    src = as_pcapng(src) if ext == "pcapng" else src
    _refused_alike(src, tmp_path / "out.pcap", TransformError, 33)


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
    _refused_alike(src, tmp_path / "out.pcap", OutputError, 31)


@pytest.mark.parametrize("case", ["before-1970", "past-2554"])
def test_a_pcapng_time_no_record_holds_is_refused_at_the_same_record(tmp_path, case):
    """A pcapng interface (microsecond times) whose time offset (-5 s) takes its records before
    1970, or whose times go past what a nanosecond pcapng record holds, from record 31 on."""
    b = UdpBuilder("10.0.0.1", "10.0.0.9", 7013, 7013)
    back = case == "before-1970"
    opts = struct.pack("<HHq", 14, 8, -5) if back else struct.pack("<HHB3x", 9, 1, 6)  # if_tsoffset, if_tsresol
    idb = struct.pack("<HHI", 1, 0, 65535) + opts + b"\0\0\0\0"
    blocks = [struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1), idb]
    for i in range(40):
        pkt = b.frame(encode_named("A", "B", [("Lat", 2, str(i % 3))]), i + 1)
        ticks = (10**7 + i if i < 30 else 10**6 + i) if back else (10**15 + i if i < 30 else 2**64 // 1000 + i)  # (us)
        pad = b"\0" * (-len(pkt) % 4)
        blocks.append(struct.pack("<IIIII", 0, ticks >> 32, ticks & 0xFFFFFFFF, len(pkt), len(pkt)) + pkt + pad)
    src = tmp_path / "in.pcapng"
    with open(src, "wb") as fh:
        for btype, body in zip([0x0A0D0D0A, 1] + [6] * 40, blocks):
            fh.write(struct.pack("<II", btype, 12 + len(body)) + body + struct.pack("<I", 12 + len(body)))
    _refused_alike(src, tmp_path / "out.pcapng", OutputError, 31)
