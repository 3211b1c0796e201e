"""A malformed frame counted by every command that decodes, as the dissector and its tap count it
(issue 28; docs/fields-sharedlink.md, "Counts").

The decoding core gives each ``[:`` of UDP/TCP bytes that hold no well-formed frame as a frame of
kind ``malformed`` (its header's pair, ``?`` for a missing letter; a wrong checksum a failure), so
``ingest`` (a frame row), ``export`` (a csv/jsonl row, an MCAP frames message without a values
message) and ``diff`` (its frame count) count what ``tshark -z sharedlink,stats`` counts. The
expected counts come from the tap (sharedlink.lua in real tshark), not from our code.
"""

from __future__ import annotations

import csv
import io
import json
from collections import Counter
from pathlib import Path

import pytest
from sl_checks import tap_stats

from sharedlink.analysis.decode import Decoded, Decoder
from sharedlink.analysis.diff import DiffOptions, diff_captures
from sharedlink.analysis.export import ExportOptions, export, export_file
from sharedlink.analysis.stats import capture_stats, one_line
from sharedlink.fleet.ingest import ingest
from sharedlink.fleet.query import connect
from tshark_util import Pkt, frame, write_pcap

GOOD = frame("A", "B", "N0", "D1")
MS_ = 1_000_000


def malformed_capture(tmp_path: Path, transport: str) -> Path:
    """Good frames among malformed ones (unterminated, short headers, no letters, bad and good
    checksums on malformed frames) and noise, in datagrams (UDP) or one TCP stream."""
    payloads = [
        b"[:AB|N0|D1" + GOOD,  # unterminated: the next '[:' ends it
        b"junk\r\n" + b"[:C]\r\n" + GOOD,  # noise, then a header too short (no source letter: ?>C)
        b"[:]" + GOOD + b"NO CARRIER\r\n",  # no letters at all (?>?); noise after the frame
        b"[:CDx|N0|D2|C00]\r\n" + GOOD,  # no '|' after the letters; its checksum is checked (bad)
        b"[:AB|N0|D1|C5A\r\n" + GOOD,  # unterminated, its last field a checksum ("5A\r\n": bad)
        b"[:AB|N0|D1|C" + frame("A", "B", "N0", "D", crlf=False),  # an empty checksum text: bad
        GOOD + GOOD,
        GOOD + b"[:DC|N0|D3",  # unterminated at the end of the payload
    ]
    if transport == "tcp":  # (an unterminated tail waits for the next segment: a frame closes it)
        payloads.append(b"|C00]\r\n")
    pkts = [Pkt(0.1 * i, p, 4000, 4000, transport, "10.0.0.2", "10.0.0.1") for i, p in enumerate(payloads)]
    return write_pcap(tmp_path / f"malformed-{transport}.pcap", pkts)


def by_pair(rows) -> dict[str, tuple[int, int, dict[str, int]]]:
    """``(pair, kind, checksum verdict)`` rows as the tap's pairs: frames, bad checksums, kinds."""
    out: dict[str, list] = {}
    for pair, kind, checksum in rows:
        p = out.setdefault(pair, [0, 0, Counter()])
        p[0] += 1
        p[1] += checksum in ("bad", False)
        p[2][kind] += 1
    return {k: (n, bad, dict(kinds)) for k, (n, bad, kinds) in out.items()}


@pytest.fixture(scope="module", params=["udp", "tcp"])
def capture(request, tmp_path_factory) -> tuple[Path, dict, dict]:
    """(the capture, the tap's report, its pairs as (frames, checksum failures, kinds))."""
    path = malformed_capture(tmp_path_factory.mktemp("malformed"), request.param)
    tap = tap_stats(path)
    assert tap["kinds"].get("malformed", 0) >= 6 and tap["Checksum failures"] >= 3, tap
    assert "?>C" in tap["pairs"] and "?>?" in tap["pairs"]
    want = {pair: (n, bad, kinds) for pair, (n, bad, _late, kinds) in tap["pairs"].items()}
    return path, tap, want


def test_the_core_gives_each_malformed_frame(capture):
    path, tap, want = capture
    items = list(Decoder().capture(path))
    frames = [d for d in items if isinstance(d, Decoded)]
    assert by_pair((d.pair, d.kind, d.checksum_ok) for d in frames) == want
    for d in frames:
        if d.kind == "malformed":
            assert d.raw.startswith(b"[:") and not d.updates and not d.late and d.checksum_ok in (False, None)
            assert not d.table.vars


def test_ingest_keeps_a_row_for_each(capture, tmp_path):
    path, tap, want = capture
    report = ingest([path], tmp_path / "ds")
    assert report.frames == tap["Frames"]
    rows = connect(tmp_path / "ds").execute("select pair, kind, checksum_ok, raw from frames").fetchall()
    assert by_pair((pair, kind, ok) for pair, kind, ok, _raw in rows) == want
    assert all(bytes(raw).startswith(b"[:") for _p, kind, _ok, raw in rows if kind == "malformed")


@pytest.mark.parametrize("fmt", ["csv", "jsonl"])
def test_export_writes_a_row_for_each(capture, fmt):
    path, tap, want = capture
    out = io.StringIO()
    assert export(path, out, ExportOptions(fmt=fmt)).frames == tap["Frames"]
    text = out.getvalue()
    rows = list(csv.DictReader(io.StringIO(text))) if fmt == "csv" else [json.loads(x) for x in text.splitlines()]
    assert by_pair((f"{r['src']}>{r['dst']}", r["kind"], r["checksum"]) for r in rows) == want


def test_export_mcap_publishes_a_frames_message_for_each(capture, tmp_path):
    from sl_checks import Mcap

    path, tap, want = capture
    res = export_file(path, tmp_path / "x.mcap", ExportOptions(fmt="mcap"))
    assert res.frames == tap["Frames"]
    m = Mcap(tmp_path / "x.mcap")
    frames = [msg for topic, msgs in m.msgs.items() if topic.endswith("/frames") for _t, msg in msgs]
    assert by_pair((f"{f['src']}>{f['dst']}", f["kind"], f["checksum"]) for f in frames) == want
    # a malformed frame sets and shows nothing: no values message for it
    values = sum(len(msgs) for topic, msgs in m.msgs.items() if topic.endswith("/values"))
    assert values == len(frames) - tap["kinds"]["malformed"]


@pytest.mark.parametrize("fast", [True, False])
def test_diff_counts_them_as_frames(capture, fast):
    path, tap, _want = capture
    rep = diff_captures(path, path, DiffOptions(parallel=False, fast=fast))
    for side in (rep.a, rep.b):
        assert (side.frames, side.checksum_failures) == (tap["Frames"], tap["Checksum failures"])
        assert side.undecodable == tap["Noise"]


def near_misses(raw: bytes) -> list[bytes]:
    """Malformed forms of a hot frame the fast tiers must leave to the general path: cut before
    its ']', its ']' lost (its line end kept), a second '[:' inside it, its letters cut."""
    return [raw[:-3], raw[:-3] + b"\r\n", raw[:12] + b"[:" + raw[12:], raw[:4]]


def test_the_fast_tiers_never_take_a_malformed_frame(tmp_path, tiers):
    """A beacon run by the fast tiers (stats' count_run, diff's compiled layouts and block tier), a
    malformed datagram (a hot frame cut) after every ninth frame: each is one frame of kind
    malformed, under the run's pair, as the tap counts it; the tiers took the runs between."""
    from sl_checks import agree, beacon, ether, udp, write_records

    recs = []
    for i, (ts, raw) in enumerate(beacon("B", "A", 120)):
        recs.append((ts, ether(udp("10.0.0.1", raw))))
        if i % 9 == 8:
            recs.append((ts + MS_, ether(udp("10.0.0.1", near_misses(raw)[i // 9 % 4]))))
    path = write_records(tmp_path / "near-misses.pcap", recs)
    st = agree(path, tiers)
    # 13 near misses, three of them with a '[:' inside (two malformed frames: the second names other letters)
    assert st.kinds["malformed"] == 16 and st.pairs["B>A"].kinds["malformed"] == 13
    assert tiers["counts"] > 60 and tiers["compiled"] + tiers["block"] > 60


def test_checksum_texts_and_a_bar_letter_as_the_dissector_reads_them(tmp_path):
    """The codec follows sharedlink.lua (util.lua checksum_value, parse.lua parse_header): a
    checksum of 1 to 8 hex digits in either case ("0067" is 67; no sign, no space, no "0x"), and
    '|' as a letter ("[:|B|..." is a frame from B to '|'; "[:A||..." from '|' to A). Each frame
    alone in a datagram; stats counts what the tap counts (kinds, pairs, checksum failures)."""
    from sharedlink.protocols.codec import checksum

    def framed(body: str, ck: str) -> bytes:
        return b"[" + body.encode() + ck.encode() + b"]\r\n"

    body = ":AB|N0|D1|C"
    c = checksum(body.encode())
    payloads = [framed(body, t % c) for t in ("%02X", "%04X", "%03x", "%08X", "%09X", "+%X", " %X", "1%02X")]
    for letters in ("|B", "A|"):
        b = f":{letters}|N0|D2|C"
        payloads.append(framed(b, "%02X" % checksum(b.encode())))
    path = write_pcap(tmp_path / "texts.pcap", [Pkt(0.1 * i, p) for i, p in enumerate(payloads)])
    st = capture_stats(path)
    tap = tap_stats(path)
    assert (tap["Frames"], tap["Checksum failures"], tap["Noise"]) == (st.frames, st.checksum_failures,
                                                                       st.noise_segments) == (10, 4, 0)
    assert tap["kinds"] == st.kinds and "malformed" not in st.kinds
    assert tap["pairs"] == {p.pair: (p.frames, p.checksum_failures, p.sync_late, p.kinds) for p in st.pairs.values()}
    assert {"B>|", "|>A"} <= set(st.pairs)


@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_a_bracket_inside_a_value_across_segments(tmp_path, transport):
    """A '[' inside a value is part of it (a frame runs from '[:' to the first ']'), also when a
    TCP segment ends inside the frame, right after that '[', or on a '[' that starts the next
    frame: stats counts what the tap counts, no malformed frame."""
    from sharedlink.protocols.codec import checksum

    def framed(body: bytes) -> bytes:
        return b"[" + body + b"%02X" % checksum(body) + b"]\r\n"

    one, two = framed(b":AB|N0|D1[x|C"), framed(b":AB|N0|D[[2|C")
    if transport == "tcp":
        payloads = [one[:11], one[11:] + two[:10], two[10:] + b"[", GOOD[1:]]
    else:
        payloads = [one, two, GOOD]
    path = write_pcap(tmp_path / f"bracket-{transport}.pcap",
                      [Pkt(0.1 * i, p, 4000, 4000, transport, "10.0.0.2", "10.0.0.1") for i, p in enumerate(payloads)])
    st = capture_stats(path)
    tap = tap_stats(path)
    assert (tap["Frames"], tap["Checksum failures"], tap["Noise"]) == (st.frames, st.checksum_failures,
                                                                       st.noise_segments) == (3, 0, 0)
    assert tap["kinds"] == st.kinds and "malformed" not in st.kinds
    assert tap["vars"] == {k: (v.count, one_line(v.last or "")) for k, v in st.variables.items()}
