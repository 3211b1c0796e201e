"""Malformed blackboard messages (docs/fields-p2os-blackboard.md, "Malformed messages"): text from
a type character that does not read as a good message (too short, a wrong count, odd digits,
non-hex, no CR) is a message, malformed, in both decoders: blackboard.lua shows it (its type, its
expert) and the Python session reader gives it as the master's message of kind ``malformed``
(no decoded message, the reason in ``error``), so `stats`, `export` and `health` count it where
the dissector shows it; before the rule Python counted it as noise. On golden_small's
bb-edge.pcap (frames 11, 12, 13, 16 and 23), with the link health of the -z sharedlink,stats
tap and `stats --json` the same."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import sl_cli
from sl_agreement import health_tap
from sl_robots import OTHERS

import tshark_util as tu
from sharedlink.analysis.sessions import iter_sessions

EDGE = Path(__file__).resolve().parent / "golden_small" / "bb-edge.pcap"
PREFS = {"blackboard.udp_port": "7100"}
MALFORMED = [11, 12, 13, 16, 23]  # make_inputs.bb_edge: too short, count wrong, odd digits, non-hex, no CR
TRUNCATED = "Read response truncated"


def test_lua_and_python_give_the_same_messages_frame_by_frame() -> None:
    rows = tu.fields(EDGE, ["blackboard.type"], prefs=PREFS, extra=OTHERS, two_pass=True)
    # a read response cut off at a datagram's end is noise to Python ("Over UDP")
    lua = {n: len(r["blackboard.type"]) - (TRUNCATED in r["_ws.expert.message"]) for n, r in enumerate(rows, 1)}
    msgs = list(iter_sessions(EDGE))
    py = Counter(m.number for m in msgs)
    assert {n: c for n, c in lua.items() if c} == dict(py)
    bad = [m for m in msgs if m.message is None]
    assert [m.number for m in bad] == MALFORMED
    assert all(m.side == "master" and m.error for m in bad)
    assert all(rows[n - 1]["blackboard.type"] in (["set"], ["request"]) for n in MALFORMED)


def test_stats_export_and_health_count_them() -> None:
    stats = json.loads(sl_cli.run_cli("stats", "--json", EDGE, check=True).stdout)
    types = {(t["side"], t["type"]): t["messages"] for t in stats["blackboard"]["types"]}
    assert types[("master", "malformed")] == len(MALFORMED)
    assert stats["blackboard"]["packets"] == sum(types.values())
    rows = [json.loads(x) for x in sl_cli.run_cli("export", "--format", "jsonl", "-o", "-", EDGE,
                                                  check=True).stdout.splitlines()]
    bb = {r["number"]: r for r in rows if r.get("protocol") == "blackboard"}
    assert sorted(n for n, r in bb.items() if r["type"] == "malformed") == MALFORMED
    assert all(bb[n]["error"] for n in MALFORMED)
    # link health: the tap (blackboard.lua with sharedlink.lua) and stats --json, frames and bad checksums
    _outs, links, _text = health_tap(EDGE, prefs=PREFS, robots=True)
    tap = {pair: (int(cols[0]), cols[6]) for (_link, pair), cols in links.items()}
    py = {lk["pair"]: (lk["frames"], "%.2f" % lk["bad_checksum_pct"]) for lk in stats["links"]}
    assert tap == py
    assert tap["master>slave"][0] == 14


# (every golden_small blackboard input, message by message: test_robot_frames_agree.py)
