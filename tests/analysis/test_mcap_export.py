"""`sharedlink export --format mcap`: the file read back with the independent `mcap` reader.

Counts are compared with what tshark and the dissectors see in the same capture, values and
times with ``sl_captures.reference`` (an independent reading of the pcap) and with tshark's
P2OS fields. Protobuf messages (LocationFix, PoseInFrame) are decoded with the `protobuf`
package from the schema stored in the file, as Foxglove does.
"""

from __future__ import annotations

import json
import math
from collections import Counter, defaultdict
from pathlib import Path

import pytest
from core_streams import vector_capture
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sl_captures import BEACON, captures, examples, reference, write_capture
from sl_checks import Mcap
from sl_cli import run_cli
from sl_vectors import load_streams

import tshark_util as tu
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.state import BEACON_VARIABLES

mcap_reader = pytest.importorskip("mcap.reader")
descriptor_pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")

REPO = Path(__file__).resolve().parents[2]
OTHERS = [a for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua"
          for a in ("-X", f"lua_script:{s}")]


def epoch_ns(text: str) -> int:
    """tshark's frame.time_epoch ("1767268801.383333333") as integer ns, exactly."""
    sec, _, frac = text.partition(".")
    return int(sec) * 10**9 + int((frac + "000000000")[:9])




@pytest.fixture(scope="module")
def beacon(tmp_path_factory) -> tuple[Path, Mcap]:
    d = tmp_path_factory.mktemp("mcap")
    cap = d / "drive.pcap"
    generate_file(GenOptions(duration=30, seed=3, compress=True, drop=0.05, bad_checksum=0.05), cap)
    out = d / "drive.mcap"
    r = run_cli("export", cap, "-o", out)
    assert r.returncode == 0, r.stderr
    assert "messages" in r.stderr
    return cap, Mcap(out)


def test_beacon_schemas_topics_and_counts_match_tshark(beacon):
    cap, m = beacon
    assert m.header.profile == "sharedlink"
    base = "/sharedlink/B_to_A"
    assert m.schemas == {
        f"{base}/location": ("foxglove.LocationFix", "protobuf", "protobuf"),
        f"{base}/values": ("sharedlink.Values", "jsonschema", "json"),
        f"{base}/frames": ("sharedlink.Frame", "jsonschema", "json"),
        f"{base}/link_quality": ("sharedlink.LinkQuality", "jsonschema", "json"),
    }
    rows = tu.fields(cap, ["sharedlink.src", "sharedlink.dst", "sharedlink.checksum.status", "sharedlink.kind"])
    pairs = Counter((r["sharedlink.src"][0], r["sharedlink.dst"][0]) for r in rows if r["sharedlink.src"])
    assert pairs == {("B", "A"): len(m.msgs[f"{base}/frames"])}
    good = sum(1 for r in rows if r["sharedlink.checksum.status"] == ["1"])
    bad = len(rows) - good
    assert bad > 0 and good > 100
    assert m.counts() == {t: len(v) for t, v in m.msgs.items()}
    assert len(m.msgs[f"{base}/values"]) == len(m.msgs[f"{base}/frames"])
    assert len(m.msgs[f"{base}/location"]) == good  # every good frame of a beacon has a position
    assert Counter(f["checksum"] for _t, f in m.msgs[f"{base}/frames"]) == {"good": good, "bad": bad}


def test_beacon_log_times_values_and_positions_match_the_capture(beacon):
    cap, m = beacon
    ref = reference(cap)
    base = "/sharedlink/B_to_A"
    frames, values = m.msgs[f"{base}/frames"], m.msgs[f"{base}/values"]
    assert len(frames) == len(ref)
    for (t, f), (tv, v), fr in zip(frames, values, ref):
        assert t == tv == fr.ts_ns
        assert f["number"] == fr.number and (f["src"], f["dst"]) == (fr.src, fr.dst)
        assert f["checksum"] == ("good" if fr.ok else "bad")
        assert f["text"].startswith(f"[:{fr.dst}{fr.src}|") and f["text"].endswith("]")
        assert sorted(f["changed"]) == sorted(fr.changed)
        assert set(v) == set(fr.values)
        for name in BEACON:
            if name in fr.values:
                assert isinstance(v[name], float) and v[name] == float(fr.values[name])
    good = [fr for fr in ref if fr.ok]
    locs = m.msgs[f"{base}/location"]
    for (t, fix), fr in zip(locs, good):
        assert t == fr.ts_ns == fix.timestamp.seconds * 10**9 + fix.timestamp.nanos
        assert fix.latitude == float(fr.values["AutoGpsLat"]) and fix.longitude == float(fr.values["AutoGpsLon"])
        # the schema's units: radians (the variable is in degrees), m/s (the variable in mph)
        assert fix.heading == pytest.approx(float(fr.values["AutoGpsHead"]) * math.pi / 180, abs=1e-12)
        speed = float(fr.values["AutoGpsVel"]) * 0.44704
        assert math.hypot(fix.velocity.x, fix.velocity.y) == pytest.approx(speed, abs=1e-9)
        if speed > 0:  # east = sin(heading), north = cos(heading)
            assert math.atan2(fix.velocity.x, fix.velocity.y) == pytest.approx(
                math.remainder(fix.heading, 2 * math.pi), abs=1e-9)
        assert list(fix.position_covariance) == [0.0] * 9 and fix.position_covariance_type == 0
        assert fix.frame_id == "B>A"
    # first and last, spelled out
    assert locs[0][0] == good[0].ts_ns and locs[-1][0] == good[-1].ts_ns
    assert values[-1][1]["AutoGpsLat"] == float(ref[-1].values["AutoGpsLat"])


def test_other_lat_lon_names(tmp_path):
    cap = tmp_path / "p.pcap"
    generate_file(GenOptions(duration=5, seed=2), cap)
    out = tmp_path / "p.mcap"
    # a name the capture never carries is refused (issue 30), no file left behind
    r = run_cli("export", cap, "--format", "mcap", "-o", out, "--heading", "Nope", "--velocity", "Nope")
    assert r.returncode == 2 and "no variable Nope" in r.stderr and not out.exists(), r.stderr
    r = run_cli("export", cap, "--format", "mcap", "-o", out, "--lat", "AutoGpsLon", "--lon", "AutoGpsLat")
    assert r.returncode == 0, r.stderr
    m = Mcap(out)
    ref = reference(cap)
    fixes = m.msgs["/sharedlink/B_to_A/location"]
    assert len(fixes) == len(ref)
    fix = fixes[-1][1]
    assert fix.latitude == float(ref[-1].values["AutoGpsLon"]) and fix.longitude == float(ref[-1].values["AutoGpsLat"])


@pytest.mark.parametrize("transport", ["tcp", "serial"])
def test_p2os_session_poses_and_commands_match_tshark(tmp_path, transport):
    cap = tmp_path / f"p2os-{transport}.pcapng"
    r = run_cli("gen", cap, "--protocol", "p2os", "--transport", transport, "--duration", "8")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "p2os.mcap"
    r = run_cli("export", cap, "-o", out)
    assert r.returncode == 0, r.stderr
    m = Mcap(out)
    assert m.schemas["/p2os/1/pose"] == ("foxglove.PoseInFrame", "protobuf", "protobuf")
    assert m.schemas["/p2os/1/commands"][2] == "json"
    rows = tu.fields(cap, ["frame.time_epoch", "p2os.direction", "p2os.type", "p2os.command", "p2os.sip.xpos",
                           "p2os.sip.ypos", "p2os.sip.thpos", "p2os.sip.lvel"], extra=OTHERS)
    clients = [c for r in rows for d, c in zip(r["p2os.direction"], r["p2os.command"] or [None] * 99) if d == "0"]
    n_client = sum(d == "0" for r in rows for d in r["p2os.direction"])
    n_server = sum(d == "1" for r in rows for d in r["p2os.direction"])
    sips = [(int(x), int(y), int(th), int(lv)) for r in rows
            for x, y, th, lv in zip(r["p2os.sip.xpos"], r["p2os.sip.ypos"], r["p2os.sip.thpos"], r["p2os.sip.lvel"])]
    assert n_client == len(m.msgs["/p2os/1/commands"]) > 10 and clients
    assert n_server == len(m.msgs["/p2os/1/sip"]) + len(m.msgs["/p2os/1/server"])
    assert len(sips) == len(m.msgs["/p2os/1/pose"]) == len(m.msgs["/p2os/1/sip"]) > 10
    assert [c["command"] for _t, c in m.msgs["/p2os/1/commands"]] == [int(c) for c in clients]
    for (t, pose), (_t2, sip), (x, y, th, lv) in zip(m.msgs["/p2os/1/pose"], m.msgs["/p2os/1/sip"], sips):
        assert pose.pose.position.x == x / 1000 and pose.pose.position.y == y / 1000
        yaw = 2 * math.atan2(pose.pose.orientation.z, pose.pose.orientation.w)
        assert math.isclose(math.remainder(yaw - th * 2 * math.pi / 4096, 2 * math.pi), 0, abs_tol=1e-9)
        assert (sip["x_mm"], sip["y_mm"], sip["lvel_mm_s"]) == (x, y, lv)
        assert t == pose.timestamp.seconds * 10**9 + pose.timestamp.nanos
    # log times are the capture times of the records that carried the SIPs
    sip_times = [epoch_ns(r["frame.time_epoch"][0]) for r in rows for _x in r["p2os.sip.xpos"]]
    assert [t for t, _p in m.msgs["/p2os/1/pose"]] == sip_times


def test_blackboard_messages_match_tshark(tmp_path):
    cap = tmp_path / "bb.pcap"
    r = run_cli("gen", cap, "--protocol", "blackboard", "--duration", "5")
    assert r.returncode == 0, r.stderr
    out = tmp_path / "bb.mcap"
    assert run_cli("export", cap, "-o", out).returncode == 0
    m = Mcap(out)
    rows = tu.fields(cap, ["blackboard.type"], extra=OTHERS)
    want = Counter(t for r in rows for t in r["blackboard.type"])
    got = Counter(msg["type"] for _t, msg in m.msgs["/blackboard/1/messages"])
    assert got == want and got["set"] > 10 and got["response"] > 5


def test_mcap_needs_a_file_and_a_readable_capture(tmp_path):
    cap = tmp_path / "x.pcap"
    generate_file(GenOptions(duration=2), cap)
    r = run_cli("export", cap, "--format", "mcap")
    assert r.returncode == 2 and "sharedlink: error:" in r.stderr and "-o" in r.stderr
    r = run_cli("export", tmp_path / "missing.pcap", "-o", tmp_path / "y.mcap")
    assert r.returncode == 2 and not (tmp_path / "y.mcap").exists()
    bad = tmp_path / "bad.pcap"
    bad.write_bytes(b"not a capture at all")
    r = run_cli("export", bad, "-o", tmp_path / "z.mcap")
    assert r.returncode == 2 and "Traceback" not in r.stderr and not (tmp_path / "z.mcap").exists()


@pytest.mark.parametrize("form", ["named", "positional"])
def test_hot_path_messages_equal_the_reference_builders(tmp_path, form):
    """FoxgloveChannels.frame's hand-formatted rows and cached values equal frame_json/values_json."""
    import io

    import foxglove

    from sharedlink.analysis.decode import Decoded, iter_decoded
    from sharedlink.analysis.foxglove_channels import FoxgloveChannels, frame_json, values_json

    cap = tmp_path / "c.pcap"
    generate_file(GenOptions(duration=10, seed=9, form=form, compress=True, bad_checksum=0.1, drop=0.1), cap)
    ctx = foxglove.Context()
    buf = io.BytesIO()
    writer = foxglove.open_mcap(buf, context=ctx)
    channels = FoxgloveChannels(ctx)
    want_frames, want_values = [], []
    for d in iter_decoded(cap):
        if isinstance(d, Decoded):
            channels.frame(d)
            want_frames.append(frame_json(d))
            want_values.append(values_json(d))
    writer.close()
    path = tmp_path / "c.mcap"
    path.write_bytes(buf.getvalue())
    m = Mcap(path)
    assert [f for _t, f in m.msgs["/sharedlink/B_to_A/frames"]] == want_frames
    assert [v for _t, v in m.msgs["/sharedlink/B_to_A/values"]] == want_values
    assert channels.counts == m.counts()


@pytest.mark.parametrize("type_code", [None, 0, 2, 4])
def test_value_fragment_is_the_typed_value_as_json(type_code):
    """A values message member (FoxgloveChannels' hot path, _fragment) reads back as the typed
    value the reference gives (Variable.value; text where a double is not finite), of the same
    type, for texts of every kind: JSON numbers or not, integers for a double, fractions for a
    long, overflowing exponents, leading zeros, signs, empty."""
    import json
    import math

    from sharedlink.analysis.foxglove_channels import _fragment
    from sharedlink.protocols.state import Variable

    texts = ["7", "-0", "0", "12345678901234567890", "1.5", "-0.25", "1e5", "1E-3", "1e999", "-1e999", "007",
             "1.", ".5", "+3", "abc", "", "0x10", "1_000", "NaN", " 1", "2.50"]
    for t in texts:
        v = Variable("Speed", type_code, t)
        want = v.value
        if isinstance(want, float) and not math.isfinite(want):
            want = t
        x, member = _fragment("Speed", v)
        got = json.loads("{" + member + "}")["Speed"]
        assert (type(x), x) == (type(want), want), t
        assert (type(got), got) == (type(want), want), t


@settings(max_examples=examples(300), deadline=None)
@given(st.one_of(st.just(0.0), st.floats(-90, 90), st.integers(-90, 90)), st.one_of(st.just(0.0), st.floats(-180, 180)),
       st.one_of(st.none(), st.just(0.0), st.floats(-720, 720)), st.one_of(st.none(), st.just(0), st.floats(0, 200)),
       st.integers(0, (1 << 32) * 10**9 - 1), st.sampled_from(["B>A", "C>A", ""]))
def test_spliced_location_fix_equals_the_whole_encoding(lat, lon, head, speed, ts_ns, frame_id):
    """The location channels' messages (a LocationFix encoded by hand: the fields after the
    timestamp kept per heading and speed) are byte for byte foxglove-sdk's encoding of the
    whole message, for
    zero and signed coordinates, no heading or speed, times from 1970 to 2106 (foxglove-sdk's
    Timestamp holds unsigned 32-bit seconds)."""
    import foxglove

    import sharedlink.analysis.foxglove_channels as fc
    from sharedlink.analysis.foxglove_channels import ChannelOptions, FoxgloveChannels, _Direction

    ch = FoxgloveChannels(foxglove.Context(), ChannelOptions())
    typed = {"AutoGpsLat": lat, "AutoGpsLon": lon, "AutoGpsHead": head, "AutoGpsVel": speed}
    dr = _Direction(None, None, None)
    whole = ch._location(typed, ts_ns, frame_id)
    assert whole is not None
    fc._splice[0] = True  # (the hand-made encoding itself, not the sdk's it falls back to)
    for _ in range(2):  # made, then from the kept fields
        assert ch._fix_bytes(dr, typed, ts_ns, frame_id) == whole.encode()


def _sharedlink_messages(path: Path) -> dict[str, list]:
    """The SharedLink messages (topic, log time, bytes) in the file's order, all topics
    together (so an order across directions counts), under the key ``"all"``; and per topic.
    (Not the link_quality topics nor the values' gap messages at outages, under ``"gaps"``: written
    at the end from link health, test_mcap_link_quality.py, test_mcap_outage_gaps.py.)"""
    out: dict[str, list] = defaultdict(list)
    with open(path, "rb") as fh:
        for _schema, channel, message in mcap_reader.make_reader(fh).iter_messages(log_time_order=False):
            if b'"NaN"' in message.data and "NaN" in json.loads(message.data).values():
                out["gaps"].append((channel.topic, message.log_time))
            elif channel.topic.startswith("/sharedlink/") and not channel.topic.endswith("/link_quality"):
                out["all"].append((channel.topic, message.log_time, message.data))
                out[channel.topic].append((message.log_time, message.data))
    return out


def _reference_mcap(cap: Path, out: Path, variables) -> dict[str, int]:
    """The SharedLink messages of ``cap`` published frame by frame (FoxgloveChannels.frame) from
    the plain reference decoder's frames."""
    import foxglove
    from core_streams import reference_items

    from sharedlink.analysis.decode import Decoded, ReferenceDecoder
    from sharedlink.analysis.foxglove_channels import FoxgloveChannels

    ctx = foxglove.Context()
    with open(out, "wb") as fh:
        writer = foxglove.open_mcap(fh, context=ctx)
        channels = FoxgloveChannels(ctx)
        dec = ReferenceDecoder(variables, carried=False)
        for d in reference_items(dec, cap):
            if isinstance(d, Decoded):
                channels.frame(d)
        writer.close()
    return channels.counts


def _same_as_reference(tmp_path: Path, cap: Path, variables=BEACON_VARIABLES) -> int:
    """export_mcap (the core's columns mode) gives the messages the reference frames give."""
    from sharedlink.analysis.export import ExportOptions
    from sharedlink.analysis.mcap_export import export_mcap

    export_mcap(cap, tmp_path / "new.mcap", ExportOptions(variables=list(variables)))
    want_counts = _reference_mcap(cap, tmp_path / "ref.mcap", variables)
    got, want = _sharedlink_messages(tmp_path / "new.mcap"), _sharedlink_messages(tmp_path / "ref.mcap")
    gaps = Counter(t for t, _ in got.pop("gaps", []))
    assert got.keys() == want.keys()
    for topic in want:
        assert got[topic] == want[topic], topic
    counts = Mcap(tmp_path / "new.mcap").counts()
    assert {t: n - gaps[t] for t, n in counts.items() if t.startswith("/sharedlink/") and not t.endswith("/link_quality")
            } == want_counts
    return len(got["all"])


@pytest.mark.parametrize("variant", [dict(compress=True, bad_checksum=0.1, drop=0.3, jitter_ms=300.0, seed=2),
                                     dict(seed=3), dict(form="positional", compress=True, bad_checksum=0.05, seed=4)])
def test_columns_mode_messages_equal_the_reference_frames_on_fault_captures(tmp_path, variant):
    cap = tmp_path / "c.pcap"
    generate_file(GenOptions(duration=30, **variant), cap)
    assert _same_as_reference(tmp_path, cap) > 100


@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
@given(captures())
def test_columns_mode_messages_equal_the_reference_frames_on_varied_captures(tmp_path_factory, dgs):
    d = tmp_path_factory.mktemp("mc")
    _same_as_reference(d, write_capture(d / "x.pcap", dgs))


@pytest.mark.parametrize("stream", load_streams(), ids=lambda s: s["name"])
def test_columns_mode_messages_equal_the_reference_frames_on_the_shared_vectors(tmp_path, stream):
    """(replies whose value stays on the reply included: their name is in no table)"""
    cap, variables = vector_capture(stream, tmp_path)
    _same_as_reference(tmp_path, cap, variables)


def test_columns_mode_keeps_the_order_of_frames_of_two_directions_in_a_batch(tmp_path):
    """Two vehicles' compressed beacons interleaved: a batch holds frames of both directions,
    published in capture order (the file's message order as the reference's)."""
    from sharedlink.capture.pcapio import PcapWriter, read_records

    records = []
    for i, src in enumerate("BC"):
        part = tmp_path / f"{src}.pcap"
        generate_file(GenOptions(duration=30, seed=i + 1, compress=True, src=src, bad_checksum=0.02), part)
        records += [(r.ts_ns + i * 50_000_000, r.data) for r in read_records(part)]
    cap = tmp_path / "two.pcap"
    with open(cap, "wb") as fh:
        w = PcapWriter(fh)
        for ts, data in sorted(records, key=lambda r: r[0]):
            w.write(ts, data)
    assert _same_as_reference(tmp_path, cap) > 300


def test_columns_mode_messages_equal_the_reference_frames_for_values_of_every_kind(tmp_path):
    """Runs of named frames the columns mode takes, with values that take every way of
    ``_fragment_of`` (a double sent as an integer or an overflowing exponent, longs, strings
    with a quote, a backslash or a ``%``), so the run-wide typing of ``FoxgloveChannels._run``
    falls back row by row; runs where every value is a double as JSON writes it (its run-wide
    path); headings and speeds of 0, -0.0 and repeated values (the kept LocationFix tails)."""
    import random

    from sharedlink.protocols.codec import encode_named

    rng = random.Random(5)
    plain = {"AutoGpsLat": ["38.5", "38.25", "-0.5", "10.0", "0.0025"], "AutoGpsLon": ["-77.5", "-77.25", "0.5", "0.0", "-0.0"],
             "AutoGpsHead": ["57.0", "-0.0", "0.0", "359.5", "90.25"], "AutoGpsVel": ["0.0", "12.5", "3.25", "-0.0"]}
    odd = {"AutoGpsLat": ["38", "007.5", "1e999", "-0", "1e1"], "AutoGpsLon": ["-77", "-1e999", "2.5E-3"],
           "AutoGpsHead": ["57", "0", "1.", ".5"], "AutoGpsVel": ["0", "12", "+3.5"]}
    others = [("Count", 0, ["0", "7", "-3", "007", "1.5", "99999999999999999999"]),
              ("Mode", 4, ["on", 'say "hi"', "back\\slash", "100%", ""])]
    datagrams, ts = [], 1_700_000_000_000_000_000
    for block in range(12):
        mixed = block % 2 == 1
        for _ in range(120):
            values = [(n, 2, rng.choice(plain[n] + (odd[n] if mixed else []))) for n in plain if rng.random() < 0.8]
            if mixed:
                values += [(n, t, rng.choice(texts)) for n, t, texts in others if rng.random() < 0.5]
            ts += 100_000_000 + rng.choice([0, 1, 250_000])
            datagrams.append((ts, encode_named("A", "B", values or [("AutoGpsLat", 2, "38.5")])))
    cap = write_capture(tmp_path / "kinds.pcap", datagrams)
    assert _same_as_reference(tmp_path, cap) > 3 * 1000


@settings(max_examples=examples(400), deadline=None)
@given(st.lists(st.one_of(st.sampled_from(["38.34698779", "-77.0573", "0.0", "-0.0", "10.25", "0.5"]),
                          st.text("0123456789.-+eE_ ", max_size=7)), min_size=1, max_size=6))
def test_run_wide_doubles_take_only_what_the_row_by_row_typing_writes_as_sent(texts):
    """``_plain_decimals`` (the columns mode's run-wide typing of doubles) gives values only
    when every text is one ``_fragment_of`` writes as sent, and the same values; it takes a
    beacon's decimals."""
    from sharedlink.analysis.foxglove_channels import _fragment_of, _plain_decimals
    from sharedlink.protocols.codec import TYPE_DOUBLE

    got = _plain_decimals(texts)
    if got is not None:
        for t, x in zip(texts, got):
            assert _fragment_of("V", t, TYPE_DOUBLE) == (x, '"V": ' + t), t
            assert type(x) is float and json.loads(t) == x
    assert _plain_decimals(["38.34698779", "-77.05734791", "0.0", "-0.5", "57.0"]) is not None
    for bad in (["12"], ["1.2.3", "45"], ["007.5"], ["-.5"], ["1."], ["1e5"], ["+1.5"], ["1" * 400 + ".0"]):
        assert _plain_decimals(["38.5", *bad]) is None, bad
