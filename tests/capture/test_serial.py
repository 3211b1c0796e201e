"""Serial links, Python side: the incremental deframer, the capture format, log import and the
serial session generator (real files; the dissector and live ports are in the other
test_serial_* files)."""

from __future__ import annotations

import json
import random
import struct
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sl_captures import chunked, examples, reference_frames, sl_stream
from sl_cli import run_cli

from sharedlink.capture.pcapio import read_records
from sharedlink.capture.serial_format import (
    DIR_IN,
    DIR_OUT,
    DIR_UNKNOWN,
    GIVEN_UP,
    MAX_PENDING,
    Deframer,
    SerialCaptureWriter,
    StreamReader,
    detect,
    parse_linktype,
    read_capture,
)
from sharedlink.capture.serial_import import SerialImportError, detect_format, parse_hexdump, read_log
from sharedlink.generators.serial import SerialGenOptions, generate_serial_file, line_records, session_frames
from sharedlink.protocols import blackboard, p2os
from sharedlink.protocols.codec import encode_named, encode_positional, parse_frame

CLI = [sys.executable, "-m", "sharedlink"]

# -- the deframer --------------------------------------------------------------------------------


@settings(max_examples=examples(300), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sl_stream(), st.lists(st.integers(0, 10_000), max_size=40), st.sampled_from(["sharedlink", "auto"]))
def test_any_split_gives_the_frames_of_the_whole_stream(data, cuts, protocol):
    d = Deframer(protocol)
    pieces = []
    for i, c in enumerate(chunked(data, cuts)):
        pieces += d.feed(c, i + 1)
    pieces += d.flush()
    assert [p.data for p in pieces if p.is_frame] == reference_frames(data)
    # nothing lost, nothing doubled, in order
    assert b"".join(p.data for p in pieces) == data
    assert all(a.end == b.start for a, b in zip(pieces, pieces[1:]))
    # each frame decodes as the codec decodes it alone
    for p in pieces:
        if p.is_frame:
            assert p.frame == parse_frame(p.data) and p.records


@settings(max_examples=examples(100), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sl_stream(max_items=6), st.binary(max_size=20), st.sampled_from(["sharedlink", "blackboard"]),
       st.lists(st.integers(1, 3), min_size=1, max_size=8))
def test_held_bytes_appended_without_a_scan_give_what_a_scan_gives(data, garbage, protocol, sizes):
    """Records that only lengthen a held frame are appended without a scan (linear time byte by
    byte, issue 31): the pieces, their reasons and their records are those of scanning the
    whole stream at each record (a Deframer that never takes the short cut)."""
    if protocol == "blackboard":
        data = b"".join(blackboard.build_message(blackboard.SetMessage(0x1F00 + i, 1, bytes([i]))) for i in range(3))
    stream = garbage + data[: len(data) // 2] + garbage + data
    fast, slow = Deframer(protocol), Deframer(protocol)
    got, want = [], []
    pos = k = 0
    while pos < len(stream):
        c = stream[pos : pos + sizes[k % len(sizes)]]
        pos, k = pos + len(c), k + 1
        got += fast.feed(c, k)
        slow._finish = ()  # the reference: every record scanned again
        want += slow.feed(c, k)
    got += fast.flush()
    want += slow.flush()
    assert [(p.start, p.data, p.frame, p.reason, p.records) for p in got] == [
        (p.start, p.data, p.frame, p.reason, p.records) for p in want]


@settings(max_examples=examples(150), deadline=None)
@given(sl_stream(max_items=6), st.binary(min_size=1, max_size=30), st.lists(st.integers(0, 10_000), max_size=20))
def test_a_truncated_tail_or_garbage_loses_no_frame_around_it(data, garbage, cuts):
    frames = reference_frames(data)
    whole = data + garbage + data
    d = Deframer("sharedlink")
    got = []
    for c in chunked(whole, cuts):
        got += d.feed(c)
    got += d.flush()
    fr = [p.data for p in got if p.is_frame]
    # the frames before the garbage all survive; after it, at most the first can be eaten by a
    # '[' in the garbage that opens a frame the real one closes (iter_segments's own rule)
    assert fr[: len(frames)] == frames
    assert fr == reference_frames(whole)
    assert fr[-(len(frames) - 1) :] == frames[1:] or len(frames) == 1


def test_hold_rules_at_chunk_ends():
    f = encode_positional("A", "B", ["1", "2"])
    d = Deframer("sharedlink")
    assert d.feed(f[:-2]) == []  # ']' seen, CR LF not yet: held
    assert d.feed(b"\r") == []
    out = d.feed(b"\n[:A")
    assert [p.data for p in out] == [f] and d.pending == b"[:A"
    # a frame without CR LF completes when the next byte is not CR
    g = encode_positional("A", "B", ["3"], crlf=False)
    d = Deframer("sharedlink")
    assert d.feed(g) == []
    out = d.feed(b"x")
    assert [p.data for p in out] == [g, b"x"] and not out[0].frame.crlf
    assert [p.data for p in d.flush()] == []


@pytest.mark.parametrize("protocol,opener", [("sharedlink", b"[:AB|N0|D"), ("blackboard", b":031F00")])
def test_an_unfinished_frame_is_held_at_most_max_pending_bytes(tmp_path, protocol, opener):
    """A frame that never ends (no ']' or CR) is held only up to MAX_PENDING bytes, then given
    up as noise: the bytes held stay bounded however long the line babbles, nothing is lost,
    and a good frame after it is still found."""
    good = encode_positional("A", "B", ["1"]) if protocol == "sharedlink" else (
        blackboard.build_message(blackboard.SetMessage(0x1F00, 1, b"\x01")))
    chunk = 1000
    babble = opener + b"7" * (3 * MAX_PENDING)
    d = Deframer(protocol)
    pieces, held = [], []
    for i in range(0, len(babble), chunk):
        pieces += d.feed(babble[i : i + chunk])
        held.append(len(d.pending))
    pieces += d.feed(good)
    pieces += d.flush()
    assert max(held) <= MAX_PENDING + chunk
    assert max(held) > MAX_PENDING - chunk  # it did hold, up to the cap
    assert b"".join(p.data for p in pieces) == babble + good
    assert [p.data for p in pieces if p.is_frame] == [good]
    released = [p for p in pieces if not p.is_frame]
    assert released and released[0].start == 0 and released[0].end <= MAX_PENDING + chunk
    # the same through a capture file: the noise is given up while the capture is read, long
    # before its end, with the records it came from
    cap = tmp_path / "babble.pcapng"
    with open(cap, "wb") as fh:
        w = SerialCaptureWriter(fh)
        for i in range(0, len(babble), chunk):
            w.write(babble[i : i + chunk], DIR_IN, 10**9 + i)
        w.write(good, DIR_IN, 10**10)
    out = list(read_capture(cap, protocol))
    first_rec, _d, first = out[0]
    assert not first.is_frame and first_rec is not None and first_rec.number <= MAX_PENDING // chunk + 2
    assert first.records == tuple(range(1, first_rec.number + 1))
    assert [p.data for _r, _d, p in out if p.is_frame] == [good]


def test_p2os_and_blackboard_deframing_and_detection():
    pk = [p2os.build_packet(p2os.encode_command(p2os.command("VEL", v))) for v in (100, -50, 0)]
    stream = b"\x00\x01" + pk[0] + b"\xfa" + pk[1] + pk[2]
    assert detect(stream) == "p2os"
    d = Deframer("auto")
    pieces = [p for c in chunked(stream, [3, 4, 9, 10, 11, 17]) for p in d.feed(c)] + d.flush()
    assert [p.data for p in pieces if p.is_frame] == pk and d.protocol == "p2os"
    assert b"".join(p.data for p in pieces) == stream
    # a checksum byte FA at the end of a packet is not held back as a header start
    tail = next(p2os.build_packet(bytes([x])) for x in range(256) if p2os.build_packet(bytes([x]))[-1] == 0xFA)
    d = Deframer("p2os")
    assert [p.data for p in d.feed(tail)] == [tail]

    msgs = [blackboard.build_message(blackboard.SetMessage(0x1F00, 1, b"\x01\x02\x03")),
            blackboard.build_message(blackboard.RequestMessage(0xE000, 1, 5))]
    assert msgs[0] == b":031F0001010203D7\r"
    stream = b"junk;zz\r" + msgs[0] + b"\n" + msgs[1]
    assert detect(stream) == "blackboard"
    d = Deframer("auto")
    pieces = [p for c in chunked(stream, [2, 9, 12, 19, 20]) for p in d.feed(c)] + d.flush()
    assert [p.data for p in pieces if p.is_frame] == [msgs[0] + b"\n", msgs[1]]


def test_undetected_direction_adopts_the_other_and_is_bounded():
    r = StreamReader("auto")
    assert r.feed(DIR_OUT, b"\x13\x37") == []  # binary, nothing recognisable: held
    f = encode_positional("A", "B", ["1"])
    assert [p.data for p in r.feed(DIR_IN, f)] == [f]
    out = r.feed(DIR_OUT, b"x" + f)
    assert [p.data for p in out if p.is_frame] == [f] and r.deframer(DIR_OUT).protocol == "sharedlink"
    # binary answers only: after ADOPT_AFTER bytes the direction takes the other's protocol
    assert r.feed(DIR_UNKNOWN, bytes(range(40))) == [] and r.deframer(DIR_UNKNOWN).protocol is None
    assert r.feed(DIR_UNKNOWN, bytes(range(40))) and r.deframer(DIR_UNKNOWN).protocol == "sharedlink"
    d = Deframer("auto")
    released = d.feed(bytes(5000))
    assert released and not released[0].is_frame and len(d.pending) == 512


# -- capture format ------------------------------------------------------------------------------


def test_writer_format_is_pcapng_user_linktype_with_direction_flags(tmp_path):
    p = tmp_path / "s.pcapng"
    with open(p, "wb") as fh:
        w = SerialCaptureWriter(fh, parse_linktype("user3"), if_name="/dev/ttyX")
        w.write(b"[:AB|N0", DIR_IN, 1_000_000_000_123_456_789)
        w.write(b"|D1|C", DIR_IN, 1_000_000_000_223_456_789)
        w.write(b"ping", DIR_OUT, 1_000_000_000_323_456_789)
    raw = p.read_bytes()
    assert struct.unpack_from("<I", raw)[0] == 0x0A0D0D0A
    recs = list(read_records(p))
    assert [(r.linktype, r.flags & 3, r.ts_ns) for r in recs] == [
        (150, 1, 1_000_000_000_123_456_789), (150, 1, 1_000_000_000_223_456_789), (150, 2, 1_000_000_000_323_456_789)]
    assert b"".join(r.data for r in recs[:2]) == b"[:AB|N0|D1|C"
    for bad in ("user16", "146", "eth"):
        with pytest.raises(ValueError):
            parse_linktype(bad)


def test_read_capture_reassembles_per_direction(tmp_path):
    a, b = encode_positional("A", "B", ["1", "2"]), encode_named("B", "A", [("X", 2, "1.5")])
    p = tmp_path / "c.pcapng"
    with open(p, "wb") as fh:
        w = SerialCaptureWriter(fh)
        w.write(a[:5], DIR_IN, 1)
        w.write(b[:9], DIR_OUT, 2)  # interleaved directions
        w.write(a[5:] + a[:3], DIR_IN, 3)
        w.write(b[9:], DIR_OUT, 4)
        w.write(a[3:], DIR_IN, 5)
    got = [(rec.number if rec else None, d, piece.data, piece.records) for rec, d, piece in read_capture(p)]
    assert got == [(3, DIR_IN, a, (1, 3)), (4, DIR_OUT, b, (2, 4)), (5, DIR_IN, a, (3, 5))]


# -- generator -----------------------------------------------------------------------------------


def test_generated_session_is_bul049_both_ways_and_line_timed(tmp_path):
    opts = SerialGenOptions(duration=12, baud=9600, seed=3, noise=0.3)
    p = tmp_path / "g.pcapng"
    stats = generate_serial_file(opts, p)
    assert p.read_bytes() == (generate_serial_file(opts, tmp_path / "h.pcapng"), (tmp_path / "h.pcapng").read_bytes())[1]
    expect = {DIR_IN: [], DIR_OUT: []}
    for lf in session_frames(opts):
        expect[lf.direction].append(lf.data)
    kinds = {k for k in stats.kinds}
    assert {"declaration", "full", "delta", "query", "reply"} <= kinds
    got = {DIR_IN: [], DIR_OUT: []}
    recs = list(read_records(p))
    for _rec, d, piece in read_capture(p, "sharedlink"):
        if piece.is_frame:
            got[d].append(piece.data)
    assert got == expect and stats.noise_bytes > 0
    # chunks were cut inside frames, timestamps never go back, and a chunk of n bytes cannot
    # arrive faster than the baud rate allows after the previous one of its direction
    assert any(not r.data.endswith(b"\n") for r in recs)
    assert all(b.ts_ns >= a.ts_ns for a, b in zip(recs, recs[1:]))
    byte_ns = 10 * 1_000_000_000 / opts.baud
    last = {}
    for r in recs:
        d = r.flags & 3
        if d in last:
            assert r.ts_ns - last[d] >= len(r.data) * byte_ns - 2
        last[d] = r.ts_ns
    # frames go to the right node: inbound B->A (vehicle), outbound A->B (host)
    for d, (dst, src) in ((DIR_IN, ("A", "B")), (DIR_OUT, ("B", "A"))):
        assert all((f.dst, f.src) == (dst, src) for f in map(parse_frame, got[d]))
    assert list(line_records(opts)) == list(line_records(opts))


# -- import --------------------------------------------------------------------------------------


def _session_bytes() -> bytes:
    return b"".join(lf.data for lf in session_frames(SerialGenOptions(duration=2)) if lf.direction == DIR_IN)


@pytest.mark.parametrize("tool", [["xxd"], ["hexdump", "-C"], ["od", "-A", "x", "-t", "x1z"], ["od"]])
def test_hex_dumps_of_real_tools_round_trip(tmp_path, tool):
    data = _session_bytes() + bytes(64) + b"\x00" * 3  # zero runs give hexdump/od '*' lines
    src = tmp_path / "dump.bin"
    src.write_bytes(data)
    text = subprocess.run([*tool, str(src)], capture_output=True, check=True).stdout
    (tmp_path / "dump.txt").write_bytes(text)
    assert detect_format(text) == "hex"
    assert parse_hexdump(text.decode()) == data
    fmt, chunks = read_log(tmp_path / "dump.txt", baud=9600, chunk=50, start_ns=0)
    assert fmt == "hex" and b"".join(c.data for c in chunks) == data
    assert chunks[0].ts_ns == 50 * 10 * 1_000_000_000 // 9600


def test_text_log_and_raw_dump_and_cli_import(tmp_path):
    f1, f2 = encode_positional("A", "B", ["1", "2"]), encode_positional("B", "A", ["9"])
    log = tmp_path / "session.log"
    log.write_text(
        "# a terminal logger's output\n"
        f"2026-01-01T12:00:00.250Z RX: {f1[:10].decode()}\n"
        f"2026-01-01T12:00:00.300Z RX: \"{f1[10:-2].decode()}\\r\\n\"\n"
        f"[1767268800.5] TX {' '.join('%02x' % b for b in f2)}\n"
        "< 0x5b ([)\n< 0x3a (:)\n"
    )
    fmt, chunks = read_log(log)
    assert fmt == "log"
    assert [(c.direction, c.data) for c in chunks] == [(DIR_IN, f1[:10]), (DIR_IN, f1[10:]), (DIR_OUT, f2), (DIR_IN, b"[:")]
    # the quoted line's escaped \\r\\n (four characters in the log) is the two bytes CR LF
    assert f1.endswith(b"\r\n") and chunks[1].data.endswith(b"\r\n") and b"\\" not in chunks[1].data
    assert chunks[0].ts_ns == 1_767_268_800_250_000_000 and chunks[2].ts_ns == 1_767_268_800_500_000_000

    out = tmp_path / "o.pcapng"
    r = run_cli("serial", "import", str(log), "--out", str(out), "--frame", "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["frames"] == 2
    recs = list(read_records(out))
    assert [(rec.flags & 3, rec.data) for rec in recs] == [(DIR_IN, f1), (DIR_OUT, f2), (DIR_IN, b"[:")]

    raw = tmp_path / "raw.bin"
    raw.write_bytes(_session_bytes())
    r = run_cli("serial", "import", str(raw), "--out", str(out), "--chunk", "7", "--start", "100", "--direction", "out")
    assert r.returncode == 0, r.stderr
    recs = list(read_records(out))
    assert b"".join(x.data for x in recs) == raw.read_bytes() and all(x.flags & 3 == DIR_OUT for x in recs)
    assert recs[0].ts_ns == 100 * 10**9 + 7 * 10 * 10**9 // 9600


def test_import_errors_are_clean(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("00000000  5b 3a 41  |[:A|\n00000010  41 42\n")
    with pytest.raises(SerialImportError) as ei:
        read_log(bad, "hex")
    assert ei.value.line == 2
    for args in (["serial", "import", str(bad), "-o", str(tmp_path / "x.pcapng"), "--log-format", "hex"],
                 ["serial", "import", str(tmp_path / "missing"), "-o", str(tmp_path / "x.pcapng")],
                 ["serial", "capture", "--baud", "9600"],
                 ["serial", "capture", str(tmp_path / "no-such-tty"), "--baud", "9600", "-o", str(tmp_path / "y.pcapng")],
                 ["gen", "-o", str(tmp_path / "z.pcap"), "--transport", "serial", "--format", "pcap"]):
        r = run_cli(*args)
        assert r.returncode == 2 and r.stderr.startswith("sharedlink: error: ") and "Traceback" not in r.stderr, (args, r.stderr)
    assert not (tmp_path / "x.pcapng").exists()
    r = run_cli("serial", "capture", str(tmp_path / "no-such-tty"), "--baud", "9600", "-o", str(tmp_path / "y.pcapng"))
    # a port that does not open: named once, the reason once (pyserial says both twice)
    assert r.stderr.count("no-such-tty") == 1 and r.stderr.count("No such file or directory") == 1, r.stderr


def test_gen_transport_serial_cli(tmp_path):
    out = tmp_path / "s.pcapng"
    r = run_cli("gen", str(out), "--transport", "serial", "--duration", "3", "--baud", "19200", "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["transport"] == "serial" and s["records"] == len(list(read_records(out)))
    frames = [p for _r, _d, p in read_capture(out) if p.is_frame]
    assert len(frames) == s["frames"]
    # the UDP default is unchanged
    r = run_cli("gen", str(tmp_path / "u.pcap"), "--frames", "3")
    assert r.returncode == 0 and next(read_records(tmp_path / "u.pcap")).linktype == 1


def test_random_bytes_never_raise():
    rng = random.Random(7)
    for _ in range(200):
        data = bytes(rng.choice(b"[]:;|\r\n\xfa\xfbAB0123456789CDEF") for _ in range(rng.randint(0, 200)))
        for proto in ("auto", "sharedlink", "p2os", "blackboard"):
            d = Deframer(proto)
            pieces = [p for i in range(0, len(data), 5) for p in d.feed(data[i : i + 5])] + d.flush()
            assert b"".join(p.data for p in pieces) == data


def _past_the_held_limit(cap):
    """Three unfinished frames of 1.5 MAX_HELD_BYTES in 1 KB records, a good frame after each."""
    good = encode_positional("A", "B", ["1"])
    with open(cap, "wb") as fh:
        w = SerialCaptureWriter(fh, flush=False)
        for k in range(3):
            for c in [b"[:AB|N0|D"] + [b"7" * 1024] * 96 + [good]:
                w.write(c, DIR_OUT, 10**18 + k * 10**9 + len(c))
    return cap


@pytest.mark.parametrize("protocol", ["auto", "sharedlink"])
def test_frames_given_up_at_the_limit_are_those_serial_lua_gives_up(tmp_path, protocol):
    """Unfinished frames of 1.5 MAX_HELD_BYTES in 1 KB records, a good frame after each: the
    Python reader gives up (reason GIVEN_UP) on the very records where serial.lua warns "Limit
    exceeded", and finds the good frames on the same records (auto: the first babble is
    released as unrecognised by both before a frame is seen)."""
    import tshark_util as tu

    cap = _past_the_held_limit(tmp_path / "over.pcapng")
    ours = [(r.number, p.is_frame) for r, _d, p in read_capture(cap, protocol) if p.is_frame or p.reason == GIVEN_UP]
    rows = tu.fields(cap, ["frame.number", "sharedlink.kind", "_ws.expert.message"], two_pass=False,
                     prefs={"slserial.protocol": protocol},
                     extra=["-X", f"lua_script:{tu.REPO / 'dissector' / 'serial.lua'}"])
    theirs = [(int(r["frame.number"][0]), "full" in r["sharedlink.kind"]) for r in rows
              if "full" in r["sharedlink.kind"] or any(m.startswith("Limit exceeded") for m in r["_ws.expert.message"])]
    assert ours == theirs and sum(f for _n, f in ours) == 3 and len(ours) == (5 if protocol == "auto" else 6)


def test_stats_counts_the_frames_given_up_at_the_limit(tmp_path):
    """stats --json's "limits" counts the unfinished serial frames given up at MAX_HELD_BYTES
    (held), as many as the reader gives up (the records serial.lua warns on), their bytes noise."""
    cap = _past_the_held_limit(tmp_path / "over.pcapng")
    given_up = sum(p.reason == GIVEN_UP for _r, _d, p in read_capture(cap, "auto"))
    r = run_cli("stats", str(cap), "--json", timeout=120)
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)
    st = st["captures"][0] if "captures" in st else st
    assert given_up >= 2 and st["limits"]["held"] == given_up and st["frames"] == 3, st


def test_a_hex_dump_whose_repeat_asks_for_terabytes_is_refused_at_once(tmp_path):
    """xxd's '*' repeats the line before up to the next offset: three lines could ask for 64 GB
    (the import allocated until killed). Past MAX_DUMP_BYTES it is one line and exit 2; a real
    repeat still expands (in one step, not a line at a time)."""
    from sharedlink.capture.serial_import import MAX_DUMP_BYTES

    line = "00000000: 5b3a 4142 7c4e 307c 4431 7c43 3030 5d0d  [:AB|N0|D1|C00].\n"
    bomb = tmp_path / "bomb.hex"
    bomb.write_text(line + "*\n1000000000: 0a\n")
    r = run_cli("serial", "import", str(bomb), "-o", str(tmp_path / "b.pcapng"), timeout=60)
    assert r.returncode == 2 and "line 3: offset 0x1000000000 is past what a dump may expand to" in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1 and not (tmp_path / "b.pcapng").exists()
    assert 0x1000000000 > MAX_DUMP_BYTES
    data = parse_hexdump(line + "*\n00100000: 0a\n00100001\n")
    assert len(data) == 0x100001 and data[:16] * (0x100000 // 16) + b"\n" == data
