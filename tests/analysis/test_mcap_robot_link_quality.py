"""Issue 43 for robot links (issue 42): `export --format mcap` of a P2OS or blackboard capture
writes one link_quality topic per paced robot link (the robot's SIP stream; the blackboard
master's and slave's sides), with the SharedLink links' schema (sharedlink.LinkQuality) and
topic rule (the link's pair below its session's topics: /p2os/1/robot_to_client/link_quality),
a message per second at the second's start: the rows `sharedlink health -o -` lists for those
links, read back with the independent `mcap` reader, the outage's seconds down (no frame, the
quality the seconds since the outage began) inside the outages `stats --json` counts."""

from __future__ import annotations

import json
from functools import partial

import pytest
import sl_cli
from sl_foxglove import check_gaps, is_gap, quality_topics

mcap_reader = pytest.importorskip("mcap.reader")
pytest.importorskip("jsonschema")  # (quality_topics validates each message)

NS = 10**9
#: name -> gen arguments: 20 s sessions with planted silences
CAPTURES = {
    "p2os-tcp": ["--protocol", "p2os", "--outage", "8:3", "--outage", "14:1.5"],
    "p2os-serial": ["--protocol", "p2os", "--transport", "serial", "--outage", "6:2.5"],
    "blackboard-udp": ["--protocol", "blackboard", "--outage", "8:3"],
    "blackboard-serial": ["--protocol", "blackboard", "--transport", "serial", "--outage", "5:2", "--outage", "12:3"],
}
#: every run here must succeed
run_cli = partial(sl_cli.run_cli, check=True)
#: the paced links a session's link health follows (robot_health.py)
PAIRS = {"p2os": {"robot>client"}, "blackboard": {"master>slave", "slave>master"}}


def runs(states: list[str]) -> int:
    """Runs of consecutive "down" seconds."""
    return sum(1 for i, s in enumerate(states) if s == "down" and (i == 0 or states[i - 1] != "down"))


@pytest.mark.parametrize("name", CAPTURES)
def test_robot_link_quality_topics_are_the_health_rows(tmp_path, name):
    protocol = name.split("-")[0]
    cap, out = tmp_path / "c.pcapng", tmp_path / "c.mcap"
    run_cli("gen", "-o", cap, "--duration", "20", *CAPTURES[name])
    run_cli("export", cap, "-o", out)
    rows = [json.loads(x) for x in run_cli("health", "-o", "-", cap).stdout.splitlines()]
    assert {r["pair"] for r in rows} == PAIRS[protocol]
    got, meta = quality_topics(out)
    want: dict[str, list] = {}
    for r in rows:
        topic = f"/{protocol}/1/" + r["pair"].replace(">", "_to_") + "/link_quality"
        want.setdefault(topic, []).append((r["second"] * NS, {k: r[k] for k in ("frames", "quality", "state", "down_s")}))
        src, dst = r["pair"].split(">")
        assert meta[topic] == {"src": src, "dst": dst, "link": r["link"], "session": r["link"].split(" ", 1)[1]}
    assert got == want
    sessions = {dict(m)["session"] for m in meta.values()}
    assert len(sessions) == 1  # the session's label, as its other topics have it
    d = json.loads(run_cli("stats", "--json", cap).stdout)
    planted = CAPTURES[name].count("--outage")
    assert len(d["outages"]) == planted * len(PAIRS[protocol])
    for topic, msgs in got.items():
        states = [doc["state"] for _t, doc in msgs]
        assert runs(states) == planted, (topic, states)  # each outage's seconds, one run each
        pair = topic.split("/")[3].replace("_to_", ">")
        mine = [o for o in d["outages"] if o["pair"] == pair]
        for t, doc in msgs:
            if doc["state"] == "down":  # a second down: no frame, shown as the seconds since the outage began
                assert doc["frames"] == 0 and doc["quality"] == doc["down_s"] > 0
                o = next(o for o in mine if o["start"] <= t / NS + 1 <= o["end"])
                assert doc["down_s"] == pytest.approx(t / NS + 1 - o["start"], abs=1e-3)
            else:
                assert doc["down_s"] is None and doc["quality"] == doc["frames"]


@pytest.mark.parametrize("transport", ["tcp", "udp"])
def test_sip_lines_break_at_the_robots_outages(tmp_path, transport):
    """The SharedLink values' rule on a P2OS robot's ``sip`` topic (sl_foxglove.check_gaps'
    check): one gap message an outage of the robot>client link, 1 ns after its start (the SIP
    before the silence), every number of that SIP "NaN"; a blackboard session's one ``messages``
    topic gets none."""
    cap, out = tmp_path / "p.pcapng", tmp_path / "p.mcap"
    run_cli("gen", "-o", cap, "--duration", "20", "--protocol", "p2os", "--transport", transport,
            "--outage", "8:3", "--outage", "14:1.5")
    run_cli("export", cap, "-o", out)
    with open(out, "rb") as fh:
        sips = [(m.log_time, json.loads(m.data)) for _s, _c, m in mcap_reader.make_reader(fh).iter_messages(
            topics=["/p2os/1/sip"], log_time_order=True)]
    outages = json.loads(run_cli("stats", "--json", cap).stdout)["outages"]
    assert len(outages) == 2
    if transport == "tcp":  # (the SIP and the ENCODER after it in one segment: the outage starts at the SIP)
        check_gaps(sips, outages)
    else:  # (a datagram each: it starts at the ENCODER 0.2 ms after the SIP)
        gaps = [i for i, (_t, doc) in enumerate(sips) if is_gap(doc)]
        assert len(gaps) == len(outages)
        for i, o in zip(gaps, sorted(outages, key=lambda o: o["start"])):
            assert abs(sips[i][0] - 1 - o["start"] * NS) < 1000 and sips[i - 1][0] < sips[i][0]
            assert sips[i + 1][0] >= o["end"] * NS - 1000 and set(sips[i][1]) == {
                n for n, v in sips[i - 1][1].items() if type(v) in (int, float)}
    bb, bbout = tmp_path / "b.pcapng", tmp_path / "b.mcap"
    run_cli("gen", "-o", bb, "--duration", "12", "--protocol", "blackboard", "--outage", "5:3")
    run_cli("export", bb, "-o", bbout)
    with open(bbout, "rb") as fh:
        assert not [m for _s, c, m in mcap_reader.make_reader(fh).iter_messages() if not c.topic.endswith("/link_quality")
                    and is_gap(json.loads(m.data))]
