"""Issue 43: `sharedlink ingest` writes link health, the `links` (per link and second) and
`outages` tables, as `sharedlink stats` figures it; docs/fleet.md's examples (fenced
`sql health`) give per vehicle and day what stats gives per capture. (Agreement with the tap,
stats and export on the fault captures: tests/dissector/test_health_tap.py.)"""

from __future__ import annotations

import datetime as dt
import re
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli

from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.pcapio import NS
from sharedlink.fleet.query import run_query

CLI = [sys.executable, "-m", "sharedlink"]
REPO = Path(__file__).resolve().parents[2]
#: vehicle -> captures' gen arguments
FLEET = {
    "v1": [["--duration", "30", "--outage", "5:3", "--outage", "20:2"],
           ["--duration", "20", "--rate", "14", "--outage", "10:4"]],
    "v2": [["--duration", "30", "--src", "C", "--outage", "12:2.5"],
           ["--duration", "20", "--start", "2026-01-02T08:00:00Z", "--outage", "3:1.5"]],
}


def docs_queries() -> list[str]:
    return re.findall(r"```sql health\n(.*?)```", (REPO / "docs" / "fleet.md").read_text(), re.S)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> tuple[Path, dict[str, list[Path]]]:
    d = tmp_path_factory.mktemp("health_fleet")
    caps: dict[str, list[Path]] = {}
    for vehicle, runs in FLEET.items():
        for k, args in enumerate(runs):
            p = d / "fleet" / vehicle / f"run{k}.pcap"
            p.parent.mkdir(parents=True, exist_ok=True)
            r = run_cli("gen", "-o", str(p), "--seed", str(k + 1), *args, timeout=120)
            assert r.returncode == 0, r.stderr
            caps.setdefault(vehicle, []).append(p)
    ds = d / "ds"
    r = run_cli("ingest", "-o", str(ds), str(d / "fleet"), timeout=300)
    assert r.returncode == 0, r.stderr
    return ds, caps


def test_docs_queries_are_stats(fleet):
    ds, caps = fleet
    per_day, per_link = docs_queries()
    want: dict[tuple, list] = {}
    links: dict[tuple, tuple] = {}
    for vehicle, paths in caps.items():
        for p in paths:
            st = capture_stats(p)
            for o in st.health.outages():
                day = dt.datetime.fromtimestamp(o.start_ns // NS, dt.timezone.utc).date()
                w = want.setdefault((vehicle, day), [0, 0, 0.0, 0])
                w[0] += 1
                w[1] += o.duration_ns
                w[2] = max(w[2], o.duration_ns / NS)
                w[3] += o.end_ns is None
            for h in st.health.sorted_links():
                links[(vehicle, str(p), h.pair.replace(">", "_to_"))] = (h.frames, len(h.outages))
    got = list(run_query(ds, per_day).rows())
    assert [(v, day, n) for v, day, n, *_ in got] == [(*k, w[0]) for k, w in sorted(want.items())]
    for (_v, _day, _n, minutes, longest, still_open), w in zip(got, (w for _k, w in sorted(want.items()))):
        assert minutes == pytest.approx(w[1] / NS / 60, abs=1e-9) and longest == w[2] and still_open == w[3]
    assert sum(w[0] for w in want.values()) == 5  # the planted outages, and nothing else
    rows = {(v, c, link): (down, worst, frames) for v, c, link, down, worst, frames in run_query(ds, per_link).rows()}
    assert {k: r[2] for k, r in rows.items()} == {k: f for k, (f, _n) in links.items()}
    for k, (down, worst, _frames) in rows.items():  # seconds down: there were outages; a whole up second has frames
        assert (down > 0) == (links[k][1] > 0) and worst >= 0


def test_reingest_replaces_health_rows(fleet, tmp_path):
    """A capture ingested again (--reingest) has its links and outages rows replaced, not doubled."""
    ds, caps = fleet
    before = list(run_query(ds, "SELECT count(*) FROM links UNION ALL SELECT count(*) FROM outages").rows())
    p = caps["v1"][0]
    r = run_cli("ingest", "-o", str(ds), "--reingest", str(p), timeout=300)
    assert r.returncode == 0, r.stderr
    assert list(run_query(ds, "SELECT count(*) FROM links UNION ALL SELECT count(*) FROM outages").rows()) == before


def test_links_rows_written_in_pieces_are_the_same(tmp_path, monkeypatch):
    """Issue 44: a link's `links` rows are made CHUNK_ROWS at a time and a day at a time (a long
    capture's seconds are never all held); written in pieces of 7 rows, across midnight and an
    outage, the table holds the same rows, each second once, in each day's partition."""
    from sharedlink.fleet import health_rows
    from sharedlink.fleet.ingest import ingest

    cap = tmp_path / "midnight.pcap"
    r = run_cli("gen", "-o", str(cap), "--seed", "3", "--duration", "40", "--start", "2026-01-01T23:59:40Z",
                "--outage", "15:4", timeout=120)
    assert r.returncode == 0, r.stderr
    sql = ("SELECT time_ns, conversation, pair, frames, state, quality, down_s, day FROM links "
           "ORDER BY time_ns, conversation, pair")
    assert ingest([cap], tmp_path / "whole").ok
    whole = list(run_query(tmp_path / "whole", sql).rows())
    monkeypatch.setattr(health_rows, "CHUNK_ROWS", 7)
    assert ingest([cap], tmp_path / "pieces").ok
    assert list(run_query(tmp_path / "pieces", sql).rows()) == whole
    assert len(whole) > 2 * 7 and {str(row[-1]) for row in whole} == {"2026-01-01", "2026-01-02"}
    assert len({(t, c, p) for t, c, p, *_ in whole}) == len(whole)
    assert any(state == "down" for *_, state, _q, _d, _day in whole)
