"""Odd captures through the fast tiers, against tshark with the dissector and its tap (issue 28).

Each capture is built here with scapy (packets) and the package's PcapWriter/PcapngWriter
(containers), never from our decoder's output: Linux cooked v2 (SLL2) records, IPv4 datagrams
split into fragments (in order, out of order, one never completed), records whose time stamps go
back and forth, and a pcapng file with three interfaces of three link types. On each:

* `stats` (the counts mode: Decoder.count_run on a classic pcap's blocks) equals `stats` the plain
  way (every frame through the reference decoder);
* the tap (`tshark -z sharedlink,stats` with sharedlink.lua) gives the same frames, checksum
  failures, late frames, noise, kinds, pairs and per-variable counts (docs/fields-sharedlink.md,
  "Counts");
* `diff`'s change records through the compiled layouts and the block tier equal the reference
  decoder's (test_core_changes.same_changes), `ingest` keeps as many frames and `export` (jsonl)
  as many of each kind.

What Wireshark does and we follow: fragments are reassembled (ip.defragment on by default), the
frame counted in the record that completes the datagram, in any order; a datagram missing a
fragment is no frame on either side. Time stamps are taken as they come: a frame whose time is
before its direction's last full frame is not late (the gap is negative), records are counted in
file order.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from core_streams import stats_by_reference
from test_core_changes import same_changes
from test_stats import tap_stats

import sharedlink.analysis.compiled_blocks as compiled_blocks
from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.export import ExportOptions, export
from sharedlink.analysis.stats import CaptureStats, capture_stats, one_line
from sharedlink.capture.pcapio import (
    LINKTYPE_ETHERNET,
    LINKTYPE_IPV4,
    LINKTYPE_LINUX_SLL2,
    PcapngWriter,
    PcapWriter,
)
from sharedlink.protocols.codec import encode_named

T0 = 1_700_000_000 * 10**9
MS = 1_000_000


def beacon(src: str, dst: str, n: int, big: frozenset[int] = frozenset()) -> Iterator[tuple[int, bytes]]:
    """(time offset ns, payload): a named beacon at 5 Hz, a full set every 20th frame (late frames
    before each), a delta of Lat between, a bad checksum every 37th, a 3 s silence after frame 25;
    the full sets whose index is in ``big`` carry a 3000-byte string (a datagram over the MTU)."""
    t = 0
    for i in range(n):
        lat = "%.5f" % (38.0 + i / 1000)
        if i % 20 == 0:
            text = ("x" * 3000 + str(i)) if i in big else "run %d" % i
            raw = encode_named(dst, src, [("Lat", 2, lat), ("Lon", 2, "-77.1"), ("Mode", 4, text)])
        else:
            raw = encode_named(dst, src, [("Lat", 2, lat)])
        if i % 37 == 5:
            raw = raw[:-5] + b"00]\r\n"  # a wrong checksum
        yield t, raw
        t += 3000 * MS if i == 25 else 200 * MS


def udp(src_ip: str, payload: bytes, sport: int = 7013, ip_id: int = 1):
    from scapy.all import IP, UDP  # noqa: PLC0415 (slow import)

    return IP(src=src_ip, dst="10.0.0.9", id=ip_id, flags=0) / UDP(sport=sport, dport=7013) / payload


def ether(pkt) -> bytes:
    from scapy.all import Ether  # noqa: PLC0415

    return bytes(Ether(src="02:00:00:00:00:01", dst="02:00:00:00:00:09") / pkt)


def sll2(pkt) -> bytes:
    from scapy.layers.l2 import CookedLinuxV2  # noqa: PLC0415

    return bytes(CookedLinuxV2(proto=0x0800, ifindex=2, lladdrtype=1, pkttype=0, lladdrlen=6,
                               src=b"\x02\0\0\0\0\x01\0\0") / pkt)


def write_pcap(path: Path, records: list[tuple[int, bytes]], linktype: int = LINKTYPE_ETHERNET) -> Path:
    with open(path, "wb") as fh:
        w = PcapWriter(fh, linktype)
        for ts, data in records:
            w.write(T0 + ts, data)
    return path


@pytest.fixture
def tiers(monkeypatch) -> dict[str, int]:
    """Frames the fast tiers take: ``counts`` (Decoder.count_run, stats), ``compiled`` (diff's
    compiled layouts, per record and block), ``block`` (compiled_blocks' block tier)."""
    took = {"counts": 0, "compiled": 0, "block": 0}
    run = Decoder.count_run

    def count_run(self, *args):
        r = run(self, *args)
        if r is not None:
            took["counts"] += r[2]
        return r

    make = compiled_blocks.block_taker

    def block_taker(*args, **kwargs):
        take = make(*args, **kwargs)

        def counted(*a):
            got = take(*a)
            if got is not None:
                took["block"] += got[2]
            return got

        return counted

    monkeypatch.setattr(Decoder, "count_run", count_run)
    monkeypatch.setattr(compiled_blocks, "block_taker", block_taker)
    return took


def agree(path: Path, took: dict[str, int]) -> CaptureStats:
    """stats (counts mode) == stats by reference == the tap; diff's tiers == the reference;
    ingest keeps as many frames, export (jsonl) as many of each kind. Returns the statistics."""
    from sharedlink.fleet.ingest import ingest  # noqa: PLC0415

    st = capture_stats(path)
    ref = stats_by_reference(path)
    skip = ("path", "limits", "error", "other_records")
    assert {k: v for k, v in ref.to_dict().items() if k not in skip} == \
        {k: v for k, v in st.to_dict().items() if k not in skip}
    tap = tap_stats(path)
    assert (tap["Frames"], tap["Checksum failures"], tap["Sync late"], tap["Noise"]) == (
        st.frames, st.checksum_failures, st.sync_late, st.noise_segments)
    assert tap["kinds"] == st.kinds
    assert tap["pairs"] == {p.pair: (p.frames, p.checksum_failures, p.sync_late, p.kinds) for p in st.pairs.values()}
    assert tap["vars"] == {k: (v.count, one_line(v.last or "")) for k, v in st.variables.items()}
    took["compiled"] += same_changes(path)
    assert ingest([path], path.parent / (path.stem + "-ds")).frames == st.frames
    out = io.StringIO()
    assert export(path, out, ExportOptions(fmt="jsonl")).frames == st.frames
    kinds: dict[str, int] = {}
    for line in out.getvalue().splitlines():
        kind = json.loads(line)["kind"]
        kinds[kind] = kinds.get(kind, 0) + 1
    assert kinds == st.kinds
    return st


def test_linux_cooked_v2(tmp_path, tiers):
    recs = [(ts, sll2(udp("10.0.0.1", raw))) for ts, raw in beacon("B", "A", 60)]
    recs += [(ts + 50 * MS, sll2(udp("10.0.0.2", raw, 7014))) for ts, raw in beacon("D", "C", 40)]
    recs.sort(key=lambda r: r[0])
    st = agree(write_pcap(tmp_path / "sll2.pcap", recs, LINKTYPE_LINUX_SLL2), tiers)
    assert tiers["compiled"] == tiers["block"] == 0  # (the fast tiers read Ethernet records only)
    assert st.frames == 100 and set(st.pairs) == {"B>A", "D>C"} and st.sync_late > 0 and st.checksum_failures > 0


def udp6(payload: bytes, ident: int, fragmentable: bool):
    from scapy.all import UDP, IPv6, IPv6ExtHdrFragment  # noqa: PLC0415

    ip = IPv6(src="fd00::1", dst="fd00::9")
    if fragmentable:
        ip = ip / IPv6ExtHdrFragment(id=ident)
    return ip / UDP(sport=7013, dport=7013) / payload


@pytest.mark.parametrize("version", [4, 6])
def test_ip_fragments_reassembled_as_wireshark_does(tmp_path, tiers, version):
    """Four full sets are 3 kB IPv4 or IPv6 datagrams in 3 fragments, amid runs of the fast tiers: in order, in
    reverse order, once with its middle fragment lost (no frame on either side); the reassembled
    frame is counted."""
    from scapy.all import fragment, fragment6  # noqa: PLC0415

    recs: list[tuple[int, bytes]] = []
    big = lost = 0
    for i, (ts, raw) in enumerate(beacon("B", "A", 120, big=frozenset({20, 40, 60, 80}))):
        small = len(raw) < 1400
        pkt = udp("10.0.0.1", raw, ip_id=1000 + i) if version == 4 else udp6(raw, 1000 + i, not small)
        if small:
            recs.append((ts, ether(pkt)))
            continue
        frags = fragment(pkt, fragsize=1200) if version == 4 else fragment6(pkt, 1280)
        assert len(frags) == 3
        big += 1
        if big == 2:
            frags = frags[::-1]
        if big == 3:
            del frags[1]
            lost += 1
        recs += [(ts + k * MS, ether(f)) for k, f in enumerate(frags)]
    st = agree(write_pcap(tmp_path / "frag.pcap", recs), tiers)
    if version == 4:  # (the fast tiers read IPv4 records only)
        assert tiers["counts"] > 20 and tiers["compiled"] > 20 and tiers["block"] > 0, tiers
    assert big == 4 and lost == 1 and st.frames == 119
    assert st.variables[("B>A", "Mode")].count == 5  # 6 full sets, the lost one never seen


def test_time_stamps_out_of_order(tmp_path, tiers):
    """Records in file order whose times go back (a 5 s step back, swapped neighbours) and jump
    forward: counted in file order; a frame earlier than its direction's last full set is not late."""
    recs = list(beacon("B", "A", 120))
    recs[12], recs[13] = recs[13], recs[12]
    recs[40:] = [(ts - 5000 * MS, raw) for ts, raw in recs[40:]]
    recs[70:] = [(ts + 9000 * MS, raw) for ts, raw in recs[70:]]
    st = agree(write_pcap(tmp_path / "order.pcap", [(ts, ether(udp("10.0.0.1", raw))) for ts, raw in recs]), tiers)
    assert tiers["counts"] > 20 and tiers["compiled"] > 20 and tiers["block"] > 0, tiers
    assert st.frames == 120 and st.sync_late > 0


def test_pcapng_with_three_interfaces(tmp_path, tiers):
    """Ethernet, SLL2 and raw IPv4 interfaces in one pcapng; one direction's records alternate
    between the Ethernet and SLL2 interfaces (one conversation to Wireshark and to us)."""
    recs: list[tuple[int, int, bytes]] = []
    for i, (ts, raw) in enumerate(beacon("B", "A", 60)):
        pkt = udp("10.0.0.1", raw)
        recs.append((ts, i % 2, ether(pkt) if i % 2 == 0 else sll2(pkt)))
    recs += [(ts + 30 * MS, 2, bytes(udp("10.0.0.2", raw, 7020))) for ts, raw in beacon("D", "C", 50)]
    recs.sort(key=lambda r: r[0])
    path = tmp_path / "multi.pcapng"
    with open(path, "wb") as fh:
        w = PcapngWriter(fh, LINKTYPE_ETHERNET)
        fh.write(w.interface(LINKTYPE_LINUX_SLL2))
        fh.write(w.interface(LINKTYPE_IPV4))
        for ts, ifc, data in recs:
            fh.write(w.record(T0 + ts, data, interface=ifc))
    st = agree(path, tiers)
    assert tiers["compiled"] > 0 and tiers["counts"] == tiers["block"] == 0, tiers  # (pcapng: records one by one)
    assert st.frames == 110 and set(st.pairs) == {"B>A", "D>C"}


@pytest.mark.parametrize("args", [["compress"], ["expand"], ["export", "--format", "jsonl"],
                                  ["export", "--format", "mcap"], ["ingest"]])
def test_output_that_is_the_input_is_refused(tmp_path, args):
    """`-o` naming the capture read (here a pcapng with two interfaces): exit 2, one line, the
    capture untouched."""
    path = tmp_path / "in.pcapng"
    with open(path, "wb") as fh:
        w = PcapngWriter(fh, LINKTYPE_ETHERNET)
        fh.write(w.interface(LINKTYPE_LINUX_SLL2))
        for i, (ts, raw) in enumerate(beacon("B", "A", 30)):
            pkt = udp("10.0.0.1", raw)
            fh.write(w.record(T0 + ts, ether(pkt) if i % 2 else sll2(pkt), interface=i % 2))
    before = path.read_bytes()
    r = subprocess.run([sys.executable, "-m", "sharedlink", args[0], str(path), *args[1:], "-o", str(path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert path.read_bytes() == before
