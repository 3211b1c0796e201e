"""Every export format's typed values, with and without ``--changes``: a long stays an exact
integer (past 2**53 too), a double a number, a string a string even when it reads as a number;
GeoJSON and KML put the typed latitude and longitude where a map tool reads them; MCAP's values
channel holds the typed values after every frame, its LocationFix the typed position (MCAP writes
every frame and variable: ``--changes`` is refused, a usage error).

The capture: a full frame (Lat 38.5, Lon -77.25, Count 2**53 + 1, Mode "0042"), a delta of Count
(-7), a full frame that moves Lat to 38.75 and Mode to "off".
"""

from __future__ import annotations

import csv
import io
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from sl_cli import run_cli

import tshark_util as tu

BIG = 2**53 + 1
FRAMES = [
    tu.frame("A", "B", "N0", "T2", "QAutoGpsLat", "D38.5", "T2", "QAutoGpsLon", "D-77.25", "T0", "QCount", f"D{BIG}",
             "T4", "QMode", "D0042"),
    tu.frame("A", "B", "N0", "T0", "QCount", "D-7"),
    tu.frame("A", "B", "N0", "T2", "QAutoGpsLat", "D38.75", "T2", "QAutoGpsLon", "D-77.25", "T0", "QCount", "D-7",
             "T4", "QMode", "Doff"),
]
#: the values after each frame, typed, and what each frame changed
AFTER = [{"AutoGpsLat": 38.5, "AutoGpsLon": -77.25, "Count": BIG, "Mode": "0042"},
         {"AutoGpsLat": 38.5, "AutoGpsLon": -77.25, "Count": -7, "Mode": "0042"},
         {"AutoGpsLat": 38.75, "AutoGpsLon": -77.25, "Count": -7, "Mode": "off"}]
CHANGED = [dict(AFTER[0]), {"Count": -7}, {"AutoGpsLat": 38.75, "Mode": "off"}]
TYPES = {"AutoGpsLat": 2, "AutoGpsLon": 2, "Count": 0, "Mode": 4}


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    t0 = 1_767_268_800.0
    return tu.write_pcap(tmp_path_factory.mktemp("typed") / "typed.pcap",
                         [tu.Pkt(t0 + 0.2 * i, p, src="10.0.0.2", dst="10.0.0.1") for i, p in enumerate(FRAMES)])


def export(capture: Path, fmt: str, changes: bool) -> str:
    return run_cli("export", capture, "--format", fmt, *(["--changes"] if changes else []), "-o", "-", check=True).stdout


def exact(values: dict) -> dict:
    """The values with their Python types, so that 1 and 1.0 and True differ."""
    return {k: (type(v).__name__, v) for k, v in values.items()}


def test_jsonl(capture: Path) -> None:
    rows = [json.loads(x) for x in export(capture, "jsonl", False).splitlines()]
    assert [exact(r["values"]) for r in rows] == [exact(v) for v in AFTER]
    assert [set(r["changed"]) for r in rows] == [set(c) for c in CHANGED]


def test_jsonl_changes(capture: Path) -> None:
    rows = [json.loads(x) for x in export(capture, "jsonl", True).splitlines()]
    want = [(i + 1, n, TYPES[n], (type(v).__name__, v)) for i, c in enumerate(CHANGED) for n, v in c.items()]
    assert [(r["number"], r["name"], r["type"], (type(r["value"]).__name__, r["value"])) for r in rows] == want


def test_csv(capture: Path) -> None:
    rows = list(csv.DictReader(io.StringIO(export(capture, "csv", False))))
    assert [{k: r[k] for k in TYPES} for r in rows] == [{k: str(v) for k, v in a.items()} for a in AFTER]


def test_csv_changes(capture: Path) -> None:
    rows = list(csv.DictReader(io.StringIO(export(capture, "csv", True))))
    want = [(str(i + 1), n, str(TYPES[n]), str(v)) for i, c in enumerate(CHANGED) for n, v in c.items()]
    assert [(r["number"], r["name"], r["type"], r["value"]) for r in rows] == want


@pytest.mark.parametrize("changes", [False, True], ids=["frames", "changes"])
def test_geojson(capture: Path, changes: bool) -> None:
    features = json.loads(export(capture, "geojson", changes))["features"]
    points = [f for f in features if f["geometry"]["type"] == "Point"]
    key, want = ("changes", CHANGED) if changes else ("values", AFTER)
    assert [exact(f["properties"][key]) for f in points] == [exact(v) for v in want]
    assert [f["geometry"]["coordinates"] for f in points] == [[a["AutoGpsLon"], a["AutoGpsLat"]] for a in AFTER]
    track = [f for f in features if f["geometry"]["type"] == "LineString"]
    assert len(track) == 1 and track[0]["geometry"]["coordinates"][0] == [-77.25, 38.5]
    assert track[0]["geometry"]["coordinates"][-1] == [-77.25, 38.75]


@pytest.mark.parametrize("changes", [False, True], ids=["frames", "changes"])
def test_kml(capture: Path, changes: bool) -> None:
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    root = ET.fromstring(export(capture, "kml", changes))
    marks = {m.findtext("k:name", namespaces=ns): m for m in root.iterfind(".//k:Placemark", ns)}

    def coords(text: str | None) -> list[tuple[float, float, float]]:
        return [tuple(float(x) for x in c.split(",")) for c in (text or "").split()]

    line = coords(marks["track B>A"].findtext(".//k:LineString/k:coordinates", namespaces=ns))
    assert line[0] == (-77.25, 38.5, 0.0) and line[-1] == (-77.25, 38.75, 0.0)
    assert coords(marks["start"].findtext(".//k:coordinates", namespaces=ns)) == [(-77.25, 38.5, 0.0)]
    assert coords(marks["end"].findtext(".//k:coordinates", namespaces=ns)) == [(-77.25, 38.75, 0.0)]


def test_mcap(capture: Path, tmp_path: Path) -> None:
    pytest.importorskip("mcap.reader")
    pytest.importorskip("google.protobuf")
    from sl_checks import Mcap

    out = tmp_path / "typed.mcap"
    run_cli("export", capture, "-o", out, "-q", check=True)
    msgs = Mcap(out).msgs
    assert [exact(v) for _t, v in msgs["/sharedlink/B_to_A/values"]] == [exact(v) for v in AFTER]
    assert [set(f["changed"]) for _t, f in msgs["/sharedlink/B_to_A/frames"]] == [set(c) for c in CHANGED]
    assert [(fix.latitude, fix.longitude) for _t, fix in msgs["/sharedlink/B_to_A/location"]] == [
        (a["AutoGpsLat"], a["AutoGpsLon"]) for a in AFTER]


def test_mcap_changes_is_a_usage_error(capture: Path, tmp_path: Path) -> None:
    out = tmp_path / "typed.mcap"
    r = run_cli("export", capture, "-o", out, "--changes")
    assert r.returncode == 2 and "--changes" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not out.exists()
