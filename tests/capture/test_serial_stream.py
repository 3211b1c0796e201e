"""Serial captures through the general reader: ``stream.iter_frames`` (what stats, export and
plot read) and diff's ``ChangeReader`` find every SharedLink frame of a serial session.

The generator's own list of frames (``gen_serial.session_frames``, with kinds) is the
reference: the frames must come out with their exact bytes, per direction and in order, and
``sharedlink stats`` must count the same kinds per node pair, whatever the UART chunking and
with line noise between the frames.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import pytest
from sl_cli import run_cli

from sharedlink.analysis.changes import read_changes
from sharedlink.analysis.diff import DiffOptions, diff_captures
from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.pcapio import CaptureError, PcapWriter, read_records
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT, SerialCaptureWriter
from sharedlink.capture.stream import Chunk, StreamFrame, iter_frames
from sharedlink.generators.serial import SerialGenOptions, generate_serial_file, session_frames
from sharedlink.protocols.codec import encode_positional

CLI = [sys.executable, "-m", "sharedlink"]

OPTIONS = {
    "default": SerialGenOptions(duration=10),
    "noise": SerialGenOptions(duration=20, noise=0.3, seed=2),
    "noise-1-byte-reads": SerialGenOptions(duration=8, noise=0.5, max_chunk=1, seed=5),
    "noise-big-reads": SerialGenOptions(duration=8, noise=0.2, max_chunk=200, seed=6),
    "uncompressed-user5": SerialGenOptions(duration=8, compress=False, linktype=152, host="C", vehicle="D", seed=3),
}


@pytest.fixture(scope="module", params=sorted(OPTIONS))
def session(request, tmp_path_factory) -> tuple[Path, SerialGenOptions, object]:
    opts = OPTIONS[request.param]
    p = tmp_path_factory.mktemp("serial") / f"{request.param}.pcapng"
    return p, opts, generate_serial_file(opts, p)


def _expected_kinds(opts: SerialGenOptions) -> tuple[Counter, dict[str, Counter]]:
    total: Counter = Counter()
    pairs: dict[str, Counter] = {}
    for lf in session_frames(opts):
        total[lf.kind] += 1
        pair = f"{opts.vehicle}>{opts.host}" if lf.direction == DIR_IN else f"{opts.host}>{opts.vehicle}"
        pairs.setdefault(pair, Counter())[lf.kind] += 1
    return total, pairs


def test_stats_counts_every_frame_per_kind_and_pair(session):
    path, opts, gen = session
    total, pairs = _expected_kinds(opts)
    st = capture_stats(path, sync_interval=opts.sync_interval)
    assert st.error is None
    assert dict(st.kinds) == dict(total) == gen.kinds
    assert st.frames == gen.frames
    assert {p: dict(ps.kinds) for p, ps in st.pairs.items()} == {p: dict(c) for p, c in pairs.items()}
    assert st.checksum_failures == 0 and st.other_records == 0
    # every byte is a frame or noise: no frame lost around the noise
    assert st.noise_bytes == gen.noise_bytes
    assert st.bytes == gen.bytes - gen.noise_bytes
    if opts.noise:
        assert st.noise_segments > 0


def test_iter_frames_gives_each_direction_s_frames_in_order_with_their_record(session):
    path, opts, _gen = session
    records = {r.number: r for r in read_records(path)}
    # each record's place in its direction's byte stream: (start, end) offsets
    spans: dict[int, tuple[int, int]] = {}
    ends = {DIR_IN: 0, DIR_OUT: 0}
    for n, r in records.items():
        d = r.flags & 3
        spans[n] = (ends[d], ends[d] + len(r.data))
        ends[d] += len(r.data)
    offset = {"inbound": 0, "outbound": 0}  # frames and noise tile each stream
    got: dict[str, list[bytes]] = {"inbound": [], "outbound": []}
    last_number = 0
    for item in iter_frames(path):
        assert isinstance(item, StreamFrame), item  # no record is of another protocol
        proto, direction, linktype, dst, interface = item.conv
        assert (proto, linktype, dst, interface) == ("serial", opts.linktype, "", 0)
        assert item.number >= last_number  # in capture order
        last_number = item.number
        rec = records[item.number]
        assert item.ts_ns == rec.ts_ns
        assert rec.flags & 3 == {"inbound": DIR_IN, "outbound": DIR_OUT}[direction]
        offset[direction] += len(item.raw)
        if item.frame is not None:
            # the frame's last byte is in the record that completed it
            start, end = spans[item.number]
            assert start < offset[direction] <= end
            got[direction].append(item.raw)
    want = {
        name: [lf.data for lf in session_frames(opts) if lf.direction == d]
        for name, d in (("inbound", DIR_IN), ("outbound", DIR_OUT))
    }
    assert got == want
    assert offset == {"inbound": ends[DIR_IN], "outbound": ends[DIR_OUT]}


def test_diff_of_a_serial_capture_with_itself_agrees_on_every_frame(session):
    path, opts, gen = session
    total, _ = _expected_kinds(opts)
    value_frames = total["full"] + total["delta"] + total["reply"]
    rep = diff_captures(path, path, DiffOptions(parallel=False))
    assert rep.agree
    d = rep.to_dict()
    for side in ("a", "b"):
        s = d[side]
        assert (s["frames"], s["value_frames"], s["full"]) == (gen.frames, value_frames, total["full"])
        assert (s["records"], s["other_packets"], s["checksum_failures"]) == (gen.records, 0, 0)
        assert s["payload_bytes"] == gen.bytes - gen.noise_bytes
        assert s["undecodable"] == capture_stats(path).noise_segments
    assert d["pairs"] == value_frames
    # the fast reader and the general one agree (serial records always take the general path)
    fast = [c.as_tuple() if isinstance(c, Chunk) else c.to_dict() for c in read_changes(path)]
    slow = [c.as_tuple() if isinstance(c, Chunk) else c.to_dict() for c in read_changes(path, fast=False)]
    assert fast == slow


def test_cli_stats_export_and_diff_on_a_serial_capture(tmp_path):
    p = tmp_path / "s.pcapng"
    r = run_cli("gen", str(p), "--transport", "serial", "--duration", "10", "--json")
    assert r.returncode == 0, r.stderr
    gen = json.loads(r.stdout)
    r = run_cli("stats", str(p), "--json")
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)
    assert st["kinds"] == gen["kinds"] and st["frames"] == gen["frames"] > 0
    r = run_cli("export", str(p), "--format", "jsonl")
    assert r.returncode == 0, r.stderr
    rows = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(rows) == gen["frames"]
    assert Counter(row["kind"] for row in rows) == Counter(gen["kinds"])
    r = run_cli("diff", str(p), str(p), "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["agree"] and rep["a"]["frames"] == gen["frames"] and rep["pairs"] > 0


@pytest.mark.parametrize("protocol", ["p2os", "blackboard"])
def test_other_protocols_on_the_line_are_other_records_not_frames_or_noise(tmp_path, protocol):
    p = tmp_path / f"{protocol}.pcapng"
    r = run_cli("gen", str(p), "--protocol", protocol, "--transport", "serial", "--duration", "5")
    assert r.returncode == 0, r.stderr
    n = sum(1 for _ in read_records(p))
    items = list(iter_frames(p))
    assert all(isinstance(i, tuple) for i in items)
    assert sorted(i[0] for i in items) == list(range(1, n + 1))  # each record once
    st = capture_stats(p)
    assert (st.frames, st.noise_segments, st.other_records) == (0, 0, n)
    rep = diff_captures(p, p, DiffOptions(parallel=False)).to_dict()
    assert (rep["a"]["frames"], rep["a"]["undecodable"], rep["a"]["other_packets"]) == (0, 0, n)


def _frame(i: int, crlf: bool = True) -> bytes:
    return encode_positional("A", "B", ["%d.5" % i, "2.5", "3", "4"], crlf=crlf)


def test_the_tails_are_flushed_at_the_end_of_the_capture(tmp_path):
    p = tmp_path / "tail.pcapng"
    with open(p, "wb") as fh:
        w = SerialCaptureWriter(fh)
        w.write(_frame(1) + _frame(2)[:5], DIR_IN, 1_000)
        w.write(_frame(2)[5:], DIR_IN, 2_000)
        w.write(b"[:BA|N0|D1", DIR_OUT, 3_000)  # never finished
        w.write(_frame(3, crlf=False), DIR_IN, 4_000)  # its CR LF might have come later
    items = list(iter_frames(p))
    frames = [(i.number, i.ts_ns, i.conv[1], i.raw) for i in items if isinstance(i, StreamFrame) and i.frame]
    assert frames == [
        (1, 1_000, "inbound", _frame(1)),
        (2, 2_000, "inbound", _frame(2)),
        (4, 4_000, "inbound", _frame(3, crlf=False)),
    ]
    noise = [(i.number, i.ts_ns, i.conv[1], i.raw) for i in items if isinstance(i, StreamFrame) and not i.frame]
    assert noise == [(3, 3_000, "outbound", b"[:BA|N0|D1")]
    assert capture_stats(p).frames == 3
    assert diff_captures(p, p, DiffOptions(parallel=False)).to_dict()["a"]["frames"] == 3


def test_a_damaged_capture_gives_its_held_frame_before_the_error(tmp_path):
    p = tmp_path / "damaged.pcapng"
    with open(p, "wb") as fh:
        w = SerialCaptureWriter(fh)
        w.write(_frame(1), DIR_IN, 1_000)
        w.write(_frame(2, crlf=False), DIR_IN, 2_000)
        w.write(b"\r\n" + _frame(3), DIR_IN, 3_000)
    data = p.read_bytes()
    p.write_bytes(data[:-10])  # the last record is cut short
    got = []
    with pytest.raises(CaptureError):
        for item in iter_frames(p):
            got.append(item)
    assert [i.raw for i in got if isinstance(i, StreamFrame) and i.frame] == [_frame(1), _frame(2, crlf=False)]
    rep = diff_captures(p, p, DiffOptions(parallel=False)).to_dict()
    assert rep["a"]["frames"] == 2 and rep["a"]["error"]


def test_classic_pcap_with_a_user_link_type_is_one_stream(tmp_path):
    p = tmp_path / "classic.pcap"
    data = _frame(1) + b"xx" + _frame(2)
    with open(p, "wb") as fh:
        w = PcapWriter(fh, 147)
        for k, i in enumerate(range(0, len(data), 7)):
            w.write(1_000 * (k + 1), data[i : i + 7])
    items = list(iter_frames(p))
    assert [(i.conv, i.raw) for i in items] == [
        (("serial", "unknown", 147, "", 0), _frame(1)),
        (("serial", "unknown", 147, "", 0), b"xx"),
        (("serial", "unknown", 147, "", 0), _frame(2)),
    ]
    rep = diff_captures(p, p, DiffOptions(parallel=False)).to_dict()
    assert rep["agree"] and (rep["a"]["frames"], rep["a"]["undecodable"]) == (2, 1)
