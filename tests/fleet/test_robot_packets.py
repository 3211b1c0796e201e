"""Issue 42: `sharedlink ingest` puts P2OS packets and blackboard messages in the `packets`
table; `sharedlink query` reads them (docs/fleet.md's examples) with the counts `stats --json`
gives (whose "packets" are tshark's: tests/analysis/test_robot_stats.py)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from sharedlink.analysis.stats import capture_stats
from sharedlink.fleet.query import run_query
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file

CLI = [sys.executable, "-m", "sharedlink"]
REPO = Path(__file__).resolve().parents[2]


def docs_queries() -> list[str]:
    """docs/fleet.md's packets examples (fenced SQL, upper case: test_ingest.py runs the sql ones)."""
    return re.findall(r"```SQL\n(.*?)```", (REPO / "docs" / "fleet.md").read_text(), re.S)


def test_packets_table_holds_what_stats_counts(tmp_path):
    p = tmp_path / "p.pcap"
    ps = tmp_path / "ps.pcapng"
    b = tmp_path / "b.pcap"
    generate_p2os_file(P2osGenOptions(duration=6, seed=3), p)
    generate_p2os_file(P2osGenOptions(duration=4, seed=4, transport="serial", fmt="pcapng"), ps)
    generate_blackboard_file(BlackboardGenOptions(duration=6, seed=5), b)
    ds = tmp_path / "ds"
    res = subprocess.run([*CLI, "ingest", "-o", str(ds), str(p), str(ps), str(b)], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert "P2OS/blackboard packets" in res.stderr
    for cap in (p, ps, b):
        st = capture_stats(cap).to_dict()
        proto = "blackboard" if cap == b else "p2os"
        rows = run_query(ds, f"SELECT count(*), count(*) FILTER (WHERE checksum_ok), min(link), max(link) "
                             f"FROM packets WHERE capture = '{cap}'").rows()
        n, good, lo, hi = next(iter(rows))
        assert n == good == st[proto]["packets"] and lo == hi == proto
        (listed,) = next(iter(run_query(ds, f"SELECT packets FROM captures WHERE path = '{cap}'").rows()))
        assert listed == n
        types = {(side, t): k for side, t, k in run_query(
            ds, f"SELECT side, type, count(*) FROM packets WHERE capture = '{cap}' GROUP BY ALL").rows()}
        key = "messages" if proto == "blackboard" else "packets"
        assert types == {(t["side"], t["type"]): t[key] for t in st[proto]["types"]}
    # docs/fleet.md: a robot's battery and odometry per capture; commands; sets never acknowledged
    battery, commands = docs_queries()
    by_cap = {r[0]: r for r in run_query(ds, battery).rows()}
    st = capture_stats(p).to_dict()["p2os"]
    r = by_cap[str(p)]
    assert r[1] == st["battery_v"]["min"] and r[3] == st["pose"]["x_max_mm"] - st["pose"]["x_min_mm"]
    assert abs(r[4] - st["velocity_mm_s"]["mean"]) < 1e-9
    per_command, unacked = [q for q in commands.split(";") if q.strip()]
    counts = {(c, n) for cap, c, n in run_query(ds, per_command).rows() if cap == str(p)}
    assert counts == {(c["name"], c["count"]) for c in st["commands"]}
    rows = dict(run_query(ds, unacked).rows())
    assert rows == {str(b): capture_stats(b).to_dict()["blackboard"]["repeated"]}
    out = subprocess.run([*CLI, "query", str(ds), "SELECT command, count(*) AS n FROM packets WHERE side = 'client' "
                          "GROUP BY ALL ORDER BY n DESC", "--format", "json"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    total: dict[str, int] = {}
    for cap in (p, ps):
        for c in capture_stats(cap).to_dict()["p2os"]["commands"]:
            total[c["name"]] = total.get(c["name"], 0) + c["count"]
    assert {r["command"]: r["n"] for r in json.loads(out.stdout)} == total
