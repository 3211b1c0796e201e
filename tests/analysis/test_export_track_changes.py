"""export --changes to GeoJSON and KML (a bug noticed in issue 42's session: KML with --changes
dropped the points whose position had not changed, GeoJSON kept those of frames with any change):
the track keeps every point in both formats, with and without --changes, SharedLink GPS tracks
and P2OS odometry tracks alike; GeoJSON's point features with --changes are the frames with
changes (their "changes")."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from sl_cli import run_cli

from sharedlink.analysis.decode import Decoded, iter_decoded


def run(*args: object) -> str:
    return run_cli(*args, check=True).stdout


def geojson_tracks(text: str) -> dict[str, list[tuple[float, float]]]:
    d = json.loads(text)
    return {f["properties"]["track"]: [tuple(c) for c in f["geometry"]["coordinates"]] for f in d["features"]
            if f["geometry"]["type"] == "LineString"}


def kml_tracks(text: str) -> dict[str, list[tuple[float, float]]]:
    out = {}
    for name, coords in re.findall(r"<Placemark><name>(?:track|odometry track) ([^<]+)</name>.*?<coordinates>\n(.*?)"
                                   r"</coordinates>", text, re.S):
        out[name] = [tuple(map(float, line.split(",")[:2])) for line in coords.splitlines()]
    return out


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("track") / "c.pcap"
    run("gen", "-o", p, "--duration", "30", "--compress", "--seed", "5")
    return p


def test_the_track_keeps_every_point(capture):
    frames = [d for d in iter_decoded(capture) if isinstance(d, Decoded)]
    plain_g = geojson_tracks(run("export", capture, "--format", "geojson", "-o", "-"))
    plain_k = kml_tracks(run("export", capture, "--format", "kml", "-o", "-"))
    changes_text = run("export", capture, "--format", "geojson", "--changes", "-o", "-")
    changes_g = geojson_tracks(changes_text)
    changes_k = kml_tracks(run("export", capture, "--format", "kml", "--changes", "-o", "-"))
    assert list(plain_g) == ["B>A"] and set(plain_k) == {"B&gt;A"}
    points = plain_g["B>A"]
    assert len(points) == len(frames)  # (a generated beacon: every frame has a position)
    unchanged = [d for d in frames if not any(u.name in ("AutoGpsLat", "AutoGpsLon") for u in d.changes())]
    assert unchanged, "the capture has frames whose position did not change"
    assert changes_g["B>A"] == points == plain_k["B&gt;A"] == changes_k["B&gt;A"]
    features = [f for f in json.loads(changes_text)["features"] if f["geometry"]["type"] == "Point"]
    assert len(features) == sum(1 for d in frames if list(d.changes()))
    assert all(f["properties"]["changes"] for f in features)


def test_p2os_odometry_track_with_changes(tmp_path):
    cap = tmp_path / "p.pcap"
    run("gen", "-o", cap, "--protocol", "p2os", "--duration", "5")
    g = geojson_tracks(run("export", cap, "--format", "geojson", "-o", "-"))
    k = kml_tracks(run("export", cap, "--format", "kml", "-o", "-"))
    assert list(g) == ["p2os session 1"] and len(g["p2os session 1"]) > 40
    assert geojson_tracks(run("export", cap, "--format", "geojson", "--changes", "-o", "-")) == g
    assert kml_tracks(run("export", cap, "--format", "kml", "--changes", "-o", "-")) == k == {"1": g["p2os session 1"]}
