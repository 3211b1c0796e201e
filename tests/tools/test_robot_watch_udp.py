"""Issue 42: `sharedlink watch --port N` of a live UDP link carrying blackboard: its messages reach
the watch's robot outputs (`--json`: export's jsonl lines) instead of being counted as SharedLink
noise. A generated blackboard session's master side (what reaches the post office's port, the one
the watch binds) replayed over real UDP on loopback to the watch's port."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys

from sl_cli import run_cli
from sl_pipes import read_lines

from sharedlink.capture.pcapio import PcapWriter, read_records
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
from sharedlink.replay import udp_fields

CLI = [sys.executable, "-m", "sharedlink"]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_live_udp_blackboard_reaches_the_robot_outputs(tmp_path):
    both = tmp_path / "b.pcap"
    generate_blackboard_file(BlackboardGenOptions(duration=3, seed=8), both)
    exported = tmp_path / "b.jsonl"
    run_cli("export", "-o", str(exported), str(both), text=False, check=True, timeout=120)
    want = [row for line in exported.read_text().splitlines() if (row := json.loads(line))["side"] == "master"]
    cap = tmp_path / "master.pcap"  # the datagrams to the post office's port (the master's)
    po = int(want[0]["link"].split(" - ")[0].rsplit(":", 1)[1])
    with open(cap, "wb") as fh:
        w = PcapWriter(fh)
        for rec in read_records(both):
            u = udp_fields(rec.linktype, rec.data)
            if u is not None and u[2] == po:
                fh.write(w.record(rec.ts_ns, rec.data))
    port = _free_port()
    w = subprocess.Popen([*CLI, "watch", "--port", str(port), "--bind-port", "--json"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        while "udp port" not in (line := w.stderr.readline()):  # type: ignore[union-attr]
            assert line, f"watch ended early: rc={w.poll()}"
        r = run_cli("replay", str(cap), "--to", f"127.0.0.1:{port}", "--pps", "2000", "-q", timeout=120)
        assert r.returncode == 0, r.stderr
        lines = read_lines(w.stdout.fileno(), len(want)).decode().splitlines()  # type: ignore[union-attr]
    finally:
        w.send_signal(signal.SIGINT)
        w.communicate(timeout=60)
    rows = [json.loads(line) for line in lines]
    assert len(rows) == len(want)
    assert {r["protocol"] for r in rows} == {"blackboard"}
    assert [r["type"] for r in rows] == [r["type"] for r in want]
    assert [(r.get("address"), r.get("data")) for r in rows] == [(r.get("address"), r.get("data")) for r in want]
