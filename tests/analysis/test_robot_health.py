"""Issue 43 on P2OS and blackboard links (issue 42 item 3): `stats` lists their links and
outages (its table and --json's "links" and "outages") beside SharedLink's. A generated session
shows none; the same session with a silence planted (every record from 8 s on moved 3 s later:
the TCP streams stay whole) shows exactly one per paced link, from the last message before it to
the first after, to the nanosecond of the messages `iter_sessions` (export's reading) finds."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli

from sharedlink.analysis.sessions import iter_sessions
from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.pcapio import NS, make_writer, read_records
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file

CLI = [sys.executable, "-m", "sharedlink"]
CUT_S, SHIFT_S = 8, 3


def silenced(src: Path, dst: Path, fmt: str) -> Path:
    """``src`` with every record from CUT_S seconds on SHIFT_S seconds later."""
    recs = list(read_records(src))
    cut = recs[0].ts_ns + CUT_S * NS
    with open(dst, "wb") as fh:
        w = make_writer(fh, fmt, recs[0].linktype)
        for r in recs:
            w.write(r.ts_ns + (SHIFT_S * NS if r.ts_ns >= cut else 0), r.data, r.flags)
    return dst


def sides(path: Path) -> dict[str, list[int]]:
    out: dict[str, list[int]] = {}
    for m in iter_sessions(path):
        out.setdefault(m.side, []).append(m.ts_ns)
    return out


@pytest.mark.parametrize("protocol, transport", [("p2os", "tcp"), ("p2os", "serial"), ("blackboard", "udp")])
def test_a_silence_on_a_robot_link_is_one_outage(tmp_path, protocol, transport):
    cap = tmp_path / "s.pcapng"
    fmt = "pcapng"
    if protocol == "p2os":
        generate_p2os_file(P2osGenOptions(duration=20, seed=2, transport=transport, fmt=fmt), cap)
        paced = {"robot": "robot>client"}
    else:
        generate_blackboard_file(BlackboardGenOptions(duration=20, seed=2, fmt=fmt), cap)
        paced = {"master": "master>slave", "slave": "slave>master"}
    plain = capture_stats(cap).to_dict()
    assert {lk["pair"] for lk in plain["links"]} == set(paced.values()) and plain["outages"] == []
    assert all(lk["link"].startswith(protocol + " ") and lk["rate_hz"] > 5 for lk in plain["links"])
    cut = silenced(cap, tmp_path / "cut.pcapng", fmt)
    r = run_cli("stats", "--json", str(cut), timeout=120)
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    want = []
    for side, pair in paced.items():
        ts = sides(cut)[side]
        k = max(range(1, len(ts)), key=lambda i: ts[i] - ts[i - 1])
        assert ts[k] - ts[k - 1] > SHIFT_S * NS
        want.append((pair, ts[k - 1], ts[k]))
    got = [(o["pair"], o["start"], o["end"]) for o in d["outages"]]
    assert len(got) == len(want)
    for (gp, gs, ge), (wp, ws, we) in sorted(zip(sorted(got), sorted(want))):
        assert gp == wp and abs(gs - ws / NS) < 1e-6 and abs(ge - we / NS) < 1e-6
    st = capture_stats(cut)
    assert sorted((o.pair, o.start_ns, o.end_ns) for o in st.health.outages()) == sorted(want)
    assert {lk["pair"]: lk["outages"] for lk in d["links"]} == dict.fromkeys(paced.values(), 1)
    text = run_cli("stats", str(cut), timeout=120).stdout
    assert "Link health" in text and "Outages (UTC)" in text
