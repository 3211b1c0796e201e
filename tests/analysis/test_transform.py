"""`sharedlink compress` and `expand`: real files, checked against the generator, against
`sharedlink diff`, and packet by packet."""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from sl_captures import captures, write_capture
from sl_cli import run_cli

from sharedlink.analysis.diff import DiffOptions, diff_captures
from sharedlink.analysis.transform import (
    compress_capture,
    expand_capture,
    replace_udp_payload,
    transform_capture,
)
from sharedlink.capture.packets import UdpBuilder, decode_packet, ones_complement_checksum
from sharedlink.capture.pcapio import CaptureError, read_records
from sharedlink.capture.stream import iter_frames
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import parse_frame

CLI = [sys.executable, "-m", "sharedlink"]
SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))


def agree(a: Path, b: Path) -> bool:
    return diff_captures(a, b, DiffOptions(parallel=False)).agree


@pytest.mark.parametrize("form", ["named", "positional"])
@pytest.mark.parametrize("fmt", ["pcap", "pcapng"])
def test_compress_and_expand_give_what_gen_writes_byte_for_byte(tmp_path, form, fmt):
    full, comp = tmp_path / f"full.{fmt}", tmp_path / f"comp.{fmt}"
    generate_file(GenOptions(duration=20, form=form, fmt=fmt, seed=5), full)
    generate_file(GenOptions(duration=20, form=form, fmt=fmt, seed=5, compress=True), comp)
    st = compress_capture(full, tmp_path / f"c.{fmt}")
    assert (tmp_path / f"c.{fmt}").read_bytes() == comp.read_bytes()
    assert (st.full, st.delta, st.copied) == (20, 80, 0)
    expand_capture(comp, tmp_path / f"e.{fmt}")
    assert (tmp_path / f"e.{fmt}").read_bytes() == full.read_bytes()


def test_sync_interval_sets_full_frames(tmp_path):
    full = tmp_path / "full.pcap"
    generate_file(GenOptions(duration=30), full)
    for s, expected_full in ((1.0, 30), (2.0, 15), (0.2, 150), (100.0, 1)):
        st = compress_capture(full, tmp_path / "c.pcap", sync_interval=s)
        assert st.full == expected_full, s
        kinds = [parse_frame(decode_packet(r.linktype, r.data).payload).kind for r in read_records(tmp_path / "c.pcap")]
        # a delta that happens to carry every value is a full set too
        assert kinds[0] == "full" and kinds.count("full") >= expected_full
        assert agree(full, tmp_path / "c.pcap")


def test_compression_keeps_timestamps_addresses_and_packet_checksums(tmp_path):
    full, comp = tmp_path / "full.pcap", tmp_path / "c.pcap"
    generate_file(GenOptions(duration=10, src="C", dst="D", port=7005), full)
    compress_capture(full, comp)
    before, after = list(read_records(full)), list(read_records(comp))
    assert [r.ts_ns for r in before] == [r.ts_ns for r in after]
    assert sum(len(r.data) for r in after) < sum(len(r.data) for r in before)
    for r in after:
        d = decode_packet(r.linktype, r.data)
        assert (d.proto, d.src, d.dst, d.sport, d.dport) == ("udp", "192.168.1.13", "255.255.255.255", 7005, 7005)
        f = parse_frame(d.payload)
        assert (f.dst, f.src, f.checksum.ok) == ("D", "C", True)
        ip = r.data[14:34]
        assert ones_complement_checksum(ip) == 0  # the IP header checksum holds
        udp = r.data[34:]
        pseudo = ip[12:20] + struct.pack("!BBH", 0, 17, len(udp))
        assert ones_complement_checksum(pseudo + udp) in (0, 0xFFFF)  # so does the UDP one


def test_replace_udp_payload_ipv4_and_ipv6_and_refusals():
    b = UdpBuilder("10.0.0.1", "10.0.0.2", 1234, 7013)
    pkt = b.frame(b"old payload", 7)
    new = replace_udp_payload(1, pkt, b"a new, longer payload")
    d = decode_packet(1, new)
    assert (d.payload, d.src, d.dst, d.sport, d.dport) == (b"a new, longer payload", "10.0.0.1", "10.0.0.2", 1234, 7013)
    assert new[18:20] == pkt[18:20]  # IP id kept
    # IPv6 on raw IP
    src, dst = bytes(15) + b"\1", bytes(15) + b"\2"
    udp = struct.pack("!HHHH", 5, 7013, 8 + 3, 0) + b"abc"
    v6 = struct.pack("!IHBB", 6 << 28, len(udp), 17, 64) + src + dst + udp
    new6 = replace_udp_payload(101, v6, b"[:AB|N0|C00]")
    d6 = decode_packet(101, new6)
    assert d6.payload == b"[:AB|N0|C00]" and d6.dport == 7013
    pseudo = src + dst + struct.pack("!IxxxB", len(new6) - 40, 17)
    assert ones_complement_checksum(pseudo + new6[40:]) in (0, 0xFFFF)
    assert replace_udp_payload(1, pkt[:20], b"x") is None  # truncated
    assert replace_udp_payload(1, b"\xff" * 12 + b"\x08\x06" + bytes(28), b"x") is None  # ARP


@SETTINGS
@given(captures())
def test_any_capture_compressed_or_expanded_carries_the_same_data(tmp_path_factory, dgs):
    d = tmp_path_factory.mktemp("prop")
    x = write_capture(d / "x.pcap", dgs)
    c1 = compress_capture(x, d / "c1.pcap")
    compress_capture(x, d / "c2.pcap")
    assert (d / "c1.pcap").read_bytes() == (d / "c2.pcap").read_bytes()  # deterministic
    assert c1.records == len(dgs)
    assert agree(x, d / "c1.pcap")
    expand_capture(d / "c1.pcap", d / "e.pcap")
    assert agree(x, d / "e.pcap")
    expand_capture(x, d / "e2.pcap")
    assert agree(x, d / "e2.pcap")
    # every frame keeps its place, time and addresses; noise and non-value frames stay as they were
    fx = [f for f in iter_frames(x) if not isinstance(f, tuple)]
    fc = [f for f in iter_frames(d / "c1.pcap") if not isinstance(f, tuple)]
    assert [(f.number, f.ts_ns, f.frame is None) for f in fx] == [(f.number, f.ts_ns, f.frame is None) for f in fc]
    for a, b in zip(fx, fc):
        if a.frame is None or a.frame.kind not in ("full", "delta") or a.frame.checksum.ok is False:
            assert a.raw == b.raw
        else:
            assert (b.frame.dst, b.frame.src, b.frame.crlf, b.frame.checksum.ok) == (a.frame.dst, a.frame.src, a.frame.crlf, True)


def test_damaged_input_writes_the_records_before_the_damage(tmp_path):
    full = tmp_path / "full.pcap"
    generate_file(GenOptions(duration=10), full)
    data = full.read_bytes()
    (tmp_path / "cut.pcap").write_bytes(data[:-30])
    st = compress_capture(tmp_path / "cut.pcap", tmp_path / "c.pcap")
    assert st.error and "record 50" in st.error
    assert len(list(read_records(tmp_path / "c.pcap"))) == 49
    with pytest.raises(CaptureError):
        compress_capture(tmp_path / "missing.pcap", tmp_path / "c2.pcap")
    assert not (tmp_path / "c2.pcap").exists() and not (tmp_path / "c2.pcap.part").exists()
    with pytest.raises(ValueError):
        transform_capture(full, tmp_path / "x.pcap", "shrink")


def test_cli_compress_expand_and_errors(tmp_path):
    full = tmp_path / "full.pcap"
    generate_file(GenOptions(duration=10, form="positional"), full)
    r = run_cli("compress", str(full), str(tmp_path / "c.pcap"), "--sync-interval", "2", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert (out["mode"], out["full"], out["delta"], out["records"]) == ("compress", 5, 45, 51)
    assert 0 < out["saving"] < 1
    r = run_cli("expand", str(tmp_path / "c.pcap"), str(tmp_path / "e.pcap"))
    assert r.returncode == 0 and "wrote" in r.stderr and "larger" in r.stderr
    assert (tmp_path / "e.pcap").read_bytes() == full.read_bytes()
    for args, msg in (
        (["compress", str(tmp_path / "nope.pcap"), "-o", str(tmp_path / "o.pcap")], "nope.pcap: no such file"),
        (["compress", str(full), "-o", str(tmp_path / "o.pcap"), "--sync-interval", "0"], "--sync-interval"),
        (["expand", str(full), "-o", str(tmp_path / "no-dir" / "o.pcap")], "No such file"),
        (["expand", str(full), "-o", str(tmp_path / "o.pcap"), "--variables", "a:x"], "--variables"),
    ):
        r = run_cli(*args)
        assert r.returncode == 2 and msg in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)
    (tmp_path / "cut.pcap").write_bytes(full.read_bytes()[:-10])
    r = run_cli("compress", str(tmp_path / "cut.pcap"), "-o", str(tmp_path / "o.pcap"))
    assert r.returncode == 2 and "truncated record" in r.stderr and "Traceback" not in r.stderr
    assert len(list(read_records(tmp_path / "o.pcap"))) == 50
