"""Threshold options at their exact boundary, where ``<`` and ``<=`` differ (test_thresholds.py
has the sync clock in the decoders and ``stats``, and ``diff --tolerance``):

* **Outages** (docs/fields-sharedlink.md, "Link health"): a silence *longer than* the threshold
  is an outage: ``--outage-after S`` when given, else the larger of 1 s and 3 learnt periods.
  One capture of six links (one a source address), each silent once for exactly a threshold or
  1 ns more: 1 s (0.25 s periods: the floor), 1.5 s (0.5 s periods: 3 periods), 2 s (0.25 s
  periods). ``stats``, ``health``, ``export --outages``, the dissector's tap (its
  ``outage_after`` preference) and ``watch`` (the learnt rule: it has no option) find the
  outages of the links past their threshold, and none of the links exactly at it.
* **The sync interval** in the other commands that take ``--sync-interval``: a delta exactly
  1.5 s after the full frame (interval 1 s) is on time, 1 ns later late; with 2 s both on time
  (``watch --json``, ``export``'s MCAP frames channels, ``ingest``'s frames table).
* **Missed syncs** (``diff --sync-interval``): a gap between full frames (or from the last one to
  the end) that rounds to n >= 2 intervals misses n - 1: 1.5 intervals is 2, 1 ns less is 1.
* **``diff --window``**: frames match when at most the window apart: 10 ms apart match with a
  window of 10 ms, not with 9.999999 ms.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from sl_agreement import health_tap
from sl_captures import write_capture
from sl_cli import run_cli

import tshark_util as tu
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter

NS = 10**9
T0 = 1_767_268_800 * NS
END = 5 * NS
#: source address -> (period, the silence: its start and length), all in ns
LINKS = {
    "10.0.0.2": (NS // 4, NS, NS),
    "10.0.0.3": (NS // 4, NS, NS + 1),
    "10.0.0.4": (NS // 2, 2 * NS, 3 * NS // 2),
    "10.0.0.5": (NS // 2, 2 * NS, 3 * NS // 2 + 1),
    "10.0.0.6": (NS // 4, NS, 2 * NS),
    "10.0.0.7": (NS // 4, NS, 2 * NS + 1),
}
#: --outage-after (None: the learnt rule) -> the links with an outage
OUTAGES = {
    None: {"10.0.0.3", "10.0.0.5", "10.0.0.6", "10.0.0.7"},
    "1": {"10.0.0.3", "10.0.0.4", "10.0.0.5", "10.0.0.6", "10.0.0.7"},
    "1.5": {"10.0.0.5", "10.0.0.6", "10.0.0.7"},
    "2": {"10.0.0.7"},
}
FULL = tu.frame("A", "B", "N0", "T2", "QLat", "D1.5", "T2", "QLon", "D2")


def write_sorted(path: Path, records: list[tuple[int, bytes]]) -> Path:
    """A nanosecond pcap of (ts_ns, Ethernet frame) records in time order."""
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for ts, frame in sorted(records):
            w.write(ts, frame)
    return path


def link_times(period: int, start: int, silence: int) -> list[int]:
    """A link's frame times: every period until ``start``, then after the silence until END."""
    before = list(range(0, start + 1, period))
    return before + list(range(start + silence, END + 1, period))


@pytest.fixture(scope="module")
def silences(tmp_path_factory: pytest.TempPathFactory) -> Path:
    records = []
    for src, (period, start, silence) in LINKS.items():
        b = UdpBuilder(src, "10.0.0.1", 7013, 7013)
        records += [(T0 + t, b.frame(FULL, k + 1)) for k, t in enumerate(link_times(period, start, silence))]
    return write_sorted(tmp_path_factory.mktemp("outage_boundary") / "silences.pcap", records)


def silent(outages: list[dict]) -> dict[str, int]:
    """The outages' links (by source address) -> duration in ns."""
    return {o["link"].split(":")[0]: round(o["duration_s"] * NS) for o in outages}


def expected(option: str | None) -> dict[str, int]:
    return {src: LINKS[src][2] for src in OUTAGES[option]}


def option_args(option: str | None) -> list[str]:
    return [] if option is None else ["--outage-after", option]


@pytest.mark.parametrize("option", OUTAGES, ids=lambda o: f"outage-after-{o or 'learnt'}")
def test_stats_outage_after_at_its_boundary(silences: Path, option: str | None) -> None:
    d = json.loads(run_cli("stats", silences, "--json", *option_args(option), check=True).stdout)
    assert silent(d["outages"]) == expected(option)


@pytest.mark.parametrize("option", OUTAGES, ids=lambda o: f"outage-after-{o or 'learnt'}")
def test_the_dissectors_outage_after_at_its_boundary(silences: Path, option: str | None) -> None:
    got, _links, _text = health_tap(silences, None if option is None else {"sharedlink.outage_after": option})
    assert {o[0].split(":")[0] for o in got} == set(expected(option))


@pytest.mark.parametrize("option", [None, "1.5"], ids=lambda o: f"outage-after-{o or 'learnt'}")
def test_health_and_export_outage_after_at_their_boundary(silences: Path, option: str | None) -> None:
    h = json.loads(run_cli("health", silences, "--json", *option_args(option), check=True).stdout)
    assert silent(h["outages"]) == expected(option)
    rows = run_cli("export", silences, "--format", "jsonl", "--outages", "-o", "-", *option_args(option),
                   check=True).stdout.splitlines()
    assert silent([x for x in map(json.loads, rows) if x["kind"] == "outage"]) == expected(option)


def test_watch_learnt_threshold_at_its_boundary(silences: Path) -> None:
    rows = run_cli("watch", silences, "--json", "--outages", "--speed", "1000", check=True).stdout.splitlines()
    assert silent([x for x in map(json.loads, rows) if x["kind"] == "outage"]) == expected(None)


# -- the sync interval in the other commands ---------------------------------------------------


@pytest.fixture(scope="module")
def late_deltas(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two links: a full frame, then a delta exactly 1.5 s later (B>A) or 1.5 s + 1 ns (C>A)."""
    delta = {"B": tu.frame("A", "B", "N0", "T2", "QLat", "D1.6"), "C": tu.frame("A", "C", "N0", "T2", "QLat", "D1.6")}
    records = []
    for n, (src, extra) in enumerate((("B", 0), ("C", 1))):
        b = UdpBuilder(f"10.0.0.{n + 2}", "10.0.0.1", 7013, 7013)
        full = tu.frame("A", src, "N0", "T2", "QLat", "D1.5", "T2", "QLon", "D2")
        records += [(T0 + n, b.frame(full, 1)), (T0 + 3 * NS // 2 + n + extra, b.frame(delta[src], 2))]
    return write_sorted(tmp_path_factory.mktemp("sync_boundary") / "late.pcap", records)


#: --sync-interval -> the pairs whose delta is late
LATE = {"1": {"C>A"}, "2": set()}


@pytest.mark.parametrize("interval", LATE)
def test_watch_sync_interval_at_its_boundary(late_deltas: Path, interval: str) -> None:
    out = run_cli("watch", late_deltas, "--json", "--speed", "100", "--sync-interval", interval, check=True).stdout
    rows = [json.loads(x) for x in out.splitlines()]
    assert [r["kind"] for r in rows] == ["full", "full", "delta", "delta"]
    assert {f'{r["src"]}>{r["dst"]}' for r in rows if r["late"]} == LATE[interval]


@pytest.mark.parametrize("interval", LATE)
def test_export_mcap_sync_interval_at_its_boundary(late_deltas: Path, tmp_path: Path, interval: str) -> None:
    """MCAP's frames channels (the export format that writes lateness)."""
    reader = pytest.importorskip("mcap.reader")
    out = tmp_path / "late.mcap"
    run_cli("export", late_deltas, "-o", out, "-q", "--sync-interval", interval, check=True)
    with open(out, "rb") as fh:
        rows = [json.loads(m.data) for _s, c, m in reader.make_reader(fh).iter_messages() if c.topic.endswith("/frames")]
    assert sorted(r["kind"] for r in rows) == ["delta", "delta", "full", "full"]
    assert {f'{r["src"]}>{r["dst"]}' for r in rows if r["late"]} == LATE[interval]


@pytest.mark.parametrize("interval", LATE)
def test_ingest_sync_interval_at_its_boundary(late_deltas: Path, tmp_path: Path, interval: str) -> None:
    ds = tmp_path / "ds"
    run_cli("ingest", "-o", ds, "-q", "--sync-interval", interval, late_deltas, check=True)
    out = run_cli("query", ds, "select src, dst from frames where late order by all", "--format", "json",
                  check=True).stdout
    assert {f'{r["src"]}>{r["dst"]}' for r in json.loads(out)} == LATE[interval]


# -- diff: missed syncs and the matching window --------------------------------------------------


@pytest.mark.parametrize("interval", ["1", "2"])
@pytest.mark.parametrize("short", [0, 1], ids=["at", "1ns-short"])
def test_diff_missed_syncs_at_their_boundary(tmp_path: Path, interval: str, short: int) -> None:
    """Full frames every interval (twenty: the fast lanes take them), a gap of 1.5 intervals (less
    ``short`` ns), two more, then a delta 1.5 intervals (less ``short``) after the last full frame:
    two gaps that round to 2 intervals (one missed each), or to 1 (none)."""
    step = int(float(interval) * NS)
    full = tu.frame("A", "B", "N0", "T2", "QLat", "D1.5", "T2", "QLon", "D2")
    times = [k * step for k in range(20)]
    times += [times[-1] + 3 * step // 2 - short + k * step for k in range(3)]
    records = [(T0 + t, full) for t in times]
    records.append((T0 + times[-1] + 3 * step // 2 - short, tu.frame("A", "B", "N0", "T2", "QLat", "D1.6")))
    cap = write_capture(tmp_path / "syncs.pcap", records)
    d = json.loads(run_cli("diff", cap, cap, "--json", "--sync-interval", interval, check=True).stdout)
    assert d["a"]["sync_missed"] == d["b"]["sync_missed"] == (0 if short else 2)


def test_diff_window_at_its_boundary(tmp_path: Path) -> None:
    """The same five frames, 10 ms later on one side."""
    full = tu.frame("A", "B", "N0", "T2", "QLat", "D1.5", "T2", "QLon", "D2")
    caps = [write_capture(tmp_path / f"{k}.pcap", [(T0 + i * NS // 5 + k * NS // 100, full) for i in range(5)])
            for k in range(2)]
    got = {}
    for window in ("10", "9.999999"):
        r = run_cli("diff", *caps, "--window", window, "--json")
        d = json.loads(r.stdout)
        got[window] = (r.returncode, d["pairs"], d["unmatched_a"], d["unmatched_b"])
    assert got == {"10": (0, 5, 0, 0), "9.999999": (1, 0, 5, 5)}
