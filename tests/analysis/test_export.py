"""`sharedlink export`: csv, jsonl, GeoJSON and KML parse back with the capture's values.

The values are checked against ``reference``, an independent reading of the capture written
here (raw pcap records, a regular expression per frame, its own carrying of values), not
against the package's decoder.
"""

from __future__ import annotations

import csv
import json
import tracemalloc
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from sl_captures import BEACON, captures, reference, write_capture
from sl_cli import run_cli

from sharedlink.analysis.export import ExportOptions, export_file
from sharedlink.generators.beacon import GenOptions, generate_file

VARIANTS = {
    "named": dict(),
    "named-compressed": dict(compress=True, drop=0.05, bad_checksum=0.05),
    "positional": dict(form="positional", bad_checksum=0.05),
    "positional-compressed": dict(form="positional", compress=True, drop=0.05),
}


@pytest.fixture(scope="module", params=sorted(VARIANTS))
def capture(request, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("export") / f"{request.param}.pcap"
    generate_file(GenOptions(duration=40, seed=5, **VARIANTS[request.param]), path)
    return path


def test_csv_rows_match_the_capture(capture, tmp_path):
    out = tmp_path / "x.csv"
    r = run_cli("export", capture, "-o", out)
    assert r.returncode == 0, r.stderr
    ref = reference(capture)
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(ref) > 100
    assert list(rows[0])[:8] == ["number", "time", "ts_ns", "t", "src", "dst", "kind", "checksum"]
    assert set(BEACON) <= set(rows[0])
    for row, fr in zip(rows, ref):
        assert int(row["number"]) == fr.number
        assert int(row["ts_ns"]) == fr.ts_ns
        assert row["time"].startswith("2026-01-01T12:") and row["time"].endswith("Z")
        assert (row["src"], row["dst"]) == (fr.src, fr.dst)
        assert row["checksum"] == ("good" if fr.ok else "bad")
        for name in BEACON:
            assert row[name] == fr.values.get(name, ""), (fr.number, name)
    assert float(rows[-1]["t"]) == pytest.approx((ref[-1].ts_ns - ref[0].ts_ns) / 1e9)


def test_jsonl_frames_and_changes_are_typed(capture, tmp_path):
    ref = reference(capture)
    out = tmp_path / "x.jsonl"
    assert run_cli("export", capture, "-o", out).returncode == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == len(ref)
    for row, fr in zip(rows, ref):
        assert row["number"] == fr.number and row["ts_ns"] == fr.ts_ns
        assert row["values"] == {k: float(v) for k, v in fr.values.items()}
        assert sorted(row["changed"]) == sorted(fr.changed)
    # --changes: one row per variable change, in frame order
    out2 = tmp_path / "c.jsonl"
    assert run_cli("export", capture, "--changes", "--format", "jsonl", "-o", out2).returncode == 0
    changes = [json.loads(line) for line in out2.read_text().splitlines()]
    want = [(fr.number, k, float(v)) for fr in ref for k, v in fr.changed.items()]
    assert sorted((c["number"], c["name"], c["value"]) for c in changes) == sorted(want)
    assert all(isinstance(c["value"], float) and c["type"] == 2 for c in changes)


def test_geojson_is_a_feature_collection_with_the_track(capture, tmp_path):
    ref = [fr for fr in reference(capture) if fr.ok and "AutoGpsLat" in fr.values]
    out = tmp_path / "x.geojson"
    assert run_cli("export", capture, "-o", out).returncode == 0
    doc = json.loads(out.read_text())
    assert doc["type"] == "FeatureCollection"
    points = [f for f in doc["features"] if f["geometry"]["type"] == "Point"]
    lines = [f for f in doc["features"] if f["geometry"]["type"] == "LineString"]
    for f in doc["features"]:
        assert f["type"] == "Feature" and isinstance(f["properties"], dict)
        coords = f["geometry"]["coordinates"]
        for lon, lat in [coords] if f["geometry"]["type"] == "Point" else coords:
            assert -180 <= lon <= 180 and -90 <= lat <= 90
    want = [[float(fr.values["AutoGpsLon"]), float(fr.values["AutoGpsLat"])] for fr in ref]
    assert [p["geometry"]["coordinates"] for p in points] == want
    assert [p["properties"]["number"] for p in points] == [fr.number for fr in ref]
    assert len(lines) == 1 and lines[0]["geometry"]["coordinates"] == want
    assert lines[0]["properties"]["track"] == "B>A"


def test_kml_is_xml_with_the_track(capture, tmp_path):
    ref = [fr for fr in reference(capture) if fr.ok and "AutoGpsLat" in fr.values]
    out = tmp_path / "x.kml"
    assert run_cli("export", capture, "-o", out).returncode == 0
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = ET.parse(out).getroot()
    assert root.tag == "{http://www.opengis.net/kml/2.2}kml"
    line = root.find(".//k:LineString/k:coordinates", ns)
    coords = [tuple(map(float, c.split(","))) for c in line.text.split()]
    assert coords == [(float(fr.values["AutoGpsLon"]), float(fr.values["AutoGpsLat"]), 0.0) for fr in ref]
    names = [p.findtext("k:name", namespaces=ns) for p in root.iter("{http://www.opengis.net/kml/2.2}Placemark")]
    assert names == ["track B>A", "start", "end"]
    assert root.find(".//k:TimeSpan/k:begin", ns).text.startswith("2026-01-01T12:00:00")


def test_csv_changes_and_vars(tmp_path):
    cap = tmp_path / "c.pcap"
    generate_file(GenOptions(duration=20, compress=True, seed=2), cap)
    ref = reference(cap)
    out = tmp_path / "c.csv"
    r = run_cli("export", cap, "--changes", "--vars", "AutoGpsVel", "-o", out)
    assert r.returncode == 0, r.stderr
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(int(r["number"]), r["value"]) for r in rows] == [
        (fr.number, fr.changed["AutoGpsVel"]) for fr in ref if "AutoGpsVel" in fr.changed
    ]
    assert {r["name"] for r in rows} == {"AutoGpsVel"}
    # --vars limits the value columns of a frame export
    r = run_cli("export", cap, "--vars", "AutoGpsLat,AutoGpsVel")
    assert r.returncode == 0
    assert r.stdout.splitlines()[0] == "number,time,ts_ns,t,src,dst,kind,checksum,AutoGpsLat,AutoGpsVel"


def test_bad_input_exit_codes(tmp_path):
    r = run_cli("export", tmp_path / "missing.pcap")
    assert r.returncode == 2 and "no such file" in r.stderr and "Traceback" not in r.stderr
    junk = tmp_path / "junk.pcap"
    junk.write_bytes(b"not a capture at all" * 3)
    r = run_cli("export", junk, "-o", tmp_path / "j.csv")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert not (tmp_path / "j.csv").exists()
    # damaged in the middle: the frames before the damage are exported, the document is closed
    cap = tmp_path / "d.pcap"
    generate_file(GenOptions(duration=20, seed=2), cap)
    data = cap.read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[: len(data) // 2 + 7])
    for fmt in ("geojson", "kml", "csv"):
        out = tmp_path / f"cut.{fmt}"
        r = run_cli("export", cut, "-o", out)
        assert r.returncode == 2, r.stderr
        assert "error" in r.stderr and "Traceback" not in r.stderr
        text = out.read_text()
        if fmt == "geojson":
            assert len(json.loads(text)["features"]) > 40
        elif fmt == "kml":
            ET.fromstring(text)
        else:
            assert len(text.splitlines()) > 40


def test_export_streams(tmp_path):
    """Memory does not grow with the capture: 10x the frames, about the same peak."""
    small, big = tmp_path / "s.pcap", tmp_path / "b.pcap"
    generate_file(GenOptions(frames=500, compress=True, seed=3), small)
    generate_file(GenOptions(frames=5000, compress=True, seed=3), big)
    peaks = {}
    for fmt in ("csv", "geojson"):
        for p in (small, big):
            tracemalloc.start()
            export_file(p, tmp_path / f"o.{fmt}", ExportOptions(fmt=fmt))
            peaks[(fmt, p)] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        assert peaks[(fmt, big)] < 1.5 * peaks[(fmt, small)] + 200_000, peaks


@pytest.mark.parametrize("type_code", [None, 0, 2, 4, 7])
def test_jsonl_value_is_json_dumps_of_the_typed_value(type_code):
    """jsonl's value member (_value_json: int()/float() straight, the forms they take beyond the
    protocol's ruled out) is exactly json.dumps of the reference's typed value (Variable.value,
    text when not finite) for texts of every kind."""
    from sharedlink.analysis.export import _typed, _value_json
    from sharedlink.protocols.state import Variable

    texts = ["7", "-0", "0", "12345678901234567890", "1.5", "-0.25", "1e5", "1E-3", "1e999", "-1e999", "007", "1.",
             ".5", "+3", "abc", "", "0x10", "1_000", "NaN", " 1", "2.50", "inf", "-Infinity", "1" * 5000, "\u0663",
             "1e5\n", "+", "-", ".", "e5", "1e", "0b1", "1.5e+3", "\u00e9", '"q"']
    for t in texts:
        v = Variable("x", type_code, t)
        assert _value_json(v) == json.dumps(_typed(v)), t


def _two_pass_csv(path: Path) -> str:
    """The CSV export by its definition: a first pass learns every name given a value (in order
    of first appearance), the second writes each frame's row with every column: the direction's
    values after the frame, a reply's the values it carries alone (issue 40)."""
    import io

    from sharedlink.analysis.decode import Decoded, format_time, iter_decoded

    names: dict[str, None] = {}
    for d in iter_decoded(path, carried=False):
        if isinstance(d, Decoded):
            names.update((u.name, None) for u in d.updates if u.text is not None)
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["number", "time", "ts_ns", "t", "src", "dst", "kind", "checksum", *names])
    t0 = None
    for d in iter_decoded(path, carried=False):
        if not isinstance(d, Decoded):
            continue
        t0 = d.ts_ns if t0 is None else t0
        ok = "none" if d.checksum_ok is None else ("good" if d.checksum_ok else "bad")
        held = {u.name: u for u in d.updates if u.text is not None} if d.kind == "reply" else d.table.vars
        vals = [getattr(held.get(n), "text", None) for n in names]
        w.writerow([d.number, format_time(d.ts_ns), d.ts_ns, round((d.ts_ns - t0) / 1e9, 9), d.src, d.dst, d.kind, ok,
                    *["" if v is None else v for v in vals]])
    return out.getvalue()


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(captures(max_frames=25))
def test_one_pass_csv_equals_the_two_pass_definition(tmp_path_factory, datagrams):
    """csv without --select reads the capture once (rows spooled while the columns are learnt,
    the rows before a late column padded): the same text as learning the columns first, on
    streams whose names appear late, in declarations, replies, bad frames, two directions."""
    path = write_capture(tmp_path_factory.mktemp("csv") / "c.pcap", datagrams)
    out = tmp_path_factory.mktemp("csvout") / "c.csv"
    export_file(path, out, ExportOptions(fmt="csv"))
    assert out.read_text(encoding="utf-8") == _two_pass_csv(path)


def test_change_rows_of_a_reply_take_its_own_values(tmp_path):
    """Issue 29: a reply's values are never stored in its direction's table, so its change rows
    come from the frame itself (the CSV writer read the table and failed on a reply's name)."""
    from sl_vectors import load_streams, write_stream

    stream = {s["name"]: s for s in load_streams()}["real-reply-from-the-vehicle-source-port"]
    cap = write_stream(stream, tmp_path / "r.pcap")
    rows = {}
    for fmt in ("csv", "jsonl"):
        out = tmp_path / f"r.{fmt}"
        r = run_cli("export", cap, "--changes", "-o", out)
        assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
        text = out.read_text()
        got = list(csv.DictReader(text.splitlines())) if fmt == "csv" else [json.loads(x) for x in text.splitlines()]
        rows[fmt] = [(int(x["number"]), x["name"], x["value"]) for x in got]
    want = [(4, "AutoGpsVel", "0"), (6, "VehicleName", "VEH_Other"), (7, "VehicleName", "VEH_NorthEastern1")]
    assert rows["csv"][-3:] == want
    # typed in JSON: AutoGpsVel by the default list's double, the rest untyped
    assert rows["jsonl"][-3:] == [(4, "AutoGpsVel", 0.0), *want[1:]]
    assert rows["csv"][0] == (2, "video_mux1", "0") and len(rows["csv"]) == 13
