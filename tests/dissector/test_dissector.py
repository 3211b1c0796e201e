"""Tests of dissector/sharedlink.lua driven through the real tshark (no mocks).

Most cases are batched into one capture and one tshark run (module fixtures) to keep
the file fast.  Every tshark run is checked by tests/tshark_util.py for Lua errors.
"""

from __future__ import annotations

import random
import resource
import shutil
import subprocess
from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.capture.packets import decode_packet
from sharedlink.capture.pcapio import read_records
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import named_values, parse_frame
from tshark_util import (
    DISSECTOR,
    INFO_FIELD,
    Pkt,
    checksum,
    fields,
    frame,
    json_packets,
    summary,
    verbose,
    write_pcap,
)

# its module fixtures' tshark runs (shared by every test here) made once: one pytest-xdist worker
# (make test: --dist loadgroup)
pytestmark = pytest.mark.xdist_group("dissector")

B009 = (
    b"[:AB|N0|T2|QAutoGpsLat|D38.34698779|T2|QAutoGpsLon|D-77.05734791|T2|QAutoGpsHead|D57"
    b"|T2|QAutoGpsVel|D0|CF8]\r\n"
)

VARS = ["AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel"]


def one(row: dict, name: str) -> str:
    vals = row[name]
    assert len(vals) == 1, (name, vals)
    return vals[0]


def _unpadded_frame() -> tuple[bytes, str]:
    """A frame whose checksum is < 0x10, written with one digit (as some peers do)."""
    for i in range(10000):
        body = f":AB|N0|D{i}|C"
        c = sum(body.encode()) % 256
        if c < 16:
            return f"[{body}{c:X}]\r\n".encode(), f"{c:X}"
    raise AssertionError("no such frame")


def _lowercase_frame() -> bytes:
    for i in range(10000):
        body = f":AB|N0||D{i}|Xfoo|C"
        c = "%02x" % (sum(body.encode()) % 256)
        if c != c.upper():
            return f"[{body}{c}]\r\n".encode()
    raise AssertionError("no such frame")


# ---------------------------------------------------------------------------
# One capture with one scenario per packet (frame number = index + 1)
# ---------------------------------------------------------------------------

def _mixed_packets() -> list[Pkt]:
    unpadded, _ = _unpadded_frame()
    pk: list[Pkt] = []

    def add(ts: float, payload: bytes, src: str, dst: str = "10.0.0.255", **kw) -> int:
        pk.append(Pkt(ts, payload, src=src, dst=dst, **kw))
        return len(pk)

    add(1.0, B009, "10.0.1.2")                                                            # 1
    add(2.0, frame("A", "B", "N0", "D40.12345678", "D-113.12345678", "D85.6", "D22.1"), "10.0.2.2")  # 2
    add(3.0, frame("B", "A", "QAutoGpsLat"), "10.0.3.1", "10.0.3.2")                      # 3 query A->B
    add(3.25, frame("A", "B", "RAutoGpsLat", "D40.12345678"), "10.0.3.2", "10.0.3.1")      # 4 reply B->A
    add(5.0, B009.replace(b"CF8]", b"C00]"), "10.0.5.2")                                  # 5 bad checksum
    add(6.0, frame("D", "C", "N0", "D1", "D2", "D3", "D4") + frame("D", "C", "N2", "D5", "D6"), "10.0.6.2")  # 6
    named = ("N0", "T2", "QLat", "D1.0", "T2", "QLon", "D2.0", "T0", "QCount", "D5", "T4", "QName", "Dabc")
    add(7.0, frame("F", "E", *named), "10.0.7.2")                                         # 7 named full
    add(7.5, frame("F", "E", "N0", "T2", "QLat", "D1.5"), "10.0.7.2")                      # 8 named delta
    add(9.0, frame("A", "B", "N0", "D10", "D20", "D30", "D40"), "10.0.9.2")                # 9 positional full
    add(9.5, frame("A", "B", "N0", "D11", "D", "D", "D41"), "10.0.9.2")                    # 10 positional delta
    add(11.0, frame("H", "G", "N0", "T2", "QX", "T0", "QY"), "10.0.11.2", "10.0.11.1")     # 11 declaration (N)
    add(11.2, frame("H", "G", "N0", "D1.5", "D7"), "10.0.11.2", "10.0.11.1")               # 12 uses X, Y
    add(11.4, frame("H", "G", "L0", "T2", "QU", "T2", "QV"), "10.0.11.2", "10.0.11.1")     # 13 declaration (L)
    add(11.6, frame("G", "H", "N0", "D8", "D9"), "10.0.11.1", "10.0.11.2")                 # 14 uses U, V
    add(15.0, _lowercase_frame(), "10.0.15.2")                                            # 15 empty/unknown/lower
    add(16.0, unpadded, "10.0.16.2")                                                      # 16 unpadded checksum
    add(17.0, b"xyz" + frame("A", "B", "P1") + b"\x00\x01" + frame("B", "A", "G1"), "10.0.17.2")  # 17 noise
    add(18.0, frame("A", "B", "ELink", "D0, outbound, on") + frame("A", "B", "MUI"), "10.0.18.2")  # 18 commands
    typed = ("N0", "T0", "QBig", "D9223372036854775807", "T0", "QNeg", "D-42", "T4", "QS", "Dhello world",
             "T2", "QBad", "Dxyz", "T1", "QOdd", "D5")
    add(19.0, frame("A", "B", *typed), "10.0.19.2")                                       # 19 typed values
    add(20.0, frame("Z", "B", "N0", "D1"), "10.0.20.2")                                   # 20 invalid address
    add(21.0, b"[:AB|N0|D1]\r\n", "10.0.21.2")                                            # 21 no checksum
    add(22.0, frame("A", "B", "N0", "D1", "D2", "D3", "D4", "D5"), "10.0.22.2")            # 22 past the list
    add(23.0, frame("A", "B", "N0", "D1", crlf=False), "10.0.23.2")                        # 23 no CR LF
    return pk


MIXED_FIELDS = [
    "frame.number", "sharedlink.src", "sharedlink.dst", "sharedlink.src.node", "sharedlink.dst.node",
    "sharedlink.kind", "sharedlink.ordinal", "sharedlink.type", "sharedlink.query", "sharedlink.response",
    "sharedlink.var.name", "sharedlink.var.index", "sharedlink.var.value", "sharedlink.var.double",
    "sharedlink.var.long", "sharedlink.var.string", "sharedlink.var.carried", "sharedlink.var.carried_from",
    "sharedlink.checksum", "sharedlink.checksum.text", "sharedlink.checksum.calculated",
    "sharedlink.checksum.status", "sharedlink.response_in", "sharedlink.response_to",
    "sharedlink.response_time", "sharedlink.command", "sharedlink.command.arg", "sharedlink.mode",
    "sharedlink.ping", "sharedlink.pong", "sharedlink.field.letter", "sharedlink.noise",
    "sharedlink.checksum.bad", "sharedlink.checksum.format", "sharedlink.checksum.missing",
    "sharedlink.address.invalid", "sharedlink.field.unknown", "sharedlink.field.empty", "sharedlink.malformed",
    "sharedlink.sync.late", "sharedlink.var.unknown", "sharedlink.var.badvalue", "sharedlink.crlf.missing",
    "sharedlink.noise.skipped", INFO_FIELD,
]


@pytest.fixture(scope="module")
def mixed_pcap(tmp_path_factory) -> Path:
    return write_pcap(tmp_path_factory.mktemp("mixed") / "mixed.pcap", _mixed_packets())


@pytest.fixture(scope="module")
def mixed(mixed_pcap) -> dict[int, dict[str, list[str]]]:
    rows = fields(mixed_pcap, MIXED_FIELDS)
    return {int(one(r, "frame.number")): r for r in rows}


def test_bul009_example(mixed):
    r = mixed[1]
    assert one(r, "sharedlink.dst") == "A" and one(r, "sharedlink.src") == "B"
    assert one(r, "sharedlink.dst.node") == "1" and one(r, "sharedlink.src.node") == "2"
    assert one(r, "sharedlink.kind") == "full"
    assert r["sharedlink.var.name"] == VARS
    assert r["sharedlink.var.value"] == ["38.34698779", "-77.05734791", "57", "0"]
    assert [float(x) for x in r["sharedlink.var.double"]] == [38.34698779, -77.05734791, 57.0, 0.0]
    assert r["sharedlink.type"] == ["2"] * 4
    assert one(r, "sharedlink.checksum") == "0xf8"
    assert one(r, "sharedlink.checksum.calculated") == "0xf8"
    assert one(r, "sharedlink.checksum.status") == "1"
    assert not r["sharedlink.checksum.bad"] and not r["sharedlink.checksum.format"]
    assert not r["sharedlink.crlf.missing"]
    info = one(r, INFO_FIELD)
    assert info.startswith("B\u2192A full AutoGpsLat=38.34698779 AutoGpsLon=-77.05734791")
    assert len(info) <= 125


def test_checksum_helper_matches_bul009():
    body = B009[1:B009.index(b"F8]")].decode()
    assert checksum(body) == "F8"


def test_bul049_positional(mixed):
    r = mixed[2]
    assert one(r, "sharedlink.kind") == "full"
    assert r["sharedlink.var.name"] == VARS
    assert r["sharedlink.var.index"] == ["0", "1", "2", "3"]
    assert r["sharedlink.var.value"] == ["40.12345678", "-113.12345678", "85.6", "22.1"]
    assert one(r, "sharedlink.checksum.status") == "1"


def test_positional_list_preference(mixed_pcap):
    rows = fields(mixed_pcap, ["sharedlink.var.name"], prefs={"sharedlink.variables": "A1, A2,A3,A4"},
                  display_filter="frame.number == 2")
    assert rows[0]["sharedlink.var.name"] == ["A1", "A2", "A3", "A4"]


def test_query_reply_linked_both_ways(mixed):
    q, rp = mixed[3], mixed[4]
    assert one(q, "sharedlink.kind") == "query"
    assert one(q, "sharedlink.query") == "AutoGpsLat"
    assert one(q, "sharedlink.response_in") == "4"
    assert one(rp, "sharedlink.kind") == "reply"
    assert one(rp, "sharedlink.response") == "AutoGpsLat"
    assert one(rp, "sharedlink.var.value") == "40.12345678"
    assert one(rp, "sharedlink.response_to") == "3"
    assert float(one(rp, "sharedlink.response_time")) == pytest.approx(0.25, abs=1e-6)


def test_bad_checksum(mixed):
    r = mixed[5]
    assert one(r, "sharedlink.checksum.status") == "0"
    assert one(r, "sharedlink.checksum") == "0x00"
    assert one(r, "sharedlink.checksum.calculated") == "0xf8"
    assert len(r["sharedlink.checksum.bad"]) == 1


def test_checksum_validation_off(mixed_pcap):
    rows = fields(mixed_pcap, ["sharedlink.checksum.status", "sharedlink.checksum.bad"],
                  prefs={"sharedlink.validate_checksum": False}, display_filter="frame.number == 5")
    assert one(rows[0], "sharedlink.checksum.status") == "2"
    assert not rows[0]["sharedlink.checksum.bad"]


def test_two_frames_in_one_datagram(mixed):
    r = mixed[6]
    assert r["sharedlink.kind"] == ["full", "delta"]
    assert r["sharedlink.ordinal"] == ["0", "2"]
    assert r["sharedlink.var.name"] == VARS + ["AutoGpsHead", "AutoGpsVel"]
    assert r["sharedlink.var.index"] == ["0", "1", "2", "3", "2", "3"]
    assert r["sharedlink.checksum.status"] == ["1", "1"]
    assert " ; " in one(r, INFO_FIELD)


def test_named_compression_carried(mixed):
    assert one(mixed[7], "sharedlink.kind") == "full"
    r = mixed[8]
    assert one(r, "sharedlink.kind") == "delta"
    assert r["sharedlink.var.name"] == ["Lat", "Lon", "Count", "Name"]
    assert r["sharedlink.var.value"] == ["1.5", "2.0", "5", "abc"]
    assert r["sharedlink.var.carried"] == ["1", "1", "1"]
    assert r["sharedlink.var.carried_from"] == ["7", "7", "7"]
    assert "(+3 carried)" in one(r, INFO_FIELD)


def test_positional_compression_carried(mixed):
    assert one(mixed[9], "sharedlink.kind") == "full"
    r = mixed[10]
    assert one(r, "sharedlink.kind") == "delta"
    assert r["sharedlink.var.value"] == ["11", "20", "30", "41"]
    assert r["sharedlink.var.carried"] == ["1", "1"]
    assert r["sharedlink.var.carried_from"] == ["9", "9"]
    assert not r["sharedlink.field.empty"]


def test_declaration_learning(mixed):
    r = mixed[11]
    assert one(r, "sharedlink.kind") == "declaration"
    assert r["sharedlink.var.name"] == ["X", "Y"]
    assert r["sharedlink.type"] == ["2", "0"]
    r = mixed[12]
    assert one(r, "sharedlink.kind") == "full"
    assert r["sharedlink.var.name"] == ["X", "Y"]
    assert r["sharedlink.var.value"] == ["1.5", "7"]
    assert one(mixed[13], "sharedlink.kind") == "declaration"
    r = mixed[14]      # L declared G's inbound list: used from H to G
    assert r["sharedlink.var.name"] == ["U", "V"]
    assert one(r, "sharedlink.kind") == "full"


def test_unknown_letter_empty_field_lowercase_checksum(mixed):
    r = mixed[15]
    assert one(r, "sharedlink.field.letter") == "X"
    assert len(r["sharedlink.field.unknown"]) == 1
    assert len(r["sharedlink.field.empty"]) == 1
    assert len(r["sharedlink.checksum.format"]) == 1
    assert one(r, "sharedlink.checksum.status") == "1"
    assert not r["sharedlink.checksum.bad"]


def test_unpadded_checksum(mixed):
    r = mixed[16]
    assert one(r, "sharedlink.checksum.status") == "1"
    assert len(r["sharedlink.checksum.format"]) == 1


def test_noise_ping_pong(mixed):
    r = mixed[17]
    assert r["sharedlink.noise"] == ["78:79:7a", "00:01"] or r["sharedlink.noise"] == ["78797a", "0001"]
    assert len(r["sharedlink.noise.skipped"]) == 2
    assert r["sharedlink.kind"] == ["ping", "pong"]
    assert one(r, "sharedlink.ping") == "1" and one(r, "sharedlink.pong") == "1"


def test_commands(mixed):
    r = mixed[18]
    assert r["sharedlink.kind"] == ["command", "command"]
    assert one(r, "sharedlink.command") == "Link"
    assert one(r, "sharedlink.command.arg") == "0, outbound, on"
    assert one(r, "sharedlink.mode") == "UI"
    assert "Link 0, outbound, on" in one(r, INFO_FIELD)


def test_typed_values(mixed):
    r = mixed[19]
    assert r["sharedlink.var.long"] == ["9223372036854775807", "-42"]
    assert one(r, "sharedlink.var.string") == "hello world"
    assert len(r["sharedlink.var.badvalue"]) == 1          # Dxyz is not a double
    assert r["sharedlink.type"] == ["0", "0", "4", "2", "1"]
    assert r["sharedlink.var.value"][-1] == "5"


def test_invalid_address(mixed):
    r = mixed[20]
    assert one(r, "sharedlink.dst") == "Z"
    assert len(r["sharedlink.address.invalid"]) == 1
    assert not r["sharedlink.dst.node"]


def test_missing_checksum(mixed):
    r = mixed[21]
    assert one(r, "sharedlink.checksum.status") == "2"
    assert len(r["sharedlink.checksum.missing"]) == 1
    assert not r["sharedlink.malformed"]


def test_positional_past_list(mixed):
    """The a-priori list (the default's 4 names) names only a frame of 4 slots: a 5-slot frame
    is #0..#4, untyped, with no warning (issue 29)."""
    r = mixed[22]
    assert not r["sharedlink.var.unknown"]
    assert r["sharedlink.var.index"] == ["0", "1", "2", "3", "4"]
    assert r["sharedlink.var.name"] == ["#0", "#1", "#2", "#3", "#4"]


def test_positional_past_a_declared_list_is_unknown(tmp_path):
    """Past a list learnt from a declaration a slot is #i with sharedlink.var.unknown."""
    pk = [Pkt(1.0, frame("A", "B", "N0", "T2", "QX", "T0", "QY")), Pkt(1.2, frame("A", "B", "N0", "D1", "D2", "D3"))]
    rows = fields(write_pcap(tmp_path / "decl.pcap", pk), ["sharedlink.var.name", "sharedlink.var.unknown"])
    assert rows[1]["sharedlink.var.name"] == ["X", "Y", "#2"]
    assert len(rows[1]["sharedlink.var.unknown"]) == 1


def test_no_crlf(mixed):
    """A UDP datagram is one frame: no CR LF is needed and none is noted (issue 29; BUL-110's
    own session has none). Over TCP, test_no_crlf_over_tcp."""
    r = mixed[23]
    assert not r["sharedlink.crlf.missing"]
    assert one(r, "sharedlink.checksum.status") == "1"


def test_no_crlf_over_tcp(tmp_path):
    """Over TCP CR LF frames the bytes: a frame followed by anything else is noted."""
    pk = [Pkt(1.0, frame("A", "B", "N0", "D1", crlf=False) + frame("A", "B", "N0", "D2"), 40000, 7013, "tcp"),
          Pkt(1.2, frame("A", "B", "N0", "D3"), 40000, 7013, "tcp")]
    rows = fields(write_pcap(tmp_path / "tcp.pcap", pk), ["sharedlink.crlf.missing", "sharedlink.kind"])
    assert [len(r["sharedlink.crlf.missing"]) for r in rows] == [1, 0], rows


def test_json_and_verbose_render(mixed_pcap):
    pkts = json_packets(mixed_pcap)
    assert len(pkts) == len(_mixed_packets())
    text = verbose(mixed_pcap)
    assert "SharedLink Protocol, B\u2192A full" in text
    assert "carried from frame 7" in text


def test_info_same_with_and_without_tree(mixed_pcap, tmp_path):
    """The no-tree fast path (summary) must give the Info text of the tree path."""
    pk = _mixed_packets() + [Pkt(30 + i * 0.2, B009, src="10.0.1.2") for i in range(5)]
    pk += [Pkt(40 + i * 0.2, frame("A", "B", "N0", f"D{i}", "D", "D%d" % (i * 3), "D"), src="10.0.9.9")
           for i in range(8)]
    pk += [Pkt(50 + i * 0.2, frame("A", "B", "N0", "T2", "QLat", f"D{i}", "T0", "QN", "D5"), src="10.0.9.8")
           for i in range(4)]
    pk += [Pkt(51 + i * 0.2, frame("A", "B", "N0", "T2", "QLat", f"D{i}"), src="10.0.9.8") for i in range(8)]
    pcap = write_pcap(tmp_path / "info.pcap", pk)
    lines = summary(pcap, extra=["-T", "fields", "-e", INFO_FIELD])   # fields: tree built
    plain = summary(pcap, extra=["-o", "gui.column.format:\"Info\",\"%i\""])  # no tree
    assert [x.strip() for x in plain] == [x.strip() for x in lines]
    plain2 = summary(pcap, two_pass=True, extra=["-o", "gui.column.format:\"Info\",\"%i\""])
    assert [x.strip() for x in plain2] == [x.strip() for x in lines]


# ---------------------------------------------------------------------------
# Sync interval
# ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def sync_pcap(tmp_path_factory) -> Path:
    pk = [Pkt(0.0, frame("A", "B", "N0", "D1", "D2", "D3", "D4"))]
    t = 0.2
    while t <= 3.01:
        pk.append(Pkt(t, frame("A", "B", "N0", "D1", "D", "D", "D4")))
        t = round(t + 0.2, 3)
    pk.append(Pkt(3.2, frame("A", "B", "N0", "D1", "D2", "D3", "D4")))
    pk.append(Pkt(3.4, frame("A", "B", "N0", "D", "D2", "D", "D4")))
    return write_pcap(tmp_path_factory.mktemp("sync") / "sync.pcap", pk)


def test_sync_late(sync_pcap):
    rows = fields(sync_pcap, ["frame.time_relative", "sharedlink.kind", "sharedlink.sync.late"])
    late = {round(float(one(r, "frame.time_relative")), 1) for r in rows if r["sharedlink.sync.late"]}
    assert late == {round(1.6 + 0.2 * i, 1) for i in range(8)}        # 1.6 .. 3.0
    assert rows[-2]["sharedlink.kind"] == ["full"]
    assert rows[-1]["sharedlink.kind"] == ["delta"] and not rows[-1]["sharedlink.sync.late"]


def test_sync_interval_preference(sync_pcap):
    rows = fields(sync_pcap, ["sharedlink.sync.late"], prefs={"sharedlink.sync_interval_ms": 5000})
    assert not any(r["sharedlink.sync.late"] for r in rows)


def test_sync_interval_old_name_still_works_with_a_deprecation_note(sync_pcap):
    """Issue 41: the preference is named with its unit (sync_interval_ms); the old name works for one
    release, noted as deprecated on stderr, and the new name wins when both are given."""
    res = tu.tshark(sync_pcap, ["-o", "sharedlink.sync_interval:5000", "-T", "fields", "-e", "sharedlink.sync.late"])
    assert not any(line.strip() for line in res.stdout.splitlines())
    assert "sharedlink.sync_interval is deprecated: use sharedlink.sync_interval_ms" in res.stderr
    both = tu.tshark(sync_pcap, ["-o", "sharedlink.sync_interval_ms:2000", "-o", "sharedlink.sync_interval:5000",
                                 "-T", "fields", "-e", "frame.number", "-e", "sharedlink.sync.late"]).stdout
    new = tu.tshark(sync_pcap, ["-o", "sharedlink.sync_interval_ms:2000",
                                "-T", "fields", "-e", "frame.number", "-e", "sharedlink.sync.late"]).stdout
    assert both == new and any(line.split("\t")[1].strip() for line in new.splitlines())   # 2 s: some late
    res = tu.tshark(sync_pcap, ["-o", "sharedlink.sync_interval_ms:5000", "-T", "fields", "-e", "sharedlink.sync.late"])
    assert "deprecated" not in res.stderr


def test_state_stable_across_passes(sync_pcap):
    """First-pass state is stored per frame: one-pass and two-pass outputs agree."""
    names = ["sharedlink.kind", "sharedlink.sync.late", "sharedlink.var.value", "sharedlink.var.carried_from",
             INFO_FIELD]
    assert fields(sync_pcap, names, two_pass=False) == fields(sync_pcap, names, two_pass=True)


def _carried_from_oracle(pcap: Path) -> list[list[str]]:
    """For each frame of a named stream: the frame each variable left out of it was last
    given in, in the order the variables were first seen (computed from the payloads with
    the Python codec, not from the dissector)."""
    last: dict[str, int] = {}
    out = []
    for number, rec in enumerate(read_records(pcap), 1):
        f = parse_frame(decode_packet(rec.linktype, rec.data).payload)
        given = {v.name for v in named_values(f.fields)}
        assert all(v.text != "" for v in named_values(f.fields))  # no empty D: all carried are left out
        out.append([str(last[name]) for name in last if name not in given])
        for v in named_values(f.fields):
            last[v.name] = number
    return out


@pytest.mark.parametrize("compress", [False, True], ids=["named", "compressed-named"])
def test_named_streams_agree_across_passes(tmp_path, compress):
    """One pass with a tree (-T fields) never takes the named fast path; the no-tree first
    pass of -2 takes it for every frame laid out like the last full frame. Both must give
    the same fields, and the carried values must name the frame they were last sent in."""
    pcap = tmp_path / "named.pcap"
    generate_file(GenOptions(duration=40, seed=11, compress=compress, sync_interval=1), pcap)
    names = ["sharedlink.kind", "sharedlink.var.name", "sharedlink.var.value", "sharedlink.var.carried",
             "sharedlink.var.carried_from", "sharedlink.sync.late", INFO_FIELD]
    one_pass = fields(pcap, names, two_pass=False)
    two_pass = fields(pcap, names, two_pass=True)
    assert len(one_pass) == 200
    assert one_pass == two_pass
    expected = _carried_from_oracle(pcap)
    assert [r["sharedlink.var.carried_from"] for r in two_pass] == expected
    kinds = [one(r, "sharedlink.kind") for r in two_pass]
    if compress:
        # full frames every second (five frames), deltas between them carrying the rest
        assert kinds.count("full") == 40 and kinds.count("delta") == 160
        assert len({x for row in expected for x in row}) >= 40  # carried from many frames, not only the first
    else:
        assert kinds == ["full"] * 200 and not any(expected)


def test_named_frame_with_nothing_changed(tmp_path):
    """A compressed named stream may send just N0: everything is carried."""
    pk = [Pkt(1.0, B009), Pkt(1.2, frame("A", "B", "N0")), Pkt(1.4, frame("A", "B", "N0", "T2", "QAutoGpsVel", "D3"))]
    pcap = write_pcap(tmp_path / "nothing.pcap", pk)
    rows = fields(pcap, ["sharedlink.kind", "sharedlink.var.name", "sharedlink.var.carried_from"])
    assert [r["sharedlink.kind"] for r in rows] == [["full"], ["delta"], ["delta"]]
    assert rows[1]["sharedlink.var.name"] == VARS
    assert rows[1]["sharedlink.var.carried_from"] == ["1"] * 4
    assert rows[2]["sharedlink.var.carried_from"] == ["1"] * 3


def test_many_carried_records_across_passes(tmp_path):
    """Hundreds of delta frames (packed records on the first pass) read back on the second."""
    pk = []
    for i in range(700):
        if i % 50 == 0:
            pk.append(Pkt(i * 0.02, frame("A", "B", "N0", f"D{i}", f"D{i + 1}", f"D{i + 2}", f"D{i + 3}")))
        else:
            pk.append(Pkt(i * 0.02, frame("A", "B", "N0", f"D{i}", "D", "D", f"D{i + 3}") +
                          frame("B", "A", "N0", "D", f"D{i}")))
    pcap = write_pcap(tmp_path / "many.pcap", pk)
    names = ["sharedlink.var.value", "sharedlink.var.carried_from"]
    one_pass = fields(pcap, names, two_pass=False)
    assert one_pass == fields(pcap, names, two_pass=True)
    r = one_pass[123]          # frame 124, last full frame 101
    assert r["sharedlink.var.carried_from"] == ["101", "101"]      # the A->B slot 0 never had a value
    # B->A slot 0 never had a value: carried with no value (issue 12 decoding rules)
    assert r["sharedlink.var.value"] == ["123", "101", "102", "126", "123"]


# ---------------------------------------------------------------------------
# TCP and heuristics
# ---------------------------------------------------------------------------

def test_tcp_reassembly(tmp_path):
    f2 = frame("A", "B", "N0", "D40.1", "D-113.1", "D85.6", "D22.1")
    f3 = frame("A", "B", "P7")
    tcp = dict(proto="tcp", sport=40000, dport=7013, src="10.0.30.2", dst="10.0.30.1")
    heur = dict(proto="tcp", sport=40001, dport=5555, src="10.0.31.2", dst="10.0.31.1")
    pk = [
        Pkt(1.0, B009[:30], **tcp),                 # 1: start of a frame
        Pkt(1.1, B009[30:], **tcp),                 # 2: rest -> frame complete
        Pkt(1.2, f2 + B009 + f3[:10], **tcp),       # 3: two frames + a partial one
        Pkt(1.3, f3[10:] + b"[", **tcp),            # 4: end of the partial one + '['
        Pkt(1.4, f2[1:-2], **tcp),                  # 5: rest of a frame without CR LF
        Pkt(1.5, b"\r\n", **tcp),                   # 6: the CR LF
        Pkt(2.0, B009[:40], **heur),                # 7: heuristic, other port, split
        Pkt(2.1, B009[40:], **heur),                # 8
    ]
    pcap = write_pcap(tmp_path / "tcp.pcap", pk)
    rows = {int(one(r, "frame.number")): r for r in fields(
        pcap, ["frame.number", "sharedlink.kind", "sharedlink.checksum.status", "sharedlink.var.value",
               "sharedlink.malformed", "sharedlink.noise"])}
    assert not rows[1]["sharedlink.kind"]
    assert rows[2]["sharedlink.kind"] == ["full"]
    assert rows[2]["sharedlink.var.value"] == ["38.34698779", "-77.05734791", "57", "0"]
    assert rows[3]["sharedlink.kind"] == ["full", "full"]
    assert rows[4]["sharedlink.kind"] == ["ping"]
    assert rows[5]["sharedlink.kind"] == ["full"]
    assert rows[5]["sharedlink.checksum.status"] == ["1"]
    assert rows[8]["sharedlink.kind"] == ["full"]
    for r in rows.values():
        assert not r["sharedlink.malformed"] and not r["sharedlink.noise"]


@pytest.fixture(scope="module")
def heur_pcap(tmp_path_factory) -> Path:
    rnd = random.Random(7)
    binary = bytes(rnd.randrange(256) for _ in range(300)) + b"]\r\n"
    pk = [
        Pkt(1.0, B009, sport=5000, dport=6000),                                   # 1 claimed
        Pkt(1.1, binary, sport=5001, dport=6001),                                  # 2 binary
        Pkt(1.2, b"[:AB|N0|D\x00\x01|CF8]\r\n", sport=5002, dport=6002),           # 3 not printable
        Pkt(1.3, b"[:ZZ|N0|D1|CF8]\r\n", sport=5003, dport=6003),                  # 4 not A-P
        Pkt(1.4, b"[:AB|N0|D1|CF8]x", sport=5004, dport=6004),                     # 5 bad ending
        Pkt(1.5, b"hello, not a frame", sport=5000, dport=6000),                   # 6 same conversation as 1
        Pkt(1.6, b"[:ABx" + bytes(range(200)), sport=5005, dport=6005),           # 7 binary after header
    ]
    return write_pcap(tmp_path_factory.mktemp("heur") / "heur.pcap", pk)


def _claimed(pcap: Path, **kw) -> list[bool]:
    rows = fields(pcap, ["frame.protocols"], **kw)
    return ["sharedlink" in one(r, "frame.protocols").split(":") for r in rows]


def test_heuristic_udp(heur_pcap):
    assert _claimed(heur_pcap) == [True, False, False, False, False, True, False]


def test_heuristic_disabled_by_pref(heur_pcap):
    assert _claimed(heur_pcap, prefs={"sharedlink.heuristic": False}) == [False] * 7


def test_heuristic_disabled_in_enabled_protocols(heur_pcap):
    assert _claimed(heur_pcap, extra=["--disable-heuristic", "sharedlink_udp"]) == [False] * 7


def test_port_preference(tmp_path):
    pcap = write_pcap(tmp_path / "ports.pcap", [Pkt(1.0, B009, sport=4000, dport=4000)])
    assert _claimed(pcap, prefs={"sharedlink.heuristic": False}) == [False]
    assert _claimed(pcap, prefs={"sharedlink.heuristic": False, "sharedlink.ports": "4000,7013"}) == [True]


# ---------------------------------------------------------------------------
# Damage: truncation, mutation, hostile payloads
# ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def damaged_pcap(tmp_path_factory) -> tuple[Path, int]:
    rnd = random.Random(2024)
    pk = [Pkt(1.0 + i * 0.01, B009[:i]) for i in range(1, len(B009) + 1)]
    ntrunc = len(pk)
    alphabet = b"[]|:\r\nCDNQTRLEMPG0123456789AF\x00\xff"
    for i in range(400):
        b = bytearray(B009 if i % 2 else frame("A", "B", "N0", "D1", "D", "D3"))
        for _ in range(rnd.randint(1, 6)):
            op = rnd.randrange(3)
            pos = rnd.randrange(len(b))
            if op == 0:
                b[pos] = rnd.choice(alphabet)
            elif op == 1:
                del b[pos]
            else:
                b.insert(pos, rnd.choice(alphabet))
        pk.append(Pkt(10.0 + i * 0.01, bytes(b) or b"["))
    return write_pcap(tmp_path_factory.mktemp("damage") / "damage.pcap", pk), ntrunc


def test_truncation_every_byte(damaged_pcap):
    pcap, ntrunc = damaged_pcap
    rows = fields(pcap, ["sharedlink.kind", "sharedlink.malformed", "sharedlink.checksum.status",
                         "sharedlink.crlf.missing", "sharedlink.noise"])
    close = B009.index(b"]")
    for i, r in enumerate(rows[:ntrunc], start=1):      # payload = B009[:i]
        if i < 2:
            assert r["sharedlink.noise"]                    # just '['
        elif i <= close:
            assert r["sharedlink.kind"] == ["malformed"], i
            assert len(r["sharedlink.malformed"]) == 1
        else:
            assert r["sharedlink.kind"] == ["full"], i
            assert r["sharedlink.checksum.status"] == ["1"]
            assert not r["sharedlink.crlf.missing"]  # a UDP datagram: no CR LF needed (issue 29)


def test_mutations_never_break_lua(damaged_pcap):
    pcap, _ = damaged_pcap
    # tree pass (fields), verbose pass and no-tree pass: all checked for Lua errors
    rows = fields(pcap, ["sharedlink.kind", "_ws.expert"])
    assert all(r["sharedlink.kind"] or r["_ws.expert"] for r in rows)
    verbose(pcap)
    assert len(summary(pcap)) == len(rows)


def _mutate(rnd: random.Random, data: bytes) -> bytes:
    b = bytearray(data)
    alphabet = b"[]|:\r\nCDNQTRLEMPG0123456789AF\x00\xff"
    for _ in range(rnd.randint(1, 4)):
        pos = rnd.randrange(len(b))
        op = rnd.randrange(3)
        if op == 0:
            b[pos] = rnd.choice(alphabet)
        elif op == 1:
            del b[pos]
        else:
            b.insert(pos, rnd.choice(alphabet))
    return bytes(b)


def test_tcp_stream_with_damage(tmp_path):
    """A TCP byte stream of good and damaged frames cut at random points."""
    rnd = random.Random(99)
    stream = bytearray()
    intact = 0
    for i in range(300):
        good = frame("A", "B", "N0", f"D{i}", "D2.5", "D", "D-4") if i % 3 else B009
        if rnd.random() < 0.3:
            stream += _mutate(rnd, good)
        else:
            stream += good
            intact += 1
    stream += B009                      # a clean last frame so nothing is left pending
    intact += 1
    pk, pos, t = [], 0, 1.0
    while pos < len(stream):
        n = rnd.choice([1, 2, 5, 17, 40, 90, 200, 400])
        pk.append(Pkt(t, bytes(stream[pos:pos + n]), proto="tcp", sport=41000, dport=7013,
                      src="10.0.40.2", dst="10.0.40.1"))
        pos += n
        t += 0.001
    pcap = write_pcap(tmp_path / "tcpdamage.pcap", pk)
    rows = fields(pcap, ["sharedlink.kind", "sharedlink.checksum.status"])
    good = sum(r["sharedlink.checksum.status"].count("1") for r in rows)
    assert good >= intact, (good, intact)
    assert len(summary(pcap)) == len(pk)


def test_random_garbage_payloads(tmp_path):
    rnd = random.Random(5)
    alphabet = b"[]|:\r\nABCDNQTRLPG0123456789 \x00\x7f\xfe"
    pk = [Pkt(1.0 + i * 0.01, bytes(rnd.choice(alphabet) for _ in range(rnd.randrange(1, 300))))
          for i in range(300)]
    pcap = write_pcap(tmp_path / "garbage.pcap", pk)
    rows = fields(pcap, ["frame.protocols"])
    assert all("sharedlink" in one(r, "frame.protocols") for r in rows)
    verbose(pcap)
    assert len(summary(pcap)) == len(pk)


def _hostile(n: int, seed: int = 1) -> bytes:
    rnd = random.Random(seed)
    return bytes(rnd.choice(b"[|:") for _ in range(n))


def _timed(pcap: Path, args: list[str]) -> float:
    """CPU time (user+sys) of one tshark run: robust on a busy machine."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary(pcap, extra=args, timeout=120)  # (a hang guard; the run's cost is its CPU time)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)


def test_hostile_payload_linear(tmp_path):
    big = write_pcap(tmp_path / "big.pcap", [Pkt(1.0, _hostile(65000))])
    small = write_pcap(tmp_path / "small.pcap", [Pkt(1.0, _hostile(32500))])
    none = write_pcap(tmp_path / "none.pcap", [Pkt(1.0, b"x")])
    for args in ([], ["-V"]):
        t_none = min(_timed(none, args) for _ in range(2))
        t_big = min(_timed(big, args) for _ in range(2)) - t_none
        t_small = min(_timed(small, args) for _ in range(2)) - t_none
        assert t_big < 20
        assert t_big < 4 * max(t_small, 0.2), (args, t_big, t_small)
    rows = fields(big, ["sharedlink.malformed", INFO_FIELD])
    assert rows[0]["sharedlink.malformed"]
    assert len(one(rows[0], INFO_FIELD)) < 200


# ---------------------------------------------------------------------------
# The Python helper module and static checks
# ---------------------------------------------------------------------------

def test_pyshark_module(mixed_pcap):
    import signal

    from sharedlink.wireshark import decode

    chld = signal.getsignal(signal.SIGCHLD)
    frames = list(decode(mixed_pcap))
    # decode leaves the process's signals as they were (pyshark left a SIGCHLD handler and a
    # wakeup fd nobody read: every later signal then reported BlockingIOError)
    fd = signal.set_wakeup_fd(-1)
    signal.set_wakeup_fd(fd)
    assert fd == -1 and signal.getsignal(signal.SIGCHLD) == chld
    assert len(list(decode(mixed_pcap))) == len(frames)   # and a second call works as the first
    by_num: dict[int, list] = {}
    for f in frames:
        by_num.setdefault(f.number, []).append(f)
    f1 = by_num[1][0]
    assert (f1.src, f1.dst, f1.kind, f1.checksum_status) == ("B", "A", "full", "Good")
    assert [(v.name, v.value) for v in f1.variables] == list(zip(VARS, ["38.34698779", "-77.05734791", "57", "0"]))
    assert f1.variables[0].double == pytest.approx(38.34698779)
    f8 = by_num[8][0]
    assert f8.kind == "delta"
    carried = [v for v in f8.variables if v.carried]
    assert [(v.name, v.carried_from) for v in carried] == [("Lon", 7), ("Count", 7), ("Name", 7)]
    assert [f.kind for f in by_num[6]] == ["full", "delta"]
    assert by_num[5][0].checksum_status == "Bad"
    assert by_num[4][0].response_to == 3


def test_luacheck_clean():
    if not shutil.which("luacheck"):
        pytest.skip("luacheck not installed")
    res = subprocess.run(["luacheck", "--no-color", str(DISSECTOR)], capture_output=True, text=True,
                         cwd=DISSECTOR.parents[1])
    assert res.returncode == 0, res.stdout


@pytest.mark.parametrize("luac", ["luac5.2", "luac5.4"])
def test_lua_syntax(luac):
    # Wireshark 4.0 runs Lua 5.2, 4.4 and later 5.4: every plugin compiles under both (`make
    # deps` installs both compilers from Debian's packages)
    if not shutil.which(luac):
        pytest.skip(f"{luac} not installed")
    plugins = sorted(DISSECTOR.parent.glob("*.lua"))
    assert DISSECTOR in plugins and len(plugins) >= 5
    # one file a call: Debian 12's luac5.4 (5.4.4) given several files aborts with a double free
    # for some paths (its code that joins them), whatever the files hold
    for plugin in plugins:
        res = subprocess.run([luac, "-p", str(plugin)], capture_output=True, text=True)
        assert res.returncode == 0, f"{plugin.name}: {res.stderr}"


def test_lua_portability_rules():
    src = DISSECTOR.read_text()
    code = "\n".join(line.split("--", 1)[0] for line in src.splitlines())
    for bad in ("bit32", "//", "math.pow", "loadstring", "setfenv"):
        assert bad not in code, bad
    import re

    assert not re.search(r"(?<![\w.])unpack\(", code)
    assert not re.search(r"[^&]&[^&]", code.replace("&&", ""))
