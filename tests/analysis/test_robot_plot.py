"""Issue 42: `sharedlink plot` of P2OS and blackboard captures: the odometry track, wheel
velocities and battery over time; a blackboard message timeline. The points drawn are the
decoded SIPs and messages (`stats` counts them), the PNG is written, exit 0."""

from __future__ import annotations

import json
import sys

import matplotlib

matplotlib.use("Agg")

from sl_cli import run_cli

from sharedlink.analysis.plot import collect  # noqa: E402
from sharedlink.analysis.robot_plot import build_robot_figure  # noqa: E402
from sharedlink.analysis.stats import capture_stats  # noqa: E402
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file  # noqa: E402
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file  # noqa: E402

CLI = [sys.executable, "-m", "sharedlink"]


def test_p2os_panels_hold_every_sip(tmp_path):
    path = tmp_path / "p.pcap"
    generate_p2os_file(P2osGenOptions(duration=8, seed=3), path)
    st = capture_stats(path).to_dict()["p2os"]
    data = collect(path)
    fig = build_robot_figure(data.robots, "p.pcap")
    track, _bar, vel, bat = fig.axes
    assert "robot frame" in track.get_title() and "robot odometry frame" in track.get_xlabel()
    xy = track.collections[0].get_offsets()
    assert len(xy) == st["sip"]["count"]
    assert xy[:, 0].min() == st["pose"]["x_min_mm"] and xy[:, 1].max() == st["pose"]["y_max_mm"]
    left, right = vel.lines
    assert len(left.get_ydata()) == len(right.get_ydata()) == st["sip"]["count"]
    means = [(a + b) / 2 for a, b in zip(left.get_ydata(), right.get_ydata())]
    assert max(means) == st["velocity_mm_s"]["max"] and min(means) == st["velocity_mm_s"]["min"]
    assert min(bat.lines[0].get_ydata()) == st["battery_v"]["min"] and bat.get_ylabel() == "battery (V)"
    out = tmp_path / "p.png"
    res = run_cli("plot", str(path), "-o", str(out), "--json", timeout=120)
    assert res.returncode == 0, res.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads(res.stdout)["packets"] == st["packets"] and "warning" not in res.stderr


def test_blackboard_timeline_holds_every_message(tmp_path):
    path = tmp_path / "b.pcap"
    generate_blackboard_file(BlackboardGenOptions(duration=6, seed=2), path)
    st = capture_stats(path).to_dict()["blackboard"]
    fig = build_robot_figure(collect(path).robots, "b.pcap")
    (ax,) = fig.axes
    assert sum(len(c.get_offsets()) for c in ax.collections) == st["packets"]
    assert [t.get_text() for t in ax.get_yticklabels()] == ["set", "ack", "request", "response"]
    out = tmp_path / "b.svg"
    res = run_cli("plot", str(path), "-o", str(out), timeout=120)
    assert res.returncode == 0 and out.read_text().lstrip().startswith("<?xml"), res.stderr
