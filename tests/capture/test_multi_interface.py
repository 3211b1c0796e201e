"""Multi-interface pcapng (issue 31: "compress/expand see 50 value frames where tshark sees 70").

Captures with several Interface Description Blocks (link types Ethernet, raw IP, Linux SLL and
SLL2, BSD loopback, IPv4; if_tsresol decimal and binary; if_tsoffset positive and negative; an
IDB after packets of another interface), Enhanced Packet Blocks interleaved across them, Simple
Packet Blocks, obsolete Packet Blocks and a second, big-endian section. tshark with the
dissector is the reference: the record times and the value frames per interface that
``stats``, ``compress``, ``expand`` and ``diff`` see must be those tshark sees, in the input
and in the outputs.
"""

from __future__ import annotations

import json
import struct
from collections import Counter
from pathlib import Path

from sl_cli import run_cli

import tshark_util as tu
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import read_records
from sharedlink.protocols.codec import encode_named, encode_positional

T = 1_700_000_000
VALUE_KINDS = ("full", "delta")


# -- blocks ------------------------------------------------------------------------------------


def _opt(code: int, val: bytes, e: str = "<") -> bytes:
    return struct.pack(e + "HH", code, len(val)) + val + b"\0" * ((-len(val)) & 3)


def _block(bt: int, body: bytes, e: str = "<") -> bytes:
    return struct.pack(e + "II", bt, 12 + len(body)) + body + struct.pack(e + "I", 12 + len(body))


def shb(e: str = "<") -> bytes:
    return _block(0x0A0D0D0A, struct.pack(e + "IHHq", 0x1A2B3C4D, 1, 0, -1), e)


def idb(linktype: int, resol: int | None = None, tsoffset: int | None = None, e: str = "<") -> bytes:
    o = b""
    if resol is not None:
        o += _opt(9, bytes([resol]), e)
    if tsoffset is not None:
        o += _opt(14, struct.pack(e + "q", tsoffset), e)
    if o:
        o += _opt(0, b"", e)
    return _block(1, struct.pack(e + "HHI", linktype, 0, 262144) + o, e)


def _pad(data: bytes) -> bytes:
    return data + b"\0" * ((-len(data)) & 3)


def epb(iface: int, ts: int, data: bytes, flags: int | None = None, e: str = "<") -> bytes:
    o = _opt(2, struct.pack(e + "I", flags), e) + _opt(0, b"", e) if flags is not None else b""
    return _block(6, struct.pack(e + "IIIII", iface, ts >> 32, ts & 0xFFFFFFFF, len(data), len(data)) + _pad(data) + o, e)


def pb(iface: int, ts: int, data: bytes) -> bytes:
    """The obsolete Packet Block (16-bit interface id and drops count)."""
    return _block(2, struct.pack("<HHIIII", iface, 0, ts >> 32, ts & 0xFFFFFFFF, len(data), len(data)) + _pad(data))


def spb(data: bytes) -> bytes:
    """A Simple Packet Block: interface 0, no time."""
    return _block(3, struct.pack("<I", len(data)) + _pad(data))


def sll(ip: bytes) -> bytes:
    return struct.pack(">HHH8sH", 0, 1, 6, b"\x02\0\0\0\0\x01\0\0", 0x0800) + ip


def sll2(ip: bytes) -> bytes:
    return struct.pack(">HHIHBB8s", 0x0800, 0, 1, 1, 0, 6, b"\x02\0\0\0\0\x01\0\0") + ip


# -- the captures --------------------------------------------------------------------------------


def build_mixed(path: Path, n: int = 21) -> Path:
    """Six interfaces of four link types and four time encodings, packets of every block type
    interleaved, one IDB declared after packets, one conversation seen on two interfaces, then
    a big-endian section."""
    b = [UdpBuilder(f"10.0.1.{k + 1}", "10.0.0.99", 7100 + k, 7013) for k in range(8)]

    def named(pair: str, i: int, extra: bool) -> bytes:
        values = [("Lat", 2, f"{i}.5")] + ([("Lon", 2, "1.25")] if extra else [])
        return encode_named(pair[0], pair[1], values)

    out = [shb(), idb(1)]  # 0: Ethernet, microseconds
    for i in range(5):
        out.append(epb(0, (T + i) * 10**6, b[0].frame(named("AB", i, i % 3 == 0), i + 1)))
        out.append(spb(b[1].frame(named("CD", i, True), i + 1)))
    out += [idb(101, 9, 1000),  # 1: raw IP, nanoseconds, +1000 s
            idb(1, 3),  # 2: Ethernet, milliseconds
            idb(113, 0x83, -5),  # 3: Linux SLL, 1/8 s, -5 s
            idb(276, 0x8A),  # 4: SLL2, 2^-10 s
            idb(0, 6)]  # 5: BSD loopback
    for i in range(5, n):
        out.append(epb(0, (T + i) * 10**6, b[0].frame(named("AB", i, i % 3 == 0), i + 1)))
        out.append(pb(1, (T + i - 1000) * 10**9 + 7, b[2].frame(named("EF", i, i % 4 == 0), i + 1)[14:]))
        out.append(epb(2, (T + i) * 1000, b[3].frame(encode_positional("G", "H", [f"{i}.5", "2"]), i + 1)))
        out.append(epb(2, (T + i) * 1000 + 1, b[0].frame(named("AB", i, False), i + 1)))  # AB again, on iface 2
        out.append(epb(3, (T + i + 5) * 8 + 1, sll(b[4].frame(named("IJ", i, i % 2 == 0), i + 1)[14:]), flags=1))
        out.append(epb(4, (T + i) * 1024 + 3, sll2(b[5].frame(named("KL", i, True), i + 1)[14:])))
        out.append(epb(5, (T + i) * 10**6 + 9, struct.pack("<I", 2) + b[6].frame(named("MN", i, i % 5 == 0), i + 1)[14:]))
        if i % 4 == 0:
            out.append(spb(b[1].frame(named("CD", i, False), i + 1)))
    out += [shb(">"), idb(228, 6, None, ">")]  # a big-endian section: raw IPv4, microseconds
    for i in range(n):
        out.append(epb(0, (T + 100 + i) * 10**6, b[7].frame(named("OP", i, i % 3 == 0), i + 1)[14:], e=">"))
    path.write_bytes(b"".join(out))
    return path


def build_with_serial(path: Path, n: int = 25) -> Path:
    """Ethernet plus a serial interface (USER0): stats and tshark count the serial value frames;
    compress and expand copy them unchanged."""
    b = UdpBuilder("10.0.1.1", "10.0.0.99", 7100, 7013)
    out = [shb(), idb(1), idb(147, 9)]
    for i in range(n):
        out.append(epb(0, (T + i) * 10**6, b.frame(encode_named("A", "B", [("Lat", 2, f"{i}.5")]), i + 1)))
        f = encode_named("C", "D", [("Lat", 2, f"{i}.5"), ("Lon", 2, "2.5")])
        out.append(epb(1, (T + i) * 10**9 + 5, f[:7], flags=1))
        out.append(epb(1, (T + i) * 10**9 + 6, f[7:], flags=1))
    path.write_bytes(b"".join(out))
    return path


# -- what each side sees -------------------------------------------------------------------------


def tshark_view(path: Path) -> tuple[list[int], Counter]:
    """(record times in ns, value frames per interface) as tshark with the dissectors sees them."""
    rows = tu.fields(path, ["frame.time_epoch", "frame.interface_id", "sharedlink.kind"], two_pass=False,
                     script=tu.DISSECTOR, extra=["-X", f"lua_script:{tu.REPO / 'dissector' / 'serial.lua'}"])
    times, per_iface = [], Counter()
    for r in rows:
        sec, _, frac = (r["frame.time_epoch"] or ["0"])[0].partition(".")  # an SPB has no time
        times.append(int(sec) * 10**9 + int((frac + "000000000")[:9]))
        per_iface[int(r["frame.interface_id"][0]) if r["frame.interface_id"] else -1] += sum(
            k in VALUE_KINDS for k in r["sharedlink.kind"])
    return times, +per_iface


def value_frames_stats(path: Path) -> int:
    r = run_cli("stats", path, "--json")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    kinds = json.loads(r.stdout)["kinds"]
    return sum(kinds.get(k, 0) for k in VALUE_KINDS)


def transform(mode: str, src: Path, dst: Path) -> dict:
    r = run_cli(mode, src, "-o", dst, "--json", "--force")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    return json.loads(r.stdout)


# -- tests ---------------------------------------------------------------------------------------


def test_record_times_of_every_interface_are_tsharks(tmp_path):
    """if_tsresol (decimal and binary), if_tsoffset (+ and -), SPBs (no time) and a big-endian
    section: every record's time as Wireshark computes it (SPBs: tshark shows none, we say 0)."""
    cap = build_mixed(tmp_path / "mixed.pcapng")
    times, _ = tshark_view(cap)
    ours = [r.ts_ns for r in read_records(cap)]
    assert len(ours) == len(times)
    # tshark prints times to the nanosecond; a 2^-n resolution is rounded there, truncated here
    assert all(abs(a - b) <= 1 for a, b in zip(ours, times) if b), list(zip(ours, times))[:5]


def test_value_frames_of_a_multi_interface_capture_are_tsharks_in_every_command(tmp_path):
    cap = build_mixed(tmp_path / "mixed.pcapng")
    _, want = tshark_view(cap)
    total = sum(want.values())
    assert len(want) == 6 and total == 147  # every interface (the big-endian section's too) carries values
    assert value_frames_stats(cap) == total
    comp, exp = tmp_path / "c.pcapng", tmp_path / "e.pcapng"
    rc = transform("compress", cap, comp)
    assert rc["value_frames"] == total and rc["records"] == len(list(read_records(cap)))
    re_ = transform("expand", comp, exp)
    assert re_["value_frames"] == total
    for out in (comp, exp):
        got = tshark_view(out)[1]
        # the same value frames on the same interfaces (the outputs are one section: the
        # second section's interface 0 is numbered after the first section's six)
        assert got[0] + got[6] == want[0] and {k: v for k, v in got.items() if k not in (0, 6)} == {
            k: v for k, v in want.items() if k != 0}, (out.name, got)
        assert value_frames_stats(out) == total
        d = run_cli("diff", cap, out)
        assert d.returncode == 0 and "AGREE" in d.stdout, d.stdout[-2000:] + d.stderr
        assert f"{total} matched value-frame pairs" in d.stdout


def test_compress_counts_the_serial_value_frames_it_copies(tmp_path):
    """compress/expand copy serial records as they are; the serial frames in them are followed by
    both views and counted, as stats and tshark count them (they were left out: 25 of 50)."""
    cap = build_with_serial(tmp_path / "serial-and-udp.pcapng")
    _, want = tshark_view(cap)
    assert want == {0: 25, 1: 25}
    assert value_frames_stats(cap) == 50
    rc = transform("compress", cap, tmp_path / "c.pcapng")
    assert tshark_view(tmp_path / "c.pcapng")[1] == want
    assert rc["value_frames"] == 50


def test_a_simple_packet_block_cut_at_the_snaplen_holds_no_padding(tmp_path):
    """An SPB stores only the original length: its data is that length cut at interface 0's
    SnapLen, as Wireshark reads it (the block's padding bytes were taken for packet data)."""
    frame = UdpBuilder("10.0.0.1", "10.0.0.2", 7013, 7013).frame(encode_named("A", "B", [("Lat", 2, "1.5")]), 1)
    cut = 62  # not a multiple of 4: two padding bytes follow
    body = struct.pack("<I", len(frame)) + frame[:cut] + b"\0\0"
    cap = tmp_path / "spb.pcapng"
    cap.write_bytes(shb() + _block(1, struct.pack("<HHI", 1, 0, cut)) + _block(3, body) + _block(3, body))
    recs = list(read_records(cap))
    assert [len(r.data) for r in recs] == [cut, cut] and all(r.orig_len == len(frame) for r in recs)
    assert recs[0].data == frame[:cut]
    rows = tu.fields(cap, ["frame.cap_len", "frame.len"], two_pass=False)
    assert [(int(r["frame.cap_len"][0]), int(r["frame.len"][0])) for r in rows] == [(cut, len(frame))] * 2
