"""Issue 43: `export --format mcap` writes one link_quality topic per SharedLink link (JSON,
schema sharedlink.LinkQuality), a message per second at the second's start: the rows of
`sharedlink health -o -` (which hold stats' outages), read back with the independent `mcap`
reader; every message valid against its schema (test_foxglove_schemas.py checks every topic)."""

from __future__ import annotations

import json
from functools import partial

import pytest
import sl_cli
from sl_foxglove import quality_topics

pytest.importorskip("mcap.reader")  # (quality_topics reads the file)
pytest.importorskip("jsonschema")  # (quality_topics validates each message)

NS = 10**9


#: every run here must succeed
run_cli = partial(sl_cli.run_cli, check=True)


@pytest.mark.parametrize("gen", [
    ["--duration", "30", "--outage", "10:3", "--outage", "20:2"],
    ["--duration", "20", "--transport", "serial", "--rate", "14", "--outage", "5:4"],
    ["--duration", "30", "--compress", "--drop", "0.35", "--seed", "4"],
])
def test_link_quality_topics_are_the_health_rows(tmp_path, gen):
    cap, out = tmp_path / "c.pcapng", tmp_path / "c.mcap"
    run_cli("gen", "-o", cap, "--format", "pcapng", *gen)
    run_cli("export", cap, "-o", out)
    rows = [json.loads(x) for x in run_cli("health", "-o", "-", cap).stdout.splitlines()]
    assert rows
    got, meta = quality_topics(out)
    want: dict[str, list] = {}
    for r in rows:
        topic = "/sharedlink/" + r["pair"].replace(">", "_to_") + "/link_quality"
        assert meta[topic]["link"] == r["link"]
        want.setdefault(topic, []).append((r["second"] * NS, {k: r[k] for k in ("frames", "quality", "state", "down_s")}))
    assert got == want
    outages = json.loads(run_cli("stats", "--json", cap).stdout)["outages"]
    down = [(t, d) for msgs in got.values() for t, d in msgs if d["state"] == "down"]
    for t, d in down:  # a second down ends inside an outage, with no frame in it
        assert d["frames"] == 0 and d["quality"] == d["down_s"] > 0
        assert any(o["start"] <= t / NS + 1 <= (o["end"] or float("inf")) for o in outages)
    assert bool(down) == ("--outage" in gen) and outages  # (lossy: silences too short to fill a second)
