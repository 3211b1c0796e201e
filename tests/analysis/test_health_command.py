"""`sharedlink health` (issue 43): the per-second link quality as a table, CSV, JSONL and a PNG
strip, agreeing with `stats` on the links and outages of the same capture."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from sl_cli import run_cli


@pytest.fixture(scope="module")
def cap(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("health") / "planted.pcap"
    r = run_cli("gen", "-o", p, "--duration", 40, "--rate", 6.5, "--compress", "--outage", "10:3", "--outage", "30:4")
    assert r.returncode == 0, r.stderr
    return p


def test_json_is_stats(cap):
    h = json.loads(run_cli("health", cap, "--json").stdout)
    s = json.loads(run_cli("stats", cap, "--json").stdout)
    assert h["outages"] == s["outages"] and len(h["outages"]) == 2
    assert h["links"] == s["links"]


def test_rows(cap, tmp_path):
    r = run_cli("health", cap, "-o", tmp_path / "q.csv")
    assert r.returncode == 0 and "2 outages" in r.stderr, r.stderr
    rows = list(csv.DictReader(open(tmp_path / "q.csv")))
    assert len(rows) == 40  # seconds 0 .. 39 (the last frame at 39.85 s)
    down = [(int(x["second"]) % 60, float(x["down_s"])) for x in rows if x["state"] == "down"]
    # at 6.5 Hz the frames before the silences are at 9.8462 s and 29.8462 s
    assert [s for s, _ in down] == [10, 11, 12, 30, 31, 32, 33]
    assert down[0][1] == pytest.approx(11 - 9.846154, abs=1e-3)
    up = [int(x["frames"]) for x in rows if x["state"] == "up"]
    assert all(f in (6, 7) for f in up[1:-1] if f) and sum(up) == int(json.loads(
        run_cli("stats", cap, "--json").stdout)["frames"])
    assert all(x["quality"] == x["frames"] for x in rows if x["state"] == "up")
    r = run_cli("health", cap, "-o", "-")
    lines = [json.loads(x) for x in r.stdout.splitlines()]
    assert [(x["second"], x["frames"], x["down_s"]) for x in lines] == [
        (int(x["second"]), int(x["frames"]), float(x["down_s"]) if x["down_s"] else None) for x in rows]


def test_terminal_table_and_plot(cap, tmp_path):
    r = run_cli("health", cap)
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("DOWN") == 7 and "DOWN 3.2 s" in r.stdout
    assert "Link health" in r.stdout and "Outages" in r.stdout
    r = run_cli("health", cap, "--plot", tmp_path / "q.png")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "q.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("args, message", [
    (["-o", "{tmp}/q.txt"], ".csv or .jsonl"),
    (["--plot", "{tmp}/q.gif"], ".png"),
    (["--outage-after", "0"], "--outage-after"),
    (["--outage-after=-3"], "--outage-after"),
])
def test_bad_values(cap, tmp_path, args, message):
    r = run_cli("health", cap, *(a.format(tmp=tmp_path) for a in args))
    assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr


def test_missing_capture(tmp_path):
    r = run_cli("health", tmp_path / "none.pcap")
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_plot_breaks_lines_at_outages(cap):
    """plot: no line across an outage (a NaN point inside it), and the link-quality strip."""
    import math

    from sharedlink.analysis.plot import QUALITY_LABEL, TimeAxis, broken, build_figure, collect
    from sharedlink.capture.pcapio import NS

    data = collect(cap)
    outs = data.health.outages()
    assert len(outs) == 2
    fig = build_figure(data, ["AutoGpsLat"], elapsed=True)  # (x: seconds since the first frame)
    assert [ax.get_label() for ax in fig.axes].count(QUALITY_LABEL) == 1
    (line,) = [ax for ax in fig.axes if ax.get_ylabel().split("\n")[0] == "AutoGpsLat"][0].get_lines()
    xs, ys = line.get_xdata(), line.get_ydata()
    for o in outs:
        a, b = TimeAxis.of(data, True).x(((o.start_ns - data.t0_ns) / NS, (o.start_ns + o.duration_ns - data.t0_ns) / NS))
        inside = [y for x, y in zip(xs, ys) if a < x < b]
        assert inside and all(math.isnan(y) for y in inside)
    ts, vs = broken([0.0, 1.0, 5.0], [1.0, 2.0, 3.0], [(1.0, 5.0)])
    assert ts == [0.0, 1.0, 3.0, 5.0] and vs[:2] == [1.0, 2.0] and math.isnan(vs[2]) and vs[3] == 3.0
