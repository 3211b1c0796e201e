"""Issue 42: `sharedlink stats` on P2OS and blackboard captures: a section per protocol, `--json`
keys "p2os" and "blackboard" whose "packets" are tshark's counts (p2os.lua, blackboard.lua,
serial.lua), the rest against the generators' own counts and hand-made SIP sequences."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli
from sl_robots import tshark_counts, write_tcp

from sharedlink.analysis.stats import capture_stats, render_text
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file
from sharedlink.protocols.p2os import Sip, build_packet

CLI = [sys.executable, "-m", "sharedlink"]


def stats_json(path: Path) -> dict:
    res = run_cli("stats", "--json", str(path), timeout=120)
    assert res.returncode == 0, res.stderr
    assert "no SharedLink frames" not in res.stderr
    return json.loads(res.stdout)


@pytest.mark.parametrize("transport", ["tcp", "serial"])
def test_p2os_section_counts_as_tshark_and_the_generator(tmp_path, transport):
    fmt = "pcapng" if transport == "serial" else "pcap"
    path = tmp_path / f"p.{fmt}"
    gen = generate_p2os_file(P2osGenOptions(duration=10, transport=transport, fmt=fmt, seed=4), path)
    doc = stats_json(path)
    assert "blackboard" not in doc
    p = doc["p2os"]
    p2, _ = tshark_counts(path, serial=transport == "serial")
    assert p["packets"] == sum(p2.values()) == gen.packets
    assert p["checksum_failures"] == sum(n for (_, ok), n in p2.items() if not ok) == 0
    assert p["sip"]["count"] == gen.kinds["SIP"]
    # (serial: timed by the record completing each)
    assert abs(p["sip"]["rate_hz"] - 10.0) < 0.05 and p["sip"]["gaps"] == 0
    commands = {c["name"]: c for c in p["commands"]}
    for name in ("VEL", "RVEL", "PULSE", "SYNC0", "SYNC2", "CLOSE"):
        assert commands[name]["count"] == gen.kinds[name], name
    assert commands["ENCODER"]["responses"] == gen.kinds["ENCODER"] - 1  # (the command counts itself once)
    assert commands["SYNC2"]["response"] == "SYNC2 echo" and commands["SYNC2"]["responses"] == 1
    assert 0 < p["pose"]["x_min_mm"] < p["pose"]["x_max_mm"] < 10_000 and p["pose"]["distance_mm"] > 0
    assert p["velocity_mm_s"]["max"] > 0 and 10 < p["battery_v"]["min"] < 14


@pytest.mark.parametrize("transport", ["udp", "serial"])
def test_blackboard_section_counts_as_tshark_and_the_generator(tmp_path, transport):
    fmt = "pcapng" if transport == "serial" else "pcap"
    path = tmp_path / f"b.{fmt}"
    gen = generate_blackboard_file(BlackboardGenOptions(duration=10, transport=transport, fmt=fmt, seed=5), path)
    doc = stats_json(path)
    assert "p2os" not in doc
    b = doc["blackboard"]
    _, bb = tshark_counts(path, serial=transport == "serial")
    assert b["packets"] == sum(bb.values()) == gen.messages
    types = {(t["side"], t["type"]): t["messages"] for t in b["types"]}
    assert types[("slave", "ack")] == bb["ack"] == gen.kinds["ack"] == b["acknowledged"]
    assert types[("master", "request")] == bb["request"] == gen.kinds["request"]
    assert b["repeated"] == gen.kinds.get("set (repeat)", 0) > 0
    assert b["unanswered"] >= b["repeated"]
    assert 0 < b["answer_ms"]["min"] <= b["answer_ms"]["mean"] <= b["answer_ms"]["max"]


def test_sip_gaps_distance_wrap_flags_and_a_bad_checksum(tmp_path):
    """Hand-made SIPs 10 ms apart moving 10 mm along x across the 16-bit wrap (no gap),
    a stalled left wheel in 3, motors off in 2, one SIP with a bad checksum."""
    events = []
    x = 65_500
    for i in range(40):
        sip = Sip(True, x % 65536, 1000, 0, 100, 100, 121 - i // 20, 1 if i < 3 else 0, 0, 0 if i >= 38 else 1)
        events.append((False, build_packet(sip.encode())))
        x += 10
    bad = bytearray(events[5][1])
    bad[-1] ^= 0xFF
    events[5] = (False, bytes(bad))
    path = tmp_path / "sips.pcap"
    write_tcp(path, events, 8101)
    st = capture_stats(path)
    p = st.to_dict()["p2os"]
    assert p["packets"] == 40 and p["checksum_failures"] == 1
    assert p["sip"]["gaps"] == 0 and p["pose"]["distance_mm"] == 390.0
    assert p["pose"]["x_min_mm"] == 65_500 and p["pose"]["x_max_mm"] == 65_890  # unwrapped
    assert p["flags"]["stall_left"] == 3 and p["flags"]["motors_enabled"] == 38
    assert p["battery_v"]["first"] == 12.1 and p["battery_v"]["last"] == 12.0
    text = render_text(st)
    assert "P2OS statistics" in text and "Variables" not in text  # no empty SharedLink tables


def test_sip_gap_counted(tmp_path):
    sip = build_packet(Sip(False, 1, 2, 0, 0, 0, 120).encode())
    times = [i * 100_000_000 for i in range(10)] + [3_000_000_000 + i * 100_000_000 for i in range(10)]
    path = tmp_path / "gap.pcap"
    write_tcp(path, [(False, sip)] * len(times), 8101, times)
    sip_stats = capture_stats(path).to_dict()["p2os"]["sip"]
    assert sip_stats["gaps"] == 1 and abs(sip_stats["max_gap_s"] - 2.1) < 1e-9


def test_answer_times_are_those_of_the_answers_timed():
    """bb-edge.pcap has answers to no waiting message (counted as answered, with no time): the
    mean answer time is over the answers timed, so it lies between their min and max (it was the
    sum over every answer, 8.33 ms under a 10 ms minimum)."""
    edge = Path(__file__).resolve().parents[1] / "dissector" / "golden_small" / "bb-edge.pcap"
    b = stats_json(edge)["blackboard"]
    t = b["answer_ms"]
    assert b["answered"] == 6
    assert t["min"] <= t["mean"] <= t["max"] and t == {"min": 10.0, "mean": 10.0, "max": 10.0}
