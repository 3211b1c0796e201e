"""Link health in the real tshark (issue 43): the sharedlink.outage expert and its generated
sharedlink.outage.duration on the first frame after each outage (in a summary pass, -2 and a
tree), the outage_after preference, and the -z sharedlink,stats tap's link table and outages,
which agree with `sharedlink stats` (count, start and duration to the microsecond) on generated
fault captures. Every run is checked for Lua errors (tshark_util)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from sl_agreement import (
    exported_outages,
    gen_captures,
    ingest,
    links_table_is_health,
    python_outages,
    same_outages,
)
from sl_agreement import health_tap as tap
from sl_cli import run_cli

import tshark_util as tu
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import NS, PcapWriter, read_records
from sharedlink.generators.beacon import DEFAULT_START_NS
from sharedlink.protocols.codec import checksum

#: generated fault captures: gen arguments
CAPTURES = {
    "5Hz-two-outages": ["--duration", "60", "--outage", "10:3", "--outage", "40:1.5"],
    "6.5Hz-full-sets-jitter": ["--duration", "60", "--rate", "6.5", "--compress", "--jitter", "30", "--outage", "20:3"],
    "14Hz": ["--duration", "40", "--rate", "14", "--compress", "--outage", "20:3"],
    "40Hz": ["--duration", "30", "--rate", "40", "--jitter", "5", "--outage", "12:3", "--outage", "20:1.1"],
    "lossy": ["--duration", "120", "--compress", "--drop", "0.35", "--bad-checksum", "0.05", "--seed", "4"],
    "serial": ["--transport", "serial", "--duration", "30", "--outage", "10:3", "--outage", "20:2"],
    "positional": ["--duration", "30", "--form", "positional", "--outage", "5:4"],
}


@pytest.fixture(scope="module")
def caps(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("health")
    out = gen_captures(d, CAPTURES)
    out["open"] = open_outage(d / "open.pcap")
    return out


def open_outage(path: Path) -> Path:
    """Two links at 10 Hz; the first stops after 10 s (an open outage at the end)."""
    body = b":AB|N0|T2|QAutoGpsLat|D1.5|C"
    frame = b"[" + body + b"%02X]\r\n" % checksum(body)
    a, b = UdpBuilder("10.0.0.2", "10.0.0.1", 7013, 7013), UdpBuilder("10.0.0.3", "10.0.0.1", 7013, 7013)
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for k in range(200):
            for n, builder in enumerate((a, b)):
                if n == 1 or k < 100:
                    w.write(DEFAULT_START_NS + k * NS // 10, builder.headers(len(frame), frame, k + 1) + frame)
    return path


@pytest.mark.parametrize("name", [*CAPTURES, "open"])
def test_tap_agrees_with_stats(caps, name):
    want, links = python_outages(caps[name])
    got, tap_links, _ = tap(caps[name])
    same_outages(got, want)
    if name != "lossy":
        assert want, "the capture has outages"
    assert set(tap_links) == {(lk["link"], lk["pair"]) for lk in links}
    for lk in links:
        row = tap_links[(lk["link"], lk["pair"])]
        assert row[0] == str(lk["frames"]) and row[2] == str(lk["outages"])
        assert row[1] == ("%.3f" % lk["rate_hz"] if lk["rate_hz"] else "")
        assert row[3] == "%.3f" % lk["outage_s"] and row[5] == "%.2f" % (100 * lk["availability"])
        assert row[6] == "%.2f" % lk["bad_checksum_pct"] and row[7] == str(lk["sync_late"])


def test_threshold_preference_is_outage_after(caps):
    for s in ("2.5", "0.3"):
        want, _ = python_outages(caps["5Hz-two-outages"], "--outage-after", s)
        got, _, _ = tap(caps["5Hz-two-outages"], {"sharedlink.outage_after": s})
        same_outages(got, want)
        assert len(got) == (1 if s == "2.5" else 2)


@pytest.mark.parametrize("two_pass", [False, True])
def test_expert_on_the_frame_after(caps, two_pass):
    cap = caps["5Hz-two-outages"]
    rows = tu.fields(cap, ["frame.number", "frame.time_relative", "sharedlink.outage.duration"],
                     display_filter="sharedlink.outage", two_pass=two_pass)
    # (a double: 4.0 prints 3.2, 4.4 and later every digit, 3.1999999999999993)
    assert [(float(r["frame.time_relative"][0]), [round(float(x), 9) for x in r["sharedlink.outage.duration"]])
            for r in rows] == [(13.0, [3.2]), (41.6, [1.8])]
    assert [[m for m in r["_ws.expert.message"] if m.startswith("Link silent")] for r in rows] == [
        ["Link silent"], ["Link silent"]]  # one summary a problem (issue 41); the duration in its field
    assert len(tu.fields(cap, ["frame.number"], display_filter="sharedlink.outage.duration > 3",
                         two_pass=two_pass)) == 1


def test_expert_in_a_summary_pass(caps):
    """No tree at all (tshark's summary): Expert Information still counts every outage."""
    res = tu.tshark(caps["14Hz"], ["-q", "-z", "expert"])
    m = re.search(r"^\s+(\d+)\s+\S+\s+SHAREDLINK\s+Link silent", res.stdout, re.M)
    assert m and int(m.group(1)) == 1, res.stdout


@pytest.mark.parametrize("name", [*CAPTURES, "open"])
def test_export_rows_are_stats_outages(caps, name):
    """export --format jsonl --outages: an outage row (kind: outage) before the frame that ends it, the open
    ones last; the same outages as stats --json, to the nanosecond of its figures."""
    r = run_cli("stats", "--json", caps[name])
    want = json.loads(r.stdout)["outages"]
    text = run_cli("export", "--format", "jsonl", "--outages", caps[name]).stdout
    assert exported_outages(text) == want
    rows = [json.loads(x) for x in text.splitlines()]
    for k, x in enumerate(rows):  # the frame after a closed outage's row is at its end, of its pair
        if x["kind"] == "outage" and x["end"] is not None:
            nxt = next(y for y in rows[k + 1:] if y["kind"] != "outage" and f'{y["src"]}>{y["dst"]}' == x["pair"])
            assert nxt["ts_ns"] / NS == pytest.approx(x["end"], abs=1e-6)
    if name == "open":
        assert rows[-1]["kind"] == "outage" and rows[-1]["end"] is None


@pytest.mark.parametrize("name", ["5Hz-two-outages", "lossy", "open"])
def test_export_csv_rows_are_stats_outages(caps, name):
    """export --format csv --outages: a row of kind outage (its start's time, the frame that ends
    it, its duration_s) per outage of stats --json; frame rows as without --outages otherwise."""
    import csv
    import io

    want = json.loads(run_cli("stats", "--json", caps[name]).stdout)["outages"]
    rows = list(csv.DictReader(io.StringIO(run_cli("export", "--format", "csv", "--outages", caps[name]).stdout)))
    got = [r for r in rows if r["kind"] == "outage"]
    assert len(got) == len(want)
    got.sort(key=lambda r: (int(r["ts_ns"]), r["src"]))
    for r, o in zip(got, want):  # (stats' epoch seconds are a double: its start to the microsecond)
        assert (f'{r["src"]}>{r["dst"]}', float(r["duration_s"]), r["number"] == "") == (
            o["pair"], o["duration_s"], o["end"] is None)
        assert abs(int(r["ts_ns"]) / NS - o["start"]) < 1e-6
    plain = list(csv.DictReader(io.StringIO(run_cli("export", "--format", "csv", caps[name]).stdout)))
    frames = [{k: v for k, v in r.items() if k != "duration_s"} for r in rows if r["kind"] != "outage"]
    assert frames == plain


@pytest.fixture(scope="module")
def dataset(caps, tmp_path_factory) -> Path:
    """Every capture above ingested into one fleet dataset."""
    return ingest(tmp_path_factory.mktemp("fleet"), caps.values())


@pytest.mark.parametrize("name", [*CAPTURES, "open"])
def test_ingest_outages_are_stats_outages(caps, dataset, name):
    """ingest's outages table: the outages of stats (count, links, open or not, start and duration
    to the microsecond; here to the nanosecond); its links table: the per-second rows of
    `sharedlink health -o -`, and per link the frames stats counts."""
    from sharedlink.fleet.query import run_query

    path = caps[name]
    want, links = python_outages(path)
    first = next(iter(read_records(path))).ts_ns
    where = "WHERE capture = '%s'" % str(path).replace("'", "''")
    rows = list(run_query(dataset, "SELECT conversation, pair, time_ns, duration_ns, open, end_ns, link FROM outages "
                                   f"{where} ORDER BY ALL").rows())
    got = sorted((c, p, (t - first) / NS, d / NS, o) for c, p, t, d, o, _end, _link in rows)
    assert got == want
    for _c, p, t, d, o, end, link in rows:
        assert link == p.replace(">", "_to_") and (end is None) == o and (o or end - t == d)
    if name != "lossy":
        assert want, "the capture has outages"
    links_table_is_health(dataset, path)
    frames = dict(((c, p), n) for c, p, n in run_query(
        dataset, f"SELECT conversation, pair, sum(frames) FROM links {where} GROUP BY ALL").rows())
    assert frames == {(lk["link"], lk["pair"]): lk["frames"] for lk in links}
