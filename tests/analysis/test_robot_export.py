"""Issue 42: `sharedlink export` csv/jsonl of P2OS and blackboard captures: one row per packet
with a protocol column and the decoded fields (units in the column names), the same packets,
command names, positions and blackboard types in the same order as tshark shows them with
p2os.lua/blackboard.lua/serial.lua."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli
from sl_robots import OTHERS, SERIAL

import tshark_util as tu
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file

CLI = [sys.executable, "-m", "sharedlink"]


def export(path: Path, out: Path) -> str:
    res = run_cli("export", "-o", str(out), str(path), timeout=120)
    assert res.returncode == 0, res.stderr
    assert "warning" not in res.stderr
    return res.stderr


@pytest.mark.parametrize("transport", ["tcp", "serial"])
def test_p2os_csv_rows_are_tsharks_packets(tmp_path, transport):
    fmt = "pcapng" if transport == "serial" else "pcap"
    path = tmp_path / f"p.{fmt}"
    generate_p2os_file(P2osGenOptions(duration=6, transport=transport, fmt=fmt, seed=2), path)
    out = tmp_path / "p.csv"
    export(path, out)
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert {"protocol", "x_mm", "velocity_mm_s", "heading_deg", "battery_v"} <= set(rows[0])
    ts = tu.fields(path, ["p2os.header", "p2os.command.name", "p2os.sip.xpos", "p2os.sip.ypos", "p2os.sip.volts",
                          "p2os.checksum.status"], prefs=SERIAL if transport == "serial" else None, extra=OTHERS)
    assert len(rows) == sum(len(r["p2os.header"]) for r in ts)
    assert {r["protocol"] for r in rows} == {"p2os"} and {r["checksum"] for r in rows} == {"good"}
    assert [r["command"] for r in rows if r["command"]] == [n for r in ts for n in r["p2os.command.name"]]
    sips = [r for r in rows if r["type"] == "SIP"]
    assert [(int(r["x_mm"]), int(r["y_mm"])) for r in sips] == [
        (int(x), int(y)) for r in ts for x, y in zip(r["p2os.sip.xpos"], r["p2os.sip.ypos"])]
    assert [float(r["battery_v"]) for r in sips] == [float(v) for r in ts for v in r["p2os.sip.volts"]]


@pytest.mark.parametrize("transport", ["udp", "serial"])
def test_blackboard_jsonl_rows_are_tsharks_messages(tmp_path, transport):
    fmt = "pcapng" if transport == "serial" else "pcap"
    path = tmp_path / f"b.{fmt}"
    generate_blackboard_file(BlackboardGenOptions(duration=6, transport=transport, fmt=fmt, seed=6), path)
    out = tmp_path / "b.jsonl"
    assert "P2OS/blackboard packet" in export(path, out)
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    ts = tu.fields(path, ["blackboard.type"], prefs=SERIAL if transport == "serial" else None, extra=OTHERS)
    assert [r["type"] for r in rows] == [t for r in ts for t in r["blackboard.type"]]
    assert all(r["protocol"] == "blackboard" and r["checksum"] == "good" for r in rows)
    sets = [r for r in rows if r["type"] == "set"]
    assert sets and all(len(r["data"]) == 2 * r["count"] for r in sets)
    t = [r["ts_ns"] for r in rows]
    assert t == sorted(t) or transport == "serial"  # (serial: the record completing each, in record order)


def test_fast_jsonl_lines_equal_the_plain_ones(tmp_path):
    """RobotJsonl formats SIPs and ENCODER packets straight into text: the same text as the
    plain path (the row without empty columns through json.dumps), including stalled wheels,
    negative velocities and headings, no sonars and a bad checksum."""
    from sl_robots import write_tcp

    from sharedlink.analysis.decode import Decoder
    from sharedlink.analysis.robot_export import RobotJsonl
    from sharedlink.analysis.robots import RobotLinks
    from sharedlink.analysis.sessions import SessionMessage
    from sharedlink.protocols.p2os import Encoder, Sip, build_packet

    path = tmp_path / "p.pcap"
    generate_p2os_file(P2osGenOptions(duration=5, seed=9), path)
    odd = tmp_path / "odd.pcap"
    bad = bytearray(build_packet(Sip(True, 1, 65535, -2048, -300, 250, 99, 0x0101, 0, 0, 179).encode()))
    bad[-1] ^= 1
    write_tcp(odd, [(False, bytes(bad)), (False, build_packet(Encoder(-5, 2**31 - 1).encode())),
                     (False, build_packet(Sip(False, 7, 8, 5, 0, 0, 120, 0, 0, 1, 0, ((3, 0),)).encode()))], 8101)
    for cap in (path, odd):
        dec = Decoder(carried=False)
        dec.robots = RobotLinks(messages=True)
        msgs = [m for m in dec.capture(cap) if isinstance(m, SessionMessage)]
        fast, plain = RobotJsonl([], lambda: None), RobotJsonl([], lambda: None)
        taken = 0
        for m in msgs:
            f = fast.fast_line(m)
            taken += f is not None
            assert (f or fast.line(m)) == plain.line(m)
            json.loads(plain.line(m))
        assert taken >= len(msgs) // 2


def test_geojson_and_kml_odometry_track_in_the_robot_frame(tmp_path):
    """One LineString (GeoJSON) / Folder (KML) a P2OS session: every SIP's position in metres,
    the frame said (robot odometry, not longitude/latitude), as stats measures the track."""
    import xml.etree.ElementTree as ET

    from sharedlink.analysis.stats import capture_stats

    path = tmp_path / "p.pcap"
    generate_p2os_file(P2osGenOptions(duration=6, seed=5), path)
    st = capture_stats(path).to_dict()["p2os"]
    gj = tmp_path / "p.geojson"
    export(path, gj)
    (feature,) = json.loads(gj.read_text())["features"]
    coords = feature["geometry"]["coordinates"]
    assert feature["geometry"]["type"] == "LineString" and len(coords) == st["sip"]["count"]
    assert "robot odometry frame" in feature["properties"]["frame"] and "not longitude" in feature["properties"]["frame"]
    xs = [c[0] * 1000 for c in coords]
    assert min(xs) == st["pose"]["x_min_mm"] and max(xs) == st["pose"]["x_max_mm"]
    kml = tmp_path / "p.kml"
    export(path, kml)
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    doc = ET.parse(kml).getroot()
    (folder,) = doc.findall(".//k:Folder", ns)
    assert "robot odometry frame" in folder.find("k:description", ns).text
    points = folder.find(".//k:coordinates", ns).text.split()
    assert [p.split(",")[:2] for p in points] == [[repr(x), repr(y)] for x, y in coords]
