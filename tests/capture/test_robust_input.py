"""Captures Wireshark reads that are unusual: other link types (SLL2 alone and in a pcapng,
loopback, raw IP, PPP through scapy), IPv4 and IPv6 fragments, IPv6 extension headers, pcapng
blocks that take a frame number, and a pcap header tshark refuses. For each, the commands see
the frames tshark with the dissector sees, with tshark's frame numbers, and leave the input
untouched."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import random
import struct
import subprocess
from pathlib import Path

import pytest
from scapy.layers.inet import IP, UDP, Ether, fragment
from scapy.layers.inet6 import (
    IPv6,
    IPv6ExtHdrDestOpt,
    IPv6ExtHdrFragment,
    IPv6ExtHdrHopByHop,
    IPv6ExtHdrRouting,
    fragment6,
)
from scapy.layers.l2 import CookedLinuxV2, Loopback
from scapy.layers.ppp import PPP
from scapy.utils import wrpcap

from sharedlink.capture.packets import PacketDecoder, decode_packet
from sharedlink.capture.pcapio import read_records
from sharedlink.cli import main
from sharedlink.generators.beacon import GenOptions, generate_file
from tshark_util import TSHARK_CMD, _clean_env, fields


@pytest.fixture(scope="module")
def beacon(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("robust") / "beacon.pcap"
    generate_file(GenOptions(frames=24), p)
    return p


def _packets(path: Path) -> list[Ether]:
    from scapy.utils import rdpcap

    return list(rdpcap(str(path)))


def _write(path: Path, pkts, linktype: int | None = None) -> Path:
    wrpcap(str(path), pkts, linktype=linktype)
    return path


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def tshark_numbers(path: Path) -> list[int]:
    """Frame numbers of the packets tshark with the dissector shows as SharedLink."""
    return [int(r["frame.number"][0]) for r in fields(path, ["frame.number"], display_filter="sharedlink")]


def run(capsys, *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def our_numbers(capsys, path: Path) -> list[int]:
    code, out, err = run(capsys, "export", path, "--format", "csv")
    assert code == 0, err
    return [int(r["number"]) for r in csv.DictReader(io.StringIO(out))]


def check_all_commands(capsys, path: Path, expected: list[int], tmp_path: Path) -> None:
    """stats, export, diff (against itself) and compress see tshark's frames; the input is
    not touched."""
    before = digest(path)
    assert expected, "the oracle saw no SharedLink frame: the case tests nothing"
    assert our_numbers(capsys, path) == expected
    code, out, err = run(capsys, "stats", "--json", path)
    assert code == 0, err
    assert json.loads(out)["frames"] == len(expected)
    code, out, err = run(capsys, "diff", "--json", path, path)
    assert code == 0, err
    assert json.loads(out)["a"]["value_frames"] == len(expected)
    out_path = tmp_path / ("c" + path.suffix)
    code, _, err = run(capsys, "compress", path, out_path)
    assert code == 0, err
    assert len(tshark_numbers(out_path)) == len(expected)
    assert digest(path) == before


# -- link types ------------------------------------------------------------------------------


def test_sll2_alone(beacon, tmp_path, capsys):
    pkts = []
    for p in _packets(beacon):
        q = CookedLinuxV2(proto=0x0800, ifindex=2) / p[IP]
        q.time = p.time
        pkts.append(q)
    path = _write(tmp_path / "sll2.pcap", pkts, 276)
    assert read_records(path).__next__().linktype == 276
    check_all_commands(capsys, path, tshark_numbers(path), tmp_path)


def test_sll2_as_one_interface_of_a_pcapng(beacon, tmp_path, capsys):
    sll2 = _write(tmp_path / "sll2.pcap", [CookedLinuxV2(proto=0x0800) / p[IP] for p in _packets(beacon)], 276)
    merged = tmp_path / "mixed.pcapng"
    subprocess.run(["mergecap", "-a", "-F", "pcapng", "-w", str(merged), str(beacon), str(sll2)], check=True)
    assert {r.linktype for r in read_records(merged)} == {1, 276}
    expected = tshark_numbers(merged)
    assert len(expected) == 48
    assert our_numbers(capsys, merged) == expected
    code, out, err = run(capsys, "stats", "--json", merged)
    assert code == 0 and json.loads(out)["frames"] == 48, err
    code, out, err = run(capsys, "diff", "--json", merged, merged)
    assert code == 0 and json.loads(out)["a"]["value_frames"] == 48, err
    compressed = tmp_path / "c.pcapng"  # one output interface per input interface
    code, _, err = run(capsys, "compress", merged, compressed)
    assert code == 0, err
    assert {r.linktype for r in read_records(compressed)} == {1, 276}
    assert tshark_numbers(compressed) == expected
    code, out, err = run(capsys, "diff", merged, compressed)
    assert code == 0, out


@pytest.mark.parametrize("kind", ["null", "loop", "raw", "ipv4", "ppp"])
def test_other_link_types(beacon, tmp_path, capsys, kind):
    ips = [p[IP] for p in _packets(beacon)]
    if kind == "null":
        pkts, lt = [Loopback(type=2) / ip for ip in ips], 0
    elif kind == "loop":  # OpenBSD loopback: the family in network order
        pkts, lt = [struct.pack(">I", 2) + bytes(ip) for ip in ips], 108
    elif kind == "raw":
        pkts, lt = ips, 101
    elif kind == "ipv4":
        pkts, lt = [bytes(ip) for ip in ips], 228
    else:  # PPP: decoded through scapy
        pkts, lt = [PPP(proto=0x0021) / ip for ip in ips], 9
    path = _write(tmp_path / f"{kind}.pcap", pkts, lt)
    expected = tshark_numbers(path)
    assert len(expected) == 24
    assert our_numbers(capsys, path) == expected


# -- fragments and extension headers ------------------------------------------------------------


def _fragmented(beacon: Path, shuffle: bool) -> list:
    rnd = random.Random(5)
    out = []
    for p in _packets(beacon):
        frags = [Ether(src=p.src, dst=p.dst) / f for f in fragment(p[IP], fragsize=48)]
        if shuffle:
            rnd.shuffle(frags)
        for f in frags:
            f.time = p.time
        out += frags
    return out


@pytest.mark.parametrize("shuffle", [False, True], ids=["in-order", "shuffled"])
def test_ipv4_fragments_reassembled_as_wireshark_does(beacon, tmp_path, capsys, shuffle):
    path = _write(tmp_path / "frag.pcap", _fragmented(beacon, shuffle))
    expected = tshark_numbers(path)
    assert len(expected) == 24  # on the fragment that completes each datagram
    check_all_commands(capsys, path, expected, tmp_path)


def test_reassembled_payload_is_the_original(beacon):
    originals = [bytes(p[UDP].payload) for p in _packets(beacon)]
    dec = PacketDecoder()
    got = [d.payload for d in (dec.decode(1, bytes(f)) for f in _fragmented(beacon, True)) if d is not None]
    assert got == originals
    # without reassembly a fragment is no datagram
    assert all(decode_packet(1, bytes(f)) is None for f in _fragmented(beacon, False))


def test_duplicate_and_overlapping_fragments(beacon):
    p = _packets(beacon)[0]
    frags = [bytes(Ether() / f) for f in fragment(p[IP], fragsize=40)]
    dec = PacketDecoder()
    seq = [frags[0], frags[0], *frags[2:], frags[1]]  # a duplicate, the middle one last
    out = [dec.decode(1, f) for f in seq]
    assert [d is not None for d in out] == [False] * (len(seq) - 1) + [True]
    assert out[-1].payload == bytes(p[UDP].payload)


_EXTENSIONS = {
    "hop-by-hop": lambda: IPv6ExtHdrHopByHop(),
    "dest-options": lambda: IPv6ExtHdrDestOpt(),
    "routing": lambda: IPv6ExtHdrRouting(addresses=["2001:db8::9"], segleft=0),
    "atomic-fragment": lambda: IPv6ExtHdrFragment(id=7, offset=0, m=0),
    "chain": lambda: IPv6ExtHdrHopByHop() / IPv6ExtHdrDestOpt() / IPv6ExtHdrRouting(segleft=0),
}


@pytest.mark.parametrize("ext", list(_EXTENSIONS))
def test_ipv6_extension_headers(beacon, tmp_path, capsys, ext):
    pkts = []
    for p in _packets(beacon):
        q = Ether() / IPv6(src="2001:db8::2", dst="ff02::1") / _EXTENSIONS[ext]() / UDP(
            sport=p[UDP].sport, dport=p[UDP].dport) / bytes(p[UDP].payload)
        q.time = p.time
        pkts.append(q)
    path = _write(tmp_path / "v6.pcap", pkts)
    expected = tshark_numbers(path)
    assert len(expected) == 24
    check_all_commands(capsys, path, expected, tmp_path)


def test_ipv6_fragments(beacon, tmp_path, capsys):
    pkts = []
    for p in _packets(beacon):
        whole = IPv6(src="2001:db8::2", dst="ff02::1") / IPv6ExtHdrFragment(id=p[IP].id) / UDP(
            sport=p[UDP].sport, dport=p[UDP].dport) / bytes(p[UDP].payload)
        for f in fragment6(whole, 96):
            e = Ether() / f
            e.time = p.time
            pkts.append(e)
    path = _write(tmp_path / "v6frag.pcap", pkts)
    expected = tshark_numbers(path)
    assert len(expected) == 24
    check_all_commands(capsys, path, expected, tmp_path)


# -- pcapng blocks and pcap headers ----------------------------------------------------------------


def _block(btype: int, body: bytes) -> bytes:
    body += b"\0" * ((-len(body)) & 3)
    return struct.pack("<II", btype, 12 + len(body)) + body + struct.pack("<I", 12 + len(body))


def test_pcapng_blocks_that_take_a_frame_number(beacon, tmp_path, capsys):
    ng = tmp_path / "b.pcapng"
    subprocess.run(["editcap", "-F", "pcapng", str(beacon), str(ng)], check=True)
    data = ng.read_bytes()
    blocks, i = [], 0
    while i < len(data):
        blocks.append(data[i : i + struct.unpack_from("<I", data, i + 4)[0]])
        i += len(blocks[-1])
    custom = _block(0x00000BAD, struct.pack("<I", 32473) + b"a custom block")
    nocopy = _block(0x40000BAD, struct.pack("<I", 32473) + b"do not copy")
    journal = _block(9, b"__REALTIME_TIMESTAMP=1767268800000000\nMESSAGE=hello\n")
    names = _block(4, struct.pack("<HH", 0, 0))  # no frame
    path = tmp_path / "custom.pcapng"
    path.write_bytes(b"".join(blocks[:2] + [custom, blocks[2], nocopy, journal, blocks[3], names] + blocks[4:]))
    expected = tshark_numbers(path)
    assert expected[:3] == [2, 5, 6]
    check_all_commands(capsys, path, expected, tmp_path)


_HEADER_DAMAGE = {
    "random bytes": lambda h: h[:4] + bytes(random.Random(3).randrange(256) for _ in range(20)),
    "major version 1": lambda h: h[:4] + struct.pack("<HH", 1, 0) + h[8:],
    "reserved link-type bits": lambda h: h[:20] + struct.pack("<I", 0x00010001),
    "unknown link type": lambda h: h[:20] + struct.pack("<I", 60000),
}


@pytest.mark.parametrize("damage", list(_HEADER_DAMAGE))
def test_garbage_pcap_header_is_refused_as_tshark_does(beacon, tmp_path, capsys, damage):
    data = beacon.read_bytes()
    path = tmp_path / "garbage.pcap"
    path.write_bytes(_HEADER_DAMAGE[damage](data[:24]) + data[24:])
    before = digest(path)
    r = subprocess.run([*TSHARK_CMD, "-r", str(path)], capture_output=True, text=True, env=_clean_env(), timeout=60)
    assert r.returncode != 0  # the oracle refuses it
    for args in (["stats", path], ["export", path], ["diff", path, path], ["compress", path, tmp_path / "c.pcap"],
                 ["plot", path, "-o", tmp_path / "p.png"], ["replay", "--limit", "1", "--topspeed", path]):
        code, _, err = run(capsys, *args)
        assert code == 2, (args, err)
        assert "file header" in err and "Traceback" not in err, err
    assert not (tmp_path / "c.pcap").exists() and not (tmp_path / "p.png").exists()
    assert digest(path) == before
