"""Issue 42: `sharedlink diff` of two P2OS / blackboard captures compares them packet by packet
on the decoded fields: a run and its replay (other ports, another start time) agree; a changed
SIP position, a dropped packet and a bad checksum are found, exit 1."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from sl_cli import run_cli

from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.protocols.p2os import Encoder, Sip, build_packet

CLI = [sys.executable, "-m", "sharedlink"]


def _session(path: Path, events: list[tuple[bool, bytes]], client_port: int, start: int) -> Path:
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        evs = [(start + i * 50_000_000, c, p) for i, (c, p) in enumerate(events)]
        for ts, _, frame in session_frames(evs, "tcp", ("127.0.0.1", client_port), ("127.0.0.1", 8101)):
            w.write(ts, frame)
    return path


def _events(x_at_5: int = 1005, drop: bool = False, bad: bool = False) -> list[tuple[bool, bytes]]:
    out = [(True, bytes.fromhex("FAFB060B3B64006F3B"))]
    for i in range(20):
        out.append((False, build_packet(Sip(True, x_at_5 if i == 5 else 1000 + i, 2000, i, 100, 110, 120).encode())))
        out.append((False, build_packet(Encoder(i * 10, i * 11).encode())))
    if drop:
        del out[7]
    if bad:
        b = bytearray(out[3][1])
        b[-1] ^= 1
        out[3] = (False, bytes(b))
    return out


def diff(a: Path, b: Path) -> tuple[int, dict]:
    res = run_cli("diff", "--json", str(a), str(b), timeout=120)
    assert res.returncode in (0, 1), res.stderr
    return res.returncode, json.loads(res.stdout)


def test_a_replay_agrees_and_changes_are_found(tmp_path):
    run = _session(tmp_path / "run.pcap", _events(), 40000, 10**18)
    replay = _session(tmp_path / "replay.pcap", _events(), 41234, 10**18 + 3600 * 10**9)
    rc, rep = diff(run, replay)
    assert rc == 0 and rep["agree"] and rep["pairs"] == rep["identical"] == 41 and rep["max_shift_s"] == 0
    rc, rep = diff(run, _session(tmp_path / "moved.pcap", _events(x_at_5=999), 40000, 10**18))
    assert rc == 1 and rep["differing"] == 1 and rep["fields"] == {"x_mm": 1}
    (d,) = rep["differences"]
    assert d["type"] == "SIP" and d["fields"] == {"x_mm": [1005, 999]}
    rc, rep = diff(run, _session(tmp_path / "bad.pcap", _events(bad=True), 40000, 10**18))
    assert rc == 1 and rep["fields"] == {"checksum": 1}
    rc, rep = diff(run, _session(tmp_path / "drop.pcap", _events(drop=True), 40000, 10**18))
    assert rc == 1 and rep["unmatched_a"] == 1 and rep["packets_b"] == 40
    res = run_cli("diff", str(run), str(replay), timeout=120)
    assert res.returncode == 0 and "AGREE" in res.stdout and "warning" not in res.stderr
