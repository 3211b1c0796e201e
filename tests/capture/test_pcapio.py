"""Capture files: our writers read back by our reader and by tshark; damage is named, and the
records before it are kept."""

from __future__ import annotations

import json
import struct
import subprocess
import sys

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


# -- several interfaces, each with its own link type, time resolution and offset ------------------


def _multi_interface(src: list, path, endian: str = "<", old_blocks: bool = False) -> None:
    """``src`` records (Ethernet) rewritten onto three interfaces in one pcapng section:
    Ethernet in nanoseconds; Linux cooked (SLL) in microseconds (no if_tsresol: the default) with
    if_tsoffset 100 s; raw IP in 2^-20 s units, its description block written after the first
    record. Records alternate between the interfaces, in time order. ``old_blocks``: the SLL
    interface's records in obsolete Packet Blocks (type 2, a 16-bit interface id), as old
    tools wrote them."""

    def opt(code: int, val: bytes) -> bytes:
        return struct.pack(endian + "HH", code, len(val)) + val + b"\0" * ((-len(val)) & 3)

    def block(btype: int, body: bytes) -> bytes:
        return struct.pack(endian + "II", btype, 12 + len(body)) + body + struct.pack(endian + "I", 12 + len(body))

    def idb(linktype: int, opts: bytes) -> bytes:
        return block(1, struct.pack(endian + "HHI", linktype, 0, 262144) + opts + (opt(0, b"") if opts else b""))

    out = block(0x0A0D0D0A, struct.pack(endian + "IHHq", 0x1A2B3C4D, 1, 0, -1))
    out += idb(1, opt(9, b"\x09")) + idb(113, opt(14, struct.pack(endian + "q", 100)))
    raw_declared = False
    for i, r in enumerate(src):
        iface = i % 3
        ip = r.data[14:]
        if iface == 0:
            data, ts = r.data, r.ts_ns
        elif iface == 1:
            data, ts = struct.pack("!HHH8sH", 0, 772, 6, bytes(8), 0x0800) + ip, (r.ts_ns - 100 * 10**9) // 1000
        else:
            if not raw_declared:
                out += idb(101, opt(9, bytes([0x80 | 20])))
                raw_declared = True
            data, ts = ip, r.ts_ns * (1 << 20) // 10**9
        n = len(data)
        pad = b"\0" * ((-n) & 3)
        if old_blocks and iface == 1:
            out += block(2, struct.pack(endian + "HHIIII", iface, 0, ts >> 32, ts & 0xFFFFFFFF, n, n) + data + pad)
        else:
            out += block(6, struct.pack(endian + "IIIII", iface, ts >> 32, ts & 0xFFFFFFFF, n, n) + data + pad)
    path.write_bytes(out)


@pytest.mark.parametrize("endian, old_blocks", [("<", False), (">", False), ("<", True), (">", True)])
def test_multi_interface_pcapng_reads_as_tshark_does(sample, tmp_path, endian, old_blocks):
    """Every frame of a pcapng with three interfaces (three link types, three time resolutions,
    a time offset, obsolete Packet Blocks) is read with tshark's time, and compress keeps them
    all: `diff IN OUT` agrees (before, the interface's if_tsoffset was dropped: times 100 s
    early; Packet Blocks were skipped: compress saw and wrote a third fewer records)."""
    from tshark_util import fields

    src = list(read_records(sample))
    multi = tmp_path / "multi.pcapng"
    _multi_interface(src, multi, endian, old_blocks)
    rows = fields(multi, ["frame.time_epoch", "frame.interface_id", "sharedlink.src"], display_filter="sharedlink")
    assert len(rows) == len(src) and {r["frame.interface_id"][0] for r in rows} == {"0", "1", "2"}
    recs = list(read_records(multi))
    assert [r.linktype for r in recs[:3]] == [1, 113, 101]
    want = [int(row["frame.time_epoch"][0].replace(".", "").ljust(19, "0")) for row in rows]
    assert [r.ts_ns for r in recs] == want
    assert all(abs(a.ts_ns - b.ts_ns) < 1000 for a, b in zip(recs, src))  # to the coarsest resolution
    out = tmp_path / "out.pcapng"
    cmd = [sys.executable, "-m", "sharedlink"]
    r = subprocess.run([*cmd, "compress", str(multi), str(out), "--json"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["value_frames"] == len(rows) and json.loads(r.stdout)["records"] == len(src)
    r = subprocess.run([*cmd, "diff", str(multi), str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "AGREE" in r.stdout, r.stdout + r.stderr


def test_udp_builder_wraps_the_ip_id_and_refuses_a_payload_no_datagram_holds():
    """A counter past 65535 as the IP id was a struct.error; so was a payload over 65,507 bytes
    (issue 31's "64 KB frame" traceback came from such a pack)."""
    from sharedlink.capture.packets import MAX_UDP_PAYLOAD

    b = UdpBuilder("10.0.0.1", "10.0.0.2", 7013, 7013)
    f = b.frame(b"x", 70000)
    assert f == b.frame(b"x", 70000 - 65536) and decode_packet(1, f).payload == b"x"
    assert struct.unpack("!H", f[18:20])[0] == 70000 & 0xFFFF
    assert decode_packet(1, b.frame(b"y" * MAX_UDP_PAYLOAD, 1)).payload == b"y" * MAX_UDP_PAYLOAD
    with pytest.raises(ValueError, match="65,508 bytes is more than an IPv4 datagram holds"):
        b.frame(b"z" * (MAX_UDP_PAYLOAD + 1), 1)
