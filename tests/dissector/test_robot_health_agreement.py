"""Link health of P2OS and blackboard links (issues 42 and 43) agrees in every output: the
Wireshark tap (-z sharedlink,stats with p2os.lua, blackboard.lua and serial.lua, its link table
and outages), `stats --json`, `health` (its rows and --json), `export --outages` (jsonl rows, a
robot CSV's rows of type outage), `ingest`'s outages and links tables and `watch`'s robot panel
(LINK DOWN while a silence lasts): the same outages (count, link, side, start and duration to the
microsecond) on generated P2OS and blackboard sessions over TCP, UDP and serial with silences
planted by `gen --outage` (P2OS over UDP on port 8101, and on another port in a pcap, where both
sides tell the robot's packets by their content alone). Every tshark run is checked for Lua errors (tshark_util)."""

from __future__ import annotations

import csv
import io
import json
import re
from functools import partial
from pathlib import Path

import pytest
import sl_cli
from rich.console import Console
from sl_agreement import (
    ROBOTS,
    SERIAL,
    gen_captures,
    health_tap,
    ingest,
    ingested_outages,
    json_outages,
    links_table_is_health,
    reference_outages,
    same_outages,
)

import tshark_util as tu
from sharedlink.analysis.sessions import iter_sessions
from sharedlink.capture.pcapio import NS
from sharedlink.robot_watch import RobotView

OUTAGES = ["--outage", "8:3", "--outage", "14:1.5"]
#: name -> gen arguments (20 s sessions with two silences, the line cut both ways)
CAPTURES = {
    "p2os-tcp": ["--protocol", "p2os", "--transport", "tcp"],
    "p2os-serial": ["--protocol", "p2os", "--transport", "serial"],
    "p2os-udp": ["--protocol", "p2os", "--transport", "udp"],
    # no port and no direction flag to go by: both decide each packet's side from its content
    "p2os-udp-content": ["--protocol", "p2os", "--transport", "udp", "--port", "9000", "--format", "pcap"],
    "blackboard-udp": ["--protocol", "blackboard", "--transport", "udp"],
    "blackboard-tcp": ["--protocol", "blackboard", "--transport", "tcp", "--seed", "3"],
    "blackboard-serial": ["--protocol", "blackboard", "--transport", "serial"],
}
#: paced sides a session's link health follows
PAIRS = {"p2os": {"robot>client"}, "blackboard": {"master>slave", "slave>master"}}


#: every run here must succeed
run_cli = partial(sl_cli.run_cli, check=True, timeout=180)


@pytest.fixture(scope="module")
def caps(tmp_path_factory) -> dict[str, Path]:
    return gen_captures(tmp_path_factory.mktemp("robot_health"),
                        {name: ["--duration", "20", *args, *OUTAGES] for name, args in CAPTURES.items()}, ".pcapng")


@pytest.fixture(scope="module")
def dataset(caps, tmp_path_factory) -> Path:
    return ingest(tmp_path_factory.mktemp("robot_fleet"), caps.values())


def stats(path: Path) -> dict:
    return json.loads(run_cli("stats", "--json", path).stdout)


@pytest.mark.parametrize("name", CAPTURES)
def test_tap_is_stats(caps, name):
    path = caps[name]
    d = stats(path)
    protocol = name.split("-")[0]
    want = reference_outages(path)
    same_outages(json_outages(path, d["outages"]), want)
    assert {lk["pair"] for lk in d["links"]} == PAIRS[protocol]
    assert all(lk["link"].startswith(protocol + " ") and lk["outages"] == 2 for lk in d["links"])
    assert len(want) == 2 * len(PAIRS[protocol]) and not any(o[4] for o in want)
    got, links, text = health_tap(path, robots=True)
    same_outages(got, want)
    assert set(links) == {(lk["link"], lk["pair"]) for lk in d["links"]}
    for lk in d["links"]:
        row = links[(lk["link"], lk["pair"])]
        assert row[0] == str(lk["frames"]) and row[1] == "%.3f" % lk["rate_hz"] and row[2] == str(lk["outages"])
        assert row[3] == "%.3f" % lk["outage_s"] and row[5] == "%.2f" % (100 * lk["availability"])
        assert row[6] == "%.2f" % lk["bad_checksum_pct"]
    # the expert on the packet after each silence, counted by Expert Information
    m = re.search(r"^\s+(\d+)\s+\S+\s+(P2OS|BLACKBOARD)\s+Link silent", text, re.M | re.I)
    assert m and int(m.group(1)) == len(want), text


@pytest.mark.parametrize("name", ["p2os-tcp", "blackboard-udp"])
def test_expert_and_duration_field(caps, name):
    """p2os.outage / blackboard.outage with the generated .outage.duration on the packet after a
    silence, in one pass and in two, the same durations as stats."""
    protocol = name.split("-")[0]
    want = sorted(round(o["duration_s"], 6) for o in stats(caps[name])["outages"])
    field = f"{protocol}.outage.duration"
    extra = [a for s in (*ROBOTS, SERIAL) for a in ("-X", f"lua_script:{s}")]
    for two_pass in (False, True):
        rows = tu.fields(caps[name], [field], display_filter=field, two_pass=two_pass, extra=extra)
        got = sorted(round(float(x), 6) for r in rows for x in r[field])
        assert got == want
        assert all("Link silent" in r["_ws.expert.message"] for r in rows)


@pytest.mark.parametrize("name", CAPTURES)
def test_health_export_ingest_are_stats(caps, dataset, name):
    path = caps[name]
    d = stats(path)
    want = reference_outages(path)
    same_outages(json_outages(path, d["outages"]), want)
    h = json.loads(run_cli("health", "--json", path).stdout)
    same_outages(json_outages(path, h["outages"]), want)
    assert [(lk["link"], lk["pair"], lk["frames"]) for lk in h["links"]] == [
        (lk["link"], lk["pair"], lk["frames"]) for lk in d["links"]]
    rows = [json.loads(x) for x in run_cli("export", "--format", "jsonl", "--outages", path).stdout.splitlines()]
    outs = [x for x in rows if x.get("kind") == "outage"]
    same_outages(json_outages(path, outs), want)
    for k, x in enumerate(rows):  # each outage row comes before the message that ends it, of its side
        if x.get("kind") == "outage":
            nxt = next(y for y in rows[k + 1:] if y.get("kind") != "outage" and y["side"] == x["src"])
            assert nxt["ts_ns"] / NS == pytest.approx(x["end"], abs=1e-6)
    table = list(csv.DictReader(io.StringIO(run_cli("export", "--format", "csv", "--outages", path).stdout)))
    outs = sorted((r for r in table if r["type"] == "outage"), key=lambda r: (int(r["ts_ns"]), r["side"]))
    assert len(outs) == len(want)
    for r, o in zip(outs, sorted(d["outages"], key=lambda o: (o["start"], o["pair"]))):
        assert (f"{r['protocol']} {r['link']}", r["side"], float(r["duration_s"])) == (
            o["link"], o["pair"].partition(">")[0], o["duration_s"])
        assert abs(int(r["ts_ns"]) / NS - o["start"]) < 1e-6
    assert len(table) - len(outs) == sum(1 for _ in iter_sessions(path))  # every message a row as before
    same_outages(ingested_outages(dataset, path), want)
    per_second = links_table_is_health(dataset, path)
    assert {s["pair"] for s in per_second} == PAIRS[name.split("-")[0]]


def _panel(view: RobotView, now_ns: int) -> list[str]:
    console = Console(record=True, width=200)
    console.print(view.render(now_ns))
    return [x for x in console.export_text().splitlines() if x.strip().startswith("link ")]


@pytest.mark.parametrize("name", ["p2os-tcp", "p2os-udp-content", "blackboard-serial"])
def test_watch_shows_the_outages(caps, name):
    """watch's robot panel, fed the session's messages as they come: LINK DOWN on each paced link
    while a silence lasts (once past its threshold), then as many outages as stats counts."""
    path = caps[name]
    d = stats(path)
    msgs = list(iter_sessions(path))
    first = min(o["start"] for o in d["outages"])
    view = RobotView()
    for m in msgs:
        if m.ts_ns / NS > first + 0.5:  # (inside the 3 s silence: every side has sent its last)
            break
        view.update(m)
    lines = _panel(view, round((first + 1.5) * NS))  # (10 Hz links: the 1 s floor is their threshold)
    assert len(lines) == len(PAIRS[name.split("-")[0]]) and all("LINK DOWN" in x for x in lines), lines
    assert all("outages 1" in x for x in lines)
    sec = int(first) - 1  # a whole second before the silence: Shepherd's quality, its frames
    got = _panel(view, (sec + 1) * NS + NS // 2)
    assert sum(int(re.search(r"quality (\d+)/s", x).group(1)) for x in got) == sum(
        1 for m in msgs if m.side != "client" and m.ts_ns // NS == sec) > 5
    view = RobotView()
    for m in msgs:
        view.update(m)
    lines = _panel(view, msgs[-1].ts_ns)
    want = {lk["pair"]: lk["outages"] for lk in d["links"]}
    assert {x.split()[1].rstrip(":"): int(re.search(r"outages (\d+)", x).group(1)) for x in lines} == want
    assert not any("LINK DOWN" in x for x in lines)
