"""`sharedlink stats`, the `tshark -z sharedlink,stats` tap and the coloring rules.

Python's statistics are checked against the generator's own counts and the independent
reader of test_export; the Lua tap (dissector/sharedlink_stats.lua, run by the real tshark)
must give the same counts per kind and node pair, per-variable counts and last values and
checksum failures as the Python statistics on the same capture.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import tracemalloc
from pathlib import Path

import pytest
from core_streams import stats_by_reference
from sl_captures import BEACON, reference
from sl_checks import tap_stats
from sl_cli import run_cli

from sharedlink.analysis.stats import capture_stats, one_line
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.state import BEACON_VARIABLES
from tshark_util import REPO, TSHARK_CMD, check_stderr, fields

STATS_LUA = REPO / "dissector" / "sharedlink_stats.lua"
COLORFILTERS = REPO / "dissector" / "sharedlink.colorfilters"

VARIANTS = {
    "named": dict(bad_checksum=0.05, drop=0.05),
    "named-compressed": dict(compress=True, bad_checksum=0.05, drop=0.05),
    "positional": dict(form="positional", bad_checksum=0.05),
    "positional-compressed": dict(form="positional", compress=True, drop=0.08),
    "named-compressed-drop": dict(compress=True, drop=0.1, seed=7),
    # issue 28's fault capture: late frames with a bad checksum
    "faults": dict(compress=True, drop=0.3, bad_checksum=0.05, seed=2),
}


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> dict[str, tuple[Path, object]]:
    d = tmp_path_factory.mktemp("stats")
    out = {}
    for name, kw in VARIANTS.items():
        kw = dict(kw)
        seed = kw.pop("seed", 11)
        p = d / f"{name}.pcap"
        out[name] = (p, generate_file(GenOptions(duration=40, seed=seed, **kw), p))
    return out


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_stats_match_the_capture(captures, variant):
    path, gen = captures[variant]
    st = capture_stats(path)
    ref = reference(path)
    assert st.frames == gen.frames == len(ref)
    assert st.checksum_failures == gen.bad_checksums == sum(not f.ok for f in ref)
    assert st.bytes == gen.bytes
    assert sum(st.kinds.values()) == st.frames
    assert st.kinds.get("declaration", 0) == gen.declarations
    assert list(st.pairs) == ["B>A"] and st.pairs["B>A"].frames == st.frames
    assert st.rate_hz == pytest.approx(5.0 * (1 - VARIANTS[variant].get("drop", 0.0)), rel=0.15)
    for name in BEACON:
        v = st.variables[("B>A", name)]
        sent = [float(f.present[name]) for f in ref if name in f.present]
        assert v.count == len(sent)
        assert (v.min, v.max) == (min(sent), max(sent))
        last = next(f for f in reversed(ref) if name in f.present)
        assert v.last == last.present[name] and v.last_frame == last.number
        assert v.changes == sum(name in f.changed for f in ref)
    ratio = st.compression_ratio
    if VARIANTS[variant].get("compress"):
        assert 0.3 < ratio < 0.9
    else:
        assert ratio == 1.0
        assert st.sync_late == 0 and st.sync_gaps == 0
    if variant == "named-compressed-drop":
        assert st.sync_late > 0 and st.sync_gaps > 0


def test_stats_cli_json_and_text(captures):
    path, gen = captures["named-compressed"]
    r = run_cli("stats", path, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["frames"] == gen.frames and doc["checksum_failures"] == gen.bad_checksums
    assert doc["pairs"][0]["pair"] == "B>A" and doc["pairs"][0]["src"] == "B"
    assert {v["name"] for v in doc["variables"]} == set(BEACON)
    assert 0 < doc["compression"]["ratio"] < 1
    r = run_cli("stats", path)
    assert r.returncode == 0
    assert "Frames per kind" in r.stdout and "AutoGpsLat" in r.stdout and "checksum failures" in r.stdout


def test_stats_bad_input(tmp_path, captures):
    r = run_cli("stats", tmp_path / "none.pcap")
    assert r.returncode == 2 and "no such file" in r.stderr
    junk = tmp_path / "j.pcap"
    junk.write_bytes(b"\x00" * 10)
    r = run_cli("stats", junk)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    r = run_cli("stats", captures["named"][0], "--variables", "A:x")
    assert r.returncode == 2 and "--variables" in r.stderr
    # damaged half way: the statistics of what comes before, and exit 2
    data = captures["named"][0].read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[: len(data) // 2 + 5])
    r = run_cli("stats", cut, "--json")
    assert r.returncode == 2 and "error" in r.stderr
    doc = json.loads(r.stdout)
    assert doc["frames"] > 50 and doc["error"]


def test_stats_streams(tmp_path):
    small, big = tmp_path / "s.pcap", tmp_path / "b.pcap"
    generate_file(GenOptions(frames=500, compress=True, seed=3), small)
    generate_file(GenOptions(frames=5000, compress=True, seed=3), big)
    peaks = []
    for p in (small, big):
        tracemalloc.start()
        capture_stats(p)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < 1.5 * peaks[0] + 200_000, peaks


# -- the Lua tap ------------------------------------------------------------------------------




@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_tap_matches_python_stats(captures, variant):
    path, _ = captures[variant]
    st = capture_stats(path)
    tap = tap_stats(path)
    assert tap["Frames"] == st.frames
    assert tap["Checksum failures"] == st.checksum_failures
    assert tap["kinds"] == st.kinds
    assert {k: (n, bad, kinds) for k, (n, bad, _late, kinds) in tap["pairs"].items()} == {
        p.pair: (p.frames, p.checksum_failures, p.kinds) for p in st.pairs.values()
    }
    assert tap["vars"] == {k: (v.count, v.last) for k, v in st.variables.items()}
    # late frames with a bad checksum included (docs/fields-sharedlink.md: the expert fires on
    # any full/delta frame past the interval; the tap counts one per expert): `stats` left them
    # out (55 against the tap's 58 on gen --compress --drop 0.3 --bad-checksum 0.05 --seed 2)
    assert tap["Sync late"] == st.sync_late
    assert {k: late for k, (_n, _bad, late, _kinds) in tap["pairs"].items()} == {
        p.pair: p.sync_late for p in st.pairs.values()
    }


def _vector_streams() -> list:
    from sl_vectors import load_streams, pending

    out = []
    for s in load_streams():
        if s.get("transport") == "serial":  # (the serial transport needs serial.lua)
            continue
        # a rule the two decoders do not both follow yet (issue 29): they differ until both do
        # (not strict for those: the counts compared here need not depend on the rule)
        rule = pending(s, "agreement")
        marks = [pytest.mark.xfail(reason=rule, strict=False)] if rule else []
        out.append(pytest.param(s, id=s["name"], marks=marks))
    return out


@pytest.mark.parametrize("stream", _vector_streams())
def test_tap_matches_python_stats_on_the_shared_vectors(tmp_path, stream):
    """Every count the tap has (frames, checksum failures, sync late, noise, kinds, per pair, per
    variable) on the shared vector streams, as `stats` counts it (docs/fields-sharedlink.md,
    "Counts": a malformed frame is a frame of its header's pair, noise never is), and as `stats`
    counts them the plain way (every frame through the reference decoder)."""
    from sl_vectors import write_stream

    from sharedlink.protocols.state import parse_variables

    path = write_stream(stream, tmp_path / "v.pcap")
    prefs = {"sharedlink.variables": stream["variables"]} if "variables" in stream else None
    variables = parse_variables(stream["variables"]) if "variables" in stream else list(BEACON_VARIABLES)
    st = capture_stats(path, variables)
    tap = tap_stats(path, prefs=prefs)
    assert (tap["Frames"], tap["Checksum failures"], tap["Sync late"], tap["Noise"]) == (
        st.frames, st.checksum_failures, st.sync_late, st.noise_segments)
    assert tap["kinds"] == st.kinds
    assert tap["pairs"] == {p.pair: (p.frames, p.checksum_failures, p.sync_late, p.kinds) for p in st.pairs.values()}
    assert tap["vars"] == {k: (v.count, one_line(v.last or "")) for k, v in st.variables.items()}
    ref = stats_by_reference(path, variables)
    assert (ref.frames, ref.bytes, ref.kinds, ref.noise_segments, ref.noise_bytes) == (
        st.frames, st.bytes, st.kinds, st.noise_segments, st.noise_bytes)
    assert {k: p.to_dict() for k, p in ref.pairs.items()} == {k: p.to_dict() for k, p in st.pairs.items()}


def test_tap_filter_argument(captures):
    path, _ = captures["positional"]
    tap = tap_stats(path, "frame.number <= 10")
    assert tap["Frames"] == 10
    assert tap["kinds"].get("declaration") == 1


def test_tap_without_the_dissector_says_so(captures):
    path, _ = captures["named"]
    env = dict(os.environ, HOME="/nonexistent-sharedlink-home", XDG_CONFIG_HOME="/nonexistent-sharedlink-home")
    r = subprocess.run([*TSHARK_CMD, "-q", "-n", "-X", f"lua_script:{STATS_LUA}", "-r", str(path)],
                       capture_output=True, text=True, env=env, timeout=120)
    assert "sharedlink.lua" in r.stderr and "not loaded" in r.stderr
    assert "stack traceback" not in r.stderr and "attempt to" not in r.stderr


# -- coloring rules and make install ----------------------------------------------------------


def _global_colorfilters() -> Path:
    out = subprocess.run([*TSHARK_CMD, "-G", "folders"], capture_output=True, text=True, timeout=60).stdout
    m = re.search(r"^Global configuration:\s*(.+)$", out, re.M)
    return Path(m.group(1).strip()) / "colorfilters"


def test_colorfilters_mark_bad_checksums_and_late_syncs(tmp_path, captures):
    home = tmp_path / "home"
    conf = home / ".config" / "wireshark"
    conf.mkdir(parents=True)
    default = _global_colorfilters()
    (conf / "colorfilters").write_text(
        COLORFILTERS.read_text() + (default.read_text() if default.exists() else "")
    )
    env = dict(os.environ, HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"), LC_ALL="C.UTF-8")
    env.pop("WIRESHARK_CONFIG_DIR", None)

    def colours(path: Path) -> list[tuple[str, str]]:
        r = subprocess.run([*TSHARK_CMD, "-n", "-X", f"lua_script:{REPO / 'dissector' / 'sharedlink.lua'}",
                            "-r", str(path), "--color", "-T", "psml"], capture_output=True, text=True, env=env,
                           timeout=120)
        assert r.returncode == 0, r.stderr
        check_stderr(r.stderr)
        return re.findall(r"<packet foreground='(#\w+)' background='(#\w+)'>", r.stdout)

    bad = ("#ff5050", "#12272e")  # [65535,20560,20560] on [4718,10030,11796]
    late = ("#000000", "#ffe464")
    ref = reference(captures["named"][0])
    got = colours(captures["named"][0])
    assert [c == bad for c in got] == [not f.ok for f in ref]
    path = captures["named-compressed-drop"][0]
    late_frames = {int(r["frame.number"][0]) for r in fields(path, ["frame.number"], display_filter="sharedlink.sync.late")}
    assert late_frames
    assert {i + 1 for i, c in enumerate(colours(path)) if c == late} == late_frames


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_make_install_prepends_the_rules_once(tmp_path):
    def install(home: Path) -> Path:
        env = dict(os.environ, HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"))
        env.pop("WIRESHARK_CONFIG_DIR", None)
        r = subprocess.run(["make", "-s", "install"], cwd=REPO, capture_output=True, text=True, env=env, timeout=120)
        assert r.returncode == 0, r.stderr
        return home / ".config" / "wireshark" / "colorfilters"

    rules = COLORFILTERS.read_text()
    default = _global_colorfilters()
    # no personal file: ours, then the global default
    cf = install(tmp_path / "a")
    assert cf.read_text() == rules + (default.read_text() if default.exists() else "")
    assert install(tmp_path / "a").read_text().count("@SharedLink bad checksum@") == 1
    assert (tmp_path / "a" / ".local" / "lib" / "wireshark" / "plugins" / "sharedlink_stats.lua").exists()
    # a file of their own: kept, below ours
    theirs = "@My rule@udp.port == 9@[0,0,0][65535,65535,65535]\n"
    mine = tmp_path / "b" / ".config" / "wireshark" / "colorfilters"
    mine.parent.mkdir(parents=True)
    mine.write_text(theirs)
    assert install(tmp_path / "b").read_text() == rules + theirs
    assert install(tmp_path / "b").read_text() == rules + theirs


def test_tap_and_python_agree_on_mixed_traffic(tmp_path):
    """Two node pairs, UDP and a TCP stream with frames split across segments, queries,
    replies, a declaration, positional and named frames, a bad checksum, a string value."""
    from tshark_util import Pkt, frame, write_pcap

    a = frame("A", "B", "N0", "T2", "QAutoGpsLat", "D38.5", "T2", "QAutoGpsLon", "D-77.1", "T4", "QMode", "Dauto run")
    b = frame("A", "B", "N0", "T2", "QAutoGpsLat", "D38.6")
    bad = frame("A", "B", "N0", "T2", "QAutoGpsLat", "D99.9", cs="00")
    decl = frame("C", "D", "N0", "T0", "QCount", "T2", "QLevel")
    pos = frame("C", "D", "N0", "D1", "D0.5")
    pos2 = frame("C", "D", "N0", "D", "D0.75")
    q = frame("D", "C", "QLevel")
    r = frame("C", "D", "RLevel", "D0.8")
    tcp = pos + pos2
    pkts = [
        Pkt(0.0, a), Pkt(0.2, b), Pkt(0.4, bad), Pkt(0.6, b + a),
        Pkt(1.0, decl, 4000, 4000, "tcp", "10.0.0.3", "10.0.0.4"),
        Pkt(1.1, tcp[:10], 4000, 4000, "tcp", "10.0.0.3", "10.0.0.4"),
        Pkt(1.2, tcp[10:], 4000, 4000, "tcp", "10.0.0.3", "10.0.0.4"),
        Pkt(1.3, q, 4000, 4000, "tcp", "10.0.0.4", "10.0.0.3"),
        Pkt(1.4, r, 4000, 4000, "tcp", "10.0.0.3", "10.0.0.4"),
    ]
    path = write_pcap(tmp_path / "mixed.pcap", pkts)
    st = capture_stats(path)
    assert st.frames == 10 and st.checksum_failures == 1
    assert set(st.pairs) == {"B>A", "D>C", "C>D"}
    assert st.variables[("B>A", "Mode")].last == "auto run"
    assert st.variables[("D>C", "Level")].last == "0.8" and st.variables[("D>C", "Level")].count == 3
    assert st.variables[("D>C", "Count")].count == 1
    tap = tap_stats(path)
    assert tap["Frames"] == st.frames and tap["Checksum failures"] == 1
    assert tap["kinds"] == st.kinds
    assert {k: (n, bad_, kinds) for k, (n, bad_, _late, kinds) in tap["pairs"].items()} == {
        p.pair: (p.frames, p.checksum_failures, p.kinds) for p in st.pairs.values()
    }
    assert tap["vars"] == {k: (v.count, v.last) for k, v in st.variables.items()}


@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_blackboard_and_p2os_are_not_noise(tmp_path, transport):
    """Issue 30: the related robot protocols on UDP/TCP are counted as themselves, never as noise
    (a blackboard session's binary acks and read responses with it); real noise still is."""
    from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
    from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file

    bb = generate_blackboard_file(BlackboardGenOptions(duration=3, transport=transport), tmp_path / "bb.pcap")
    st = capture_stats(tmp_path / "bb.pcap")
    assert st.noise_segments == 0 and st.frames == 0
    assert set(st.other_protocols) == {"blackboard"} and st.other_protocols["blackboard"][0] > 0
    if transport == "udp":  # one datagram a message or answer
        assert st.other_protocols["blackboard"][0] == bb.messages
    if transport == "tcp":
        generate_p2os_file(P2osGenOptions(duration=3), tmp_path / "p2.pcap")
        st = capture_stats(tmp_path / "p2.pcap")
        assert st.noise_segments == 0 and set(st.other_protocols) == {"p2os"}
        assert st.to_dict()["other_protocols"]["p2os"]["segments"] == st.other_protocols["p2os"][0]
        r = run_cli("stats", str(tmp_path / "p2.pcap"), timeout=120)
        assert "p2os (not SharedLink)" in r.stdout and "Traceback" not in r.stderr


def test_noise_that_is_no_related_protocol_stays_noise(tmp_path):
    from sharedlink.capture.packets import UdpBuilder
    from sharedlink.capture.pcapio import PcapWriter

    with open(tmp_path / "n.pcap", "wb") as fh:
        w = PcapWriter(fh)
        b = UdpBuilder("10.0.0.1", "10.0.0.9", 7013, 7013)
        for i, payload in enumerate([b"ATZ\r\nOK\r\n", b"\x00\x01\x02", b":zz\r"]):
            w.write(1_700_000_000 * 10**9 + i, b.frame(payload, i + 1))
    st = capture_stats(tmp_path / "n.pcap")
    assert st.noise_segments == 3 and st.other_protocols == {}


@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_malformed_frames_and_noise_count_as_the_dissector_shows_them(tmp_path, transport):
    """docs/fields-sharedlink.md, "Counts": every '[:' the codec cannot read is a frame of kind
    malformed under the pair its header names ('?' for a missing letter), noise is counted apart
    and is never a frame; the tap and `stats` (fast and reference paths) agree on each count."""
    from tshark_util import Pkt, frame, write_pcap

    good = frame("A", "B", "N0", "D1")
    payloads = [
        b"[:AB|N0|D1" + good,  # unterminated: the next '[:' ends it
        b"junk\r\n" + b"[:C]\r\n" + good,  # noise, then a header too short (no source letter)
        b"[:]" + good + b"NO CARRIER\r\n",  # no letters at all; noise after the frame
        b"[:CDx|N0|D2|C00]\r\n" + good,  # no '|' after the letters; its checksum is checked (bad)
        b"[:AB|N0|D1|C5A\r\n" + good,  # unterminated, its last field a checksum ("5A\r\n": bad)
        b"[:AB|N0|D1|C" + frame("A", "B", "N0", "D", crlf=False),  # an empty checksum text: bad
        b"\r\n\r\n" + good + b"\r\n",  # CR LF alone: no noise
        good + b"[:DC|N0|D3",  # unterminated at the end of the payload
    ]
    if transport == "tcp":  # (an unterminated tail waits for the next segment: a frame closes it)
        payloads.append(b"|C00]\r\n")
    pkts = [Pkt(0.1 * i, p, 4000, 4000, transport, "10.0.0.2", "10.0.0.1") for i, p in enumerate(payloads)]
    path = write_pcap(tmp_path / f"malformed-{transport}.pcap", pkts)
    st = capture_stats(path)
    ref = stats_by_reference(path)
    tap = tap_stats(path)
    assert st.kinds.get("malformed", 0) >= 6 and st.noise_segments >= 2 and st.checksum_failures >= 3
    assert "?>C" in st.pairs and "?>?" in st.pairs
    assert (tap["Frames"], tap["Checksum failures"], tap["Sync late"], tap["Noise"]) == (
        st.frames, st.checksum_failures, st.sync_late, st.noise_segments)
    assert tap["kinds"] == st.kinds
    assert tap["pairs"] == {p.pair: (p.frames, p.checksum_failures, p.sync_late, p.kinds) for p in st.pairs.values()}
    assert tap["vars"] == {k: (v.count, one_line(v.last or "")) for k, v in st.variables.items()}
    assert (ref.frames, ref.bytes, ref.kinds, ref.noise_segments) == (st.frames, st.bytes, st.kinds, st.noise_segments)


@pytest.mark.parametrize("stream", _vector_streams())
def test_ingest_and_export_count_as_stats_on_the_shared_vectors(tmp_path, stream):
    """`ingest`'s manifest and frames table, and `export --format jsonl`'s rows, count what `stats`
    (and so the tap) counts: frames, and per pair and kind, checksum failures and late frames
    (docs/fields-sharedlink.md, "Counts")."""
    import io

    from sl_vectors import write_stream

    from sharedlink.analysis.export import ExportOptions, export
    from sharedlink.fleet.ingest import ingest
    from sharedlink.fleet.query import connect
    from sharedlink.protocols.state import parse_variables

    path = write_stream(stream, tmp_path / "v.pcap")
    variables = parse_variables(stream["variables"]) if "variables" in stream else list(BEACON_VARIABLES)
    st = capture_stats(path, variables)
    report = ingest([path], tmp_path / "ds", variables=variables)
    assert report.frames == st.frames
    rows = connect(tmp_path / "ds").execute(
        "select pair, kind, count(*), count(*) filter (where checksum_ok = false), count(*) filter (where late) "
        "from frames group by pair, kind").fetchall()
    got: dict[str, list] = {}
    for pair, kind, n, bad, late in rows:
        p = got.setdefault(pair, [0, 0, 0, {}])
        p[0] += n
        p[1] += bad
        p[2] += late
        p[3][kind] = n
    want = {p.pair: [p.frames, p.checksum_failures, p.sync_late, p.kinds] for p in st.pairs.values()}
    assert got == want
    out = io.StringIO()
    assert export(path, out, ExportOptions(fmt="jsonl", variables=variables)).frames == st.frames
    got = {}
    for line in out.getvalue().splitlines():
        row = json.loads(line)
        p = got.setdefault(f"{row['src']}>{row['dst']}", [0, 0, 0, {}])
        p[0] += 1
        p[1] += row["checksum"] == "bad"
        p[3][row["kind"]] = p[3].get(row["kind"], 0) + 1
    assert got == {k: [n, bad, 0, kinds] for k, (n, bad, _late, kinds) in want.items()}


def test_a_bracket_inside_a_value(tmp_path):
    """'[:AB|N0|D1[x|C..]' is a full frame whose value is '1[x' (a frame runs from '[:' to the
    first ']' after it), as sharedlink.lua decodes it: stats and the tap agree."""
    from sharedlink.protocols.codec import checksum
    from tshark_util import Pkt, frame, write_pcap

    body = b":AB|N0|D1[x|C"
    raw = b"[" + body + b"%02X" % checksum(body) + b"]\r\n"
    path = write_pcap(tmp_path / "bracket.pcap", [Pkt(0.0, raw), Pkt(0.2, frame("A", "B", "N0", "D2"))])
    st = capture_stats(path)
    tap = tap_stats(path)
    assert (tap["Frames"], tap["Noise"]) == (st.frames, st.noise_segments) == (2, 0)
    assert tap["kinds"] == st.kinds
