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
  decoder's (sl_checks.same_changes), `ingest` keeps as many frames and `export` (jsonl)
  as many of each kind.

What Wireshark does and we follow: fragments are reassembled (ip.defragment on by default), the
frame counted in the record that completes the datagram, in any order; a datagram missing a
fragment is no frame on either side. Time stamps are taken as they come: a frame whose time is
before its direction's last full frame is not late (the gap is negative), records are counted in
file order.
"""

from __future__ import annotations

import pytest
from sl_checks import MS, T0, agree, beacon, ether, sll2, udp, write_records
from sl_cli import run_cli

from sharedlink.capture.pcapio import (
    LINKTYPE_ETHERNET,
    LINKTYPE_IPV4,
    LINKTYPE_LINUX_SLL2,
    PcapngWriter,
)


def test_linux_cooked_v2(tmp_path, tiers):
    recs = [(ts, sll2(udp("10.0.0.1", raw))) for ts, raw in beacon("B", "A", 60)]
    recs += [(ts + 50 * MS, sll2(udp("10.0.0.2", raw, 7014))) for ts, raw in beacon("D", "C", 40)]
    recs.sort(key=lambda r: r[0])
    st = agree(write_records(tmp_path / "sll2.pcap", recs, LINKTYPE_LINUX_SLL2), tiers)
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
    st = agree(write_records(tmp_path / "frag.pcap", recs), tiers)
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
    st = agree(write_records(tmp_path / "order.pcap", [(ts, ether(udp("10.0.0.1", raw))) for ts, raw in recs]), tiers)
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
    r = run_cli(args[0], str(path), *args[1:], "-o", str(path), timeout=120)
    assert r.returncode == 2, r
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert path.read_bytes() == before
