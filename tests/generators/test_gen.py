"""`sharedlink gen`: real files, read back by our reader, by scapy and by tshark."""

from __future__ import annotations

import json
import logging
import math
import subprocess
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli

from sharedlink.capture.packets import decode_packet
from sharedlink.capture.pcapio import read_records
from sharedlink.generators.beacon import DEFAULT_START_NS, GenOptions, beacon_payloads, generate_file
from sharedlink.generators.scenario import MPH, bearing_deg, distance_m
from sharedlink.protocols.codec import (
    encode_named,
    encode_positional,
    named_values,
    parse_frame,
    positional_values,
)
from sharedlink.protocols.state import LinkState

logging.getLogger("scapy").setLevel(logging.ERROR)
CLI = [sys.executable, "-m", "sharedlink"]


def frames_of(path: Path):
    for r in read_records(path):
        d = decode_packet(r.linktype, r.data)
        assert d is not None and d.proto == "udp"
        yield r, d, parse_frame(d.payload)


def test_same_seed_same_bytes_and_other_seed_differs(tmp_path):
    a, b, c = tmp_path / "a.pcap", tmp_path / "b.pcap", tmp_path / "c.pcap"
    for p, seed in ((a, 3), (b, 3), (c, 4)):
        generate_file(GenOptions(duration=30, compress=True, drop=0.05, bad_checksum=0.05, jitter_ms=10, seed=seed), p)
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()


def test_default_capture_shape(tmp_path):
    p = tmp_path / "d.pcap"
    stats = generate_file(GenOptions(), p)
    rows = list(frames_of(p))
    assert len(rows) == stats.frames == 300  # 60 s at 5 Hz
    r0, d0, f0 = rows[0]
    assert r0.ts_ns == DEFAULT_START_NS
    assert all(b[0].ts_ns - a[0].ts_ns == 200_000_000 for a, b in zip(rows, rows[1:]))
    assert (d0.dport, d0.sport, d0.dst) == (7013, 7013, "255.255.255.255")
    assert all(d.payload.endswith(b"]\r\n") and f.checksum.ok for _, d, f in rows)
    assert all((f.dst, f.src, f.kind) == ("A", "B", "full") for _, _, f in rows)
    names = [v.name for v in named_values(f0.fields)]
    assert names == ["AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel"]


def test_track_is_physically_consistent():
    """Heading is the direction of travel; speed is the distance covered per second."""
    pts = []
    for _, payload, _ in beacon_payloads(GenOptions(duration=120, seed=5)):
        v = {nv.name: float(nv.text) for nv in named_values(parse_frame(payload).fields)}
        pts.append((v["AutoGpsLat"], v["AutoGpsLon"], v["AutoGpsHead"], v["AutoGpsVel"]))
    moving = 0
    for (la1, lo1, h1, s1), (la2, lo2, h2, s2) in zip(pts, pts[1:]):
        d = distance_m(la1, lo1, la2, lo2)
        expect = (s1 + s2) / 2 * MPH * 0.2
        assert d == pytest.approx(expect, abs=0.02 + 0.01 * expect)
        if d > 0.5:
            moving += 1
            b = bearing_deg(la1, lo1, la2, lo2)
            mid = h1 + ((h2 - h1 + 540) % 360 - 180) / 2
            assert abs((b - mid + 540) % 360 - 180) < 1.0
    assert moving > len(pts) / 2
    speeds = [p[3] for p in pts]
    assert max(speeds) > 10 and min(speeds) == 0.0  # it drives and it stops
    assert len({round(p[2]) for p in pts}) > 5  # it turns
    assert all(math.isfinite(x) for p in pts for x in p)


@pytest.mark.parametrize("form", ["named", "positional"])
def test_payloads_are_what_the_codec_builds(form):
    opts = GenOptions(duration=20, compress=True, form=form, seed=2)
    for _ts, payload, kind in beacon_payloads(opts):
        f = parse_frame(payload)
        # a delta in which every value changed is a full set by its content
        assert f.kind == kind or (kind, f.kind) == ("delta", "full")
        if kind == "declaration":
            continue
        if form == "named":
            vals = [(v.name, v.type_code, v.text) for v in named_values(f.fields)]
            assert payload == encode_named("A", "B", vals)
        else:
            ordinal, texts = positional_values(f.fields)
            assert payload == encode_positional("A", "B", texts, ordinal)


@pytest.mark.parametrize("form", ["named", "positional"])
def test_compressed_stream_carries_the_full_streams_values(tmp_path, form):
    full, comp = tmp_path / "f.pcap", tmp_path / "c.pcap"
    generate_file(GenOptions(duration=30, form=form, seed=9), full)
    s = generate_file(GenOptions(duration=30, form=form, seed=9, compress=True, sync_interval=1.0), comp)
    assert s.delta > 0 and s.full >= 30
    states = []
    for path in (full, comp):
        link, snap = LinkState(), []
        for r, _, f in frames_of(path):
            link.apply(f, r.number, r.ts_ns)
            if f.kind != "declaration":
                snap.append((r.ts_ns, link.table("B", "A").values()))
        states.append(snap)
    assert states[0] == states[1]
    # a full set at least every sync interval
    fulls = [r.ts_ns for r, _, f in frames_of(comp) if LinkState().table("B", "A").kind(f) == "full"]
    assert all(b - a <= 1_000_000_000 for a, b in zip(fulls, fulls[1:]))
    assert comp.stat().st_size < full.stat().st_size


def test_faults(tmp_path):
    p = tmp_path / "f.pcap"
    s = generate_file(GenOptions(duration=120, drop=0.1, bad_checksum=0.1, jitter_ms=40, seed=11), p)
    rows = list(frames_of(p))
    assert len(rows) == s.frames == 600 - s.dropped and 30 < s.dropped < 100
    bad = [f for _, _, f in rows if f.checksum.ok is False]
    assert len(bad) == s.bad_checksums and 30 < len(bad) < 100
    ts = [r.ts_ns for r, _, _ in rows]
    assert ts == sorted(ts)
    offsets = [(t - DEFAULT_START_NS) % 200_000_000 for t in ts]
    off = [min(o, 200_000_000 - o) for o in offsets]
    assert max(off) <= 20_000_000 and max(off) > 1_000_000  # jitter within +-MS/2, and present


def test_pcapng_keeps_nanoseconds(tmp_path):
    p = tmp_path / "n.pcapng"
    opts = GenOptions(duration=2, fmt="pcapng", start_ns=DEFAULT_START_NS + 123_456_789)
    generate_file(opts, p)
    recs = list(read_records(p))
    assert recs[0].ts_ns == DEFAULT_START_NS + 123_456_789
    out = subprocess.run(
        ["tshark", "-n", "-r", str(p), "-T", "fields", "-e", "frame.time_epoch"], capture_output=True, text=True, check=True
    ).stdout.split()
    assert out[0] == "1767268800.123456789" and len(out) == 10


def test_tshark_and_scapy_read_headers_as_valid(tmp_path):
    p = tmp_path / "v.pcap"
    generate_file(GenOptions(duration=4, compress=True), p)
    out = subprocess.run(
        ["tshark", "-n", "-r", str(p), "-o", "ip.check_checksum:TRUE", "-o", "udp.check_checksum:TRUE",
         "-T", "fields", "-e", "ip.checksum.status", "-e", "udp.checksum.status", "-e", "udp.length", "-e", "_ws.expert"],
        capture_output=True, text=True, check=True,
    ).stdout.splitlines()
    assert len(out) == 20
    for line in out:
        ip_ok, udp_ok, ulen, *expert = line.split("\t")
        assert ip_ok == "1" and udp_ok == "1" and not any(expert)
    from scapy.all import IP, UDP, Ether, rdpcap

    pkts = rdpcap(str(p))
    for pkt in pkts:
        rebuilt = Ether(bytes(pkt))
        del rebuilt[IP].chksum, rebuilt[UDP].chksum
        rebuilt = Ether(bytes(rebuilt))  # scapy recomputes both checksums
        assert (rebuilt[IP].chksum, rebuilt[UDP].chksum) == (pkt[IP].chksum, pkt[UDP].chksum)


def test_scapy_layer_reads_generated_frames(tmp_path):
    from scapy.all import rdpcap

    from sharedlink.scapy_layer import SharedLink

    p = tmp_path / "s.pcap"
    generate_file(GenOptions(duration=2, compress=True), p)
    pkts = rdpcap(str(p))
    assert all(SharedLink in pkt for pkt in pkts)
    layer = pkts[0][SharedLink]
    assert layer.dst == b"A" and layer.chksum is not None
    assert bytes(layer) == bytes(pkts[0])[42:]  # rebuilt by the codec, byte-identical
    assert "checksum good" in layer.mysummary()


def test_cli_gen_json_and_errors(tmp_path):
    out = tmp_path / "c.pcapng"
    r = run_cli("gen", str(out), "--duration", "3", "--compress", "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["format"] == "pcapng" and summary["frames"] == 15 and out.exists()
    assert summary["kinds"] == {"full": 3, "delta": 12}
    for bad in (["--src", "Z"], ["--drop", "2"], ["--rate", "0"], ["--format", "xml"], ["--frames", "0"]):
        r = run_cli("gen", str(tmp_path / "x.pcap"), *bad)
        assert r.returncode == 2, bad
        assert "error" in r.stderr and "Traceback" not in r.stderr
    r = run_cli("gen", str(tmp_path / "no" / "dir.pcap"))
    assert r.returncode == 2 and "No such file" in r.stderr and "Traceback" not in r.stderr
    r = run_cli("gen", "--help")
    assert r.returncode == 0 and "--sync-interval" in r.stdout
