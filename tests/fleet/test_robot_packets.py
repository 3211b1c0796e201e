"""Issue 42: `sharedlink ingest` puts P2OS packets and blackboard messages in the `packets`
table; `sharedlink query` reads them (docs/fleet.md's examples) with the counts `stats --json`
gives (whose "packets" are tshark's: tests/analysis/test_robot_stats.py)."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from sl_cli import run_cli

from sharedlink.analysis.stats import capture_stats
from sharedlink.fleet.dataset import load_manifest, old_links, save_manifest
from sharedlink.fleet.ingest import ingest
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
    res = run_cli("ingest", "-o", str(ds), str(p), str(ps), str(b), timeout=300)
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
    out = run_cli("query", str(ds), "SELECT command, count(*) AS n FROM packets WHERE side = 'client' "
                          "GROUP BY ALL ORDER BY n DESC", "--format", "json", timeout=120)
    assert out.returncode == 0, out.stderr
    total: dict[str, int] = {}
    for cap in (p, ps):
        for c in capture_stats(cap).to_dict()["p2os"]["commands"]:
            total[c["name"]] = total.get(c["name"], 0) + c["count"]
    assert {r["command"]: r["n"] for r in json.loads(out.stdout)} == total


def test_packets_link_is_the_protocol_beside_either_spelling_of_a_pair(tmp_path):
    """Issue 41 respells the frames' and values' link (``link=B_to_A``, before ``link=B-A``);
    the packets' ``link=<protocol>`` stays, in a dataset of either spelling."""
    p = tmp_path / "p.pcap"
    beacon = tmp_path / "beacon.pcap"
    generate_p2os_file(P2osGenOptions(duration=3, seed=3), p)
    assert run_cli("gen", "-o", str(beacon), "--duration", "3", text=False).returncode == 0
    ds = tmp_path / "ds"
    assert ingest([p, beacon], ds).ok
    assert sorted(d.relative_to(ds).as_posix() for d in ds.glob("*/day=*/link=*")) == [
        "frames/day=2026-01-01/link=B_to_A", "links/day=2026-01-01/link=B_to_A",
        "links/day=2026-01-01/link=robot_to_client", "packets/day=2026-01-01/link=p2os",
        "values/day=2026-01-01/link=B_to_A"]  # (links: the robot's SIP stream too, issue 43 on P2OS)
    sql = "SELECT link, protocol, count(*) FROM packets GROUP BY ALL"
    want = list(run_query(ds, sql).rows())
    assert [r[:2] for r in want] == [("p2os", "p2os")]
    # as ingest wrote it before issue 41
    for d in ds.glob("*/day=*/link=*_to_*"):
        d.rename(d.with_name(d.name.replace("_to_", "-")))
    manifest = load_manifest(ds)
    for e in manifest.captures.values():
        e.files = [f.replace("_to_", "-") for f in e.files]
    save_manifest(ds, manifest)
    assert old_links(manifest) and {d.name for d in ds.glob("packets/day=*/link=*")} == {"link=p2os"}
    assert list(run_query(ds, sql).rows()) == want
    assert list(run_query(ds, "SELECT DISTINCT link FROM frames").rows()) == [("B_to_A",)]
