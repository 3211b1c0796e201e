"""Capture files: our writers read back by our reader and by tshark; damage is named, and the
records before it are kept."""

from __future__ import annotations

import struct
import subprocess

import pytest

from sharedlink.capture.packets import UdpBuilder, decode_packet, ones_complement_checksum
from sharedlink.capture.pcapio import (
    DIR_INBOUND,
    DIR_OUTBOUND,
    LINKTYPE_USER0,
    CaptureError,
    PcapngWriter,
    PcapWriter,
    read_records,
)
from sharedlink.generators.beacon import GenOptions, generate_file


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    p = tmp_path_factory.mktemp("pcap") / "s.pcap"
    generate_file(GenOptions(duration=4), p)
    return p


def test_pcapng_user_linktype_with_direction_flags(tmp_path):
    p = tmp_path / "u.pcapng"
    with open(p, "wb") as fh:
        w = PcapngWriter(fh, LINKTYPE_USER0, if_name="/dev/ttyUSB0")
        w.write(1_767_268_800_000_000_001, b"[:AB|", DIR_INBOUND)
        w.write(1_767_268_800_000_000_002, b"C00]\r\n", DIR_OUTBOUND)
        w.write(1_767_268_800_000_000_003, b"xyz")
    recs = list(read_records(p))
    assert [(r.number, r.ts_ns % 10, r.data, r.flags & 3, r.linktype) for r in recs] == [
        (1, 1, b"[:AB|", 1, 147),
        (2, 2, b"C00]\r\n", 2, 147),
        (3, 3, b"xyz", 0, 147),
    ]
    out = subprocess.run(
        ["tshark", "-r", str(p), "-T", "fields", "-e", "frame.len", "-e", "frame.p2p_dir", "-e", "frame.time_epoch"],
        capture_output=True, text=True, check=True,
    ).stdout.splitlines()
    assert [line.split("\t")[0] for line in out] == ["5", "6", "3"]
    assert out[0].split("\t")[2] == "1767268800.000000001"


def test_microsecond_and_big_endian_pcap(tmp_path):
    p = tmp_path / "be.pcap"
    data = b"\x00" * 20
    with open(p, "wb") as fh:
        fh.write(struct.pack(">IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
        fh.write(struct.pack(">IIII", 1000, 250, len(data), len(data)) + data)
    (r,) = read_records(p)
    assert r.ts_ns == 1000 * 10**9 + 250_000 and r.data == data


@pytest.mark.parametrize("cut", [10, 24, 30, 100])
def test_truncated_file_keeps_good_records_and_names_the_bad_one(sample, tmp_path, cut):
    raw = sample.read_bytes()
    recs = list(read_records(sample))
    bad = tmp_path / "t.pcap"
    end_of_third = 24 + sum(16 + len(r.data) for r in recs[:3])
    size = end_of_third + cut if cut >= 24 else cut
    bad.write_bytes(raw[:size])
    got = []
    with pytest.raises(CaptureError) as ei:
        for r in read_records(bad):
            got.append(r)
    if cut < 24:
        assert ei.value.record is None and got == []
    else:
        assert got == recs[:3] and ei.value.record == 4
    assert str(bad) in str(ei.value)


def test_damaged_length_is_reported(sample, tmp_path):
    raw = bytearray(sample.read_bytes())
    struct.pack_into("<I", raw, 24 + 8, 0x7FFFFFFF)  # first record's length
    bad = tmp_path / "d.pcap"
    bad.write_bytes(bytes(raw))
    with pytest.raises(CaptureError, match="record 1: record length .* implausible"):
        list(read_records(bad))


@pytest.mark.parametrize("content,reason", [(b"", "empty"), (b"hello world, not a capture", "not a pcap")])
def test_not_a_capture(tmp_path, content, reason):
    p = tmp_path / "x.pcap"
    p.write_bytes(content)
    with pytest.raises(CaptureError, match=reason):
        list(read_records(p))


def test_missing_file(tmp_path):
    with pytest.raises(CaptureError, match="No such file"):
        list(read_records(tmp_path / "nope.pcap"))


def test_udp_builder_checksums_match_rfc1071():
    b = UdpBuilder("10.1.2.3", "127.0.0.1", 7013, 9999)
    for payload in (b"", b"x", b"[:AB|C00]\r\n", bytes(range(256)) * 3):
        pkt = b.frame(payload, 77)
        ip = pkt[14:34]
        assert ones_complement_checksum(ip) == 0  # a valid header sums to 0xFFFF
        udp = pkt[34:]
        pseudo = ip[12:20] + struct.pack("!BBH", 0, 17, len(udp))
        assert ones_complement_checksum(pseudo + udp) == 0
        d = decode_packet(1, pkt)
        assert d.payload == payload and (d.sport, d.dport, d.src, d.dst) == (7013, 9999, "10.1.2.3", "127.0.0.1")


def test_decode_packet_on_truncated_and_foreign_packets():
    pkt = UdpBuilder("10.1.2.3", "127.0.0.1", 7013, 7013).frame(b"[:AB|C00]\r\n", 1)
    for n in range(len(pkt)):
        d = decode_packet(1, pkt[:n])  # never raises: None, or what the bytes still hold
        if n < 42:
            assert d is None
        else:
            assert d.payload == pkt[42:n]
    assert decode_packet(999, b"abc") is None
    arp = pkt[:12] + b"\x08\x06" + pkt[14:]
    assert decode_packet(1, arp) is None


def test_pcap_writer_round_trip(tmp_path):
    p = tmp_path / "r.pcap"
    with open(p, "wb") as fh:
        w = PcapWriter(fh, LINKTYPE_USER0)
        w.write(4 * 10**18 + 7, b"abc")
    assert p.read_bytes()[:4] == struct.pack("<I", 0xA1B23C4D)
    (r,) = read_records(p)
    assert (r.ts_ns, r.data, r.linktype, r.number) == (4 * 10**18 + 7, b"abc", LINKTYPE_USER0, 1)
