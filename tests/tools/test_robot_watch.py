"""Issue 42: `sharedlink watch CAPTURE` of P2OS and blackboard links: `--json` writes every
packet as `export --format jsonl` does; the view shows each session's last SIP (pose in the
robot's frame, velocities, battery), its last command and packets per type."""

from __future__ import annotations

import json
import subprocess
import sys

from sl_cli import run_cli

from sharedlink.analysis.stats import capture_stats
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file

CLI = [sys.executable, "-m", "sharedlink"]


def watch(*args: str) -> subprocess.CompletedProcess:
    res = run_cli("watch", *args, timeout=120)
    assert res.returncode == 0, res.stderr
    return res


def test_json_lines_are_the_export_lines(tmp_path):
    path = tmp_path / "b.pcap"
    generate_blackboard_file(BlackboardGenOptions(duration=4, seed=8), path)
    lines = watch(str(path), "--speed", "1000", "--json").stdout.splitlines()
    out = tmp_path / "b.jsonl"
    run_cli("export", "-o", str(out), str(path), text=False, check=True, timeout=120)
    assert lines == out.read_text().splitlines()
    assert len(lines) == capture_stats(path).to_dict()["blackboard"]["packets"]


def test_view_shows_the_last_sip_and_command(tmp_path):
    path = tmp_path / "p.pcap"
    generate_p2os_file(P2osGenOptions(duration=5, seed=6), path)
    text = " ".join(watch(str(path), "--speed", "1000").stdout.split())
    st = capture_stats(path).to_dict()["p2os"]
    assert f"p2os session 1 (tcp 127.0.0.1:8101 - 127.0.0.1:45678): {st['packets']} packets, 0 bad checksums" in text
    out = tmp_path / "p.jsonl"
    run_cli("export", "-o", str(out), str(path), text=False, check=True, timeout=120)
    last = [json.loads(x) for x in out.read_text().splitlines() if '"type": "SIP"' in x][-1]
    assert f"x {last['x_mm']} mm, y {last['y_mm']} mm" in text and f"battery {last['battery_v']:.1f} V" in text
    assert "last command: CLOSE" in text and f"robot SIP {st['sip']['count']}" in text
