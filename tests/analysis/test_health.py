"""Link health (issue 43): learnt rates, outages, quality per second, the checksum habit, on real
generated captures through `sharedlink stats` and `gen --outage`, and the fast count tier's
feed (Health.run) against the frame-by-frame one (Health.frame) on the same times."""

from __future__ import annotations

import json
import random
from collections import Counter
from pathlib import Path

import pytest
from sl_cli import run_cli

from sharedlink.analysis.health import FLOOR_S, Health, SecondCounts, quality, quality_runs
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import NS, PcapWriter
from sharedlink.generators.beacon import DEFAULT_START_NS
from sharedlink.protocols.codec import checksum

T0 = DEFAULT_START_NS / NS

#: the real rates issue 43 names: (gen options) -> none of them has an outage or a late full set
REAL = {
    "vehicle-6.5Hz-full-sets-1s": ["--rate", "6.5", "--compress", "--jitter", "30"],
    "client-14Hz": ["--rate", "14", "--compress", "--jitter", "20"],
    "bul110-40Hz": ["--rate", "40", "--jitter", "5"],
    "generator-5Hz": [],
}


def stats_json(path: Path, *extra: object) -> dict:
    r = run_cli("stats", "--json", path, *extra)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def gen(path: Path, *args: object) -> Path:
    r = run_cli("gen", "-o", path, "--duration", 60, *args)
    assert r.returncode == 0, r.stderr
    return path


@pytest.mark.parametrize("name", list(REAL))
def test_real_rates_no_outage_then_one(tmp_path, name):
    plain = stats_json(gen(tmp_path / "plain.pcap", *REAL[name]))
    assert plain["outages"] == []
    assert plain["sync_late"] == 0
    (link,) = plain["links"]
    rate = float(REAL[name][1]) if REAL[name] else 5.0
    assert link["rate_hz"] == pytest.approx(rate, rel=0.1)
    assert link["availability"] == 1.0
    planted = stats_json(gen(tmp_path / "planted.pcap", *REAL[name], "--outage", "20:3"))
    (o,) = planted["outages"]
    assert o["pair"] == "B>A" and o["link"] == link["link"]
    # from the last frame before 20 s to the first at or after 23 s (jitter: within it)
    assert 19.0 < o["start"] - T0 <= 20.0 + 0.05
    assert 23.0 - 0.05 <= o["end"] - T0 < 24.0
    assert o["duration_s"] == pytest.approx(o["end"] - o["start"], abs=1e-6)
    assert o["duration_s"] >= 3.0 - 0.1
    (lk,) = planted["links"]
    assert lk["outages"] == 1 and lk["longest_outage_s"] == o["duration_s"]
    assert lk["availability"] == pytest.approx(1 - o["duration_s"] / (lk["last"] - lk["first"]), abs=1e-9)


def test_exact_outage_times(tmp_path):
    """5 Hz, a 3 s silence at 10 s: frames at 9.8 and 13.0 s, an outage of 3.2 s to the microsecond."""
    d = stats_json(gen(tmp_path / "a.pcap", "--outage", "10:3", "--outage", "40:1.5"))
    assert [(round(o["start"] - T0, 6), round(o["end"] - T0, 6), round(o["duration_s"], 6)) for o in d["outages"]] == [
        (9.8, 13.0, 3.2), (39.8, 41.6, 1.8)]


def test_threshold_option_and_fail_on(tmp_path):
    cap = gen(tmp_path / "a.pcap", "--outage", "10:3", "--outage", "40:1.5")
    assert len(stats_json(cap, "--outage-after", 2.5)["outages"]) == 1
    assert len(stats_json(cap, "--outage-after", 0.3)["outages"]) == 2
    r = run_cli("stats", cap, "--fail-on", "outage")
    assert r.returncode == 1 and "outage" in r.stderr
    r = run_cli("stats", gen(tmp_path / "b.pcap"), "--fail-on", "outage")
    assert r.returncode == 0, r.stderr
    assert "Link health" in r.stdout


@pytest.mark.parametrize("args, message", [
    (["stats", "{cap}", "--outage-after", "0"], "--outage-after"),
    (["stats", "{cap}", "--outage-after=-1"], "--outage-after"),
    (["stats", "{cap}", "--fail-on", "nothing"], "--fail-on"),
    (["gen", "-o", "{out}", "--outage", "10:0"], "more than 0"),
    (["gen", "-o", "{out}", "--outage", "10:-2"], "more than 0"),
    (["gen", "-o", "{out}", "--outage=-1:2"], "negative"),
    (["gen", "-o", "{out}", "--duration", "30", "--outage", "29:2"], "past the end"),
    (["gen", "-o", "{out}", "--outage", "ten"], "START:DURATION"),
    (["gen", "-o", "{out}", "--protocol", "p2os", "--duration", "5", "--outage", "4:2"], "past the end"),  # (issue 42:
    (["gen", "-o", "{out}", "--protocol", "blackboard", "--outage", "1:-1"], "more than 0"),  # robot sessions too)
])
def test_bad_values(tmp_path, args, message):
    cap = gen(tmp_path / "a.pcap")
    r = run_cli(*(a.format(cap=cap, out=tmp_path / "o.pcap") for a in args))
    assert r.returncode == 2
    assert message in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o.pcap").exists()


def test_serial_outages(tmp_path):
    """The vehicle silenced twice on a serial link: its direction's outages, the host's side up."""
    cap = tmp_path / "s.pcapng"
    r = run_cli("gen", "-o", cap, "--transport", "serial", "--duration", 30, "--outage", "10:3", "--outage", "20:2")
    assert r.returncode == 0, r.stderr
    d = stats_json(cap)
    assert [o["pair"] for o in d["outages"]] == ["B>A", "B>A"]
    assert [round(o["duration_s"]) for o in d["outages"]] == [3, 2]
    assert {lk["pair"]: lk["outages"] for lk in d["links"]} == {"B>A": 2, "A>B": 0}


def test_open_outage(tmp_path):
    """A link that stops while another goes on: an open outage to the capture's end."""
    body = b":AB|N0|T2|QAutoGpsLat|D1.5|C"
    frame = b"[" + body + b"%02X]\r\n" % checksum(body)
    a, b = UdpBuilder("10.0.0.2", "10.0.0.1", 7013, 7013), UdpBuilder("10.0.0.3", "10.0.0.1", 7013, 7013)
    with open(tmp_path / "o.pcap", "wb") as fh:
        w = PcapWriter(fh)
        for k in range(200):  # 10 Hz for 20 s; the first link stops after 10 s
            for n, builder in enumerate((a, b)):
                if n == 1 or k < 100:
                    w.write(DEFAULT_START_NS + k * NS // 10, builder.headers(len(frame), frame, k + 1) + frame)
    d = stats_json(tmp_path / "o.pcap")
    (o,) = d["outages"]
    assert o["link"] == "10.0.0.2:7013 > 10.0.0.1:7013" and o["end"] is None
    assert (round(o["start"] - T0, 6), round(o["duration_s"], 6)) == (9.9, 10.0)
    assert next(lk for lk in d["links"] if lk["outages"])["availability"] == pytest.approx(9.9 / 19.9)
    assert "(open)" in run_cli("stats", tmp_path / "o.pcap").stdout


def _stream(rng: random.Random, n: int) -> list[int]:
    ts, out = DEFAULT_START_NS, []
    for _ in range(n):
        r = rng.random()
        ts += (rng.randint(1, 3) * NS if r < 0.01 else 0 if r < 0.05 else -rng.randint(1, 10**8) if r < 0.07
               else rng.randint(5 * 10**7, 2 * 10**8))
        out.append(ts)
    return out


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("after", [None, 0.15])
def test_run_feed_is_frame_feed(seed, after):
    """The fast tier's runs give what frame by frame gives: outages, window, frames, seconds."""
    rng = random.Random(seed)
    stamps = _stream(rng, 3000)
    a, b = Health(after, timeline=True), Health(after, timeline=True)
    ha, hb = a.link(("udp", "1.2.3.4", 1, "5.6.7.8", 2), "B", "A"), b.link(("udp", "1.2.3.4", 1, "5.6.7.8", 2), "B", "A")
    for ts in stamps:
        a.frame(ha, ts, True)
    i = 0
    while i < len(stamps):
        k = rng.randint(1, 600)
        b.run(hb, stamps[i:i + k])
        i += k
    a.finish()
    b.finish()
    assert ha.outages and ha.outages == hb.outages
    assert (ha.frames, ha.first_ns, ha.last_ns, list(ha.window)) == (hb.frames, hb.first_ns, hb.last_ns, list(hb.window))
    assert list(quality(ha)) == list(quality(hb))


def test_learnt_threshold():
    """A 0.4 Hz link: 2.5 s periods are no outage (3 periods: 7.5 s), 8 s is; the first interval
    is never one under the learnt rule, then the floor (1 s) holds for a fast link."""
    h = Health()
    lk = h.link(("udp", "a", 1, "b", 2), "B", "A")
    t = DEFAULT_START_NS
    for step in [0, 2.5, 2.5, 2.5, 8.0, 2.5]:
        t += int(step * NS)
        h.frame(lk, t, True)
    h.finish()
    assert [o.duration_ns for o in lk.outages] == [int(8.0 * NS)]
    assert lk.rate_hz == pytest.approx(0.4)
    h2 = Health()
    lk2 = h2.link(("udp", "a", 1, "b", 2), "B", "A")
    for t in (0, 5, 20, int((FLOOR_S + 0.1) * NS) + 20):
        h2.frame(lk2, DEFAULT_START_NS + t, True)
    assert [o.duration_ns for o in lk2.outages] == [int((FLOOR_S + 0.1) * NS)]
    h3 = Health()
    lk3 = h3.link(("udp", "a", 1, "b", 2), "B", "A")
    for t in (0, 5 * NS):
        h3.frame(lk3, DEFAULT_START_NS + t, True)
    assert lk3.outages == []


def test_quality_seconds():
    """Shepherd's quality: frames in a second while up; seconds since the outage began while down."""
    h = Health(timeline=True)
    lk = h.link(("udp", "a", 1, "b", 2), "B", "A")
    t0 = DEFAULT_START_NS
    stamps = [t0 + k * NS // 5 for k in range(50)] + [t0 + 13 * NS + k * NS // 5 for k in range(10)]
    h.run(lk, stamps)
    h.finish()
    rows = {s.second - t0 // NS: (s.frames, s.down_s) for s in quality(lk)}
    assert rows[0] == (5, None) and rows[9] == (5, None)  # the outage starts at 9.8 s: a second with frames is up
    assert rows[10] == (0, pytest.approx(1.2)) and rows[12] == (0, pytest.approx(3.2))
    assert rows[13] == (5, None) and rows[14] == (5, None) and max(rows) == 14


def _quality_by_the_second(lk) -> list[tuple[int, int, float | None]]:
    """The module doc's definition, second by second: no frame in it and an outage in progress
    at its end (``start <= end of second <= outage end``): down, for the seconds since it began."""
    out = []
    for s in range(lk.first_ns // NS, lk.end_ns // NS + 1):
        at, frames = (s + 1) * NS, lk.seconds.get(s, 0)
        on = [o for o in lk.outages if o.start_ns <= at and (o.end_ns is None or o.end_ns >= at)]
        down = round((min(at, lk.end_ns) - on[0].start_ns) / NS, 3) if on and not frames else None
        out.append((s, frames, down))
    return out


@pytest.mark.parametrize("seed", range(4))
def test_quality_runs_are_the_definition(seed):
    """quality() and quality_runs() in any run size give the definition's seconds, across span
    (4,096 s) and day boundaries, with outages open and closed."""
    rng = random.Random(seed)
    h = Health(timeline=True)
    lk = h.link(("udp", "a", 1, "b", 2), "B", "A")
    t = DEFAULT_START_NS - DEFAULT_START_NS % (86400 * NS) + 86400 * NS - rng.randrange(9000) * NS
    for _ in range(rng.randrange(200, 1200)):
        t += rng.choice([NS // 10, NS // 5, NS // 3, 4 * NS, 70 * NS])
        h.frame(lk, t, True)
    h.finish(t + rng.choice([0, 30 * NS]))
    want = _quality_by_the_second(lk)
    assert [(s.second, s.frames, s.down_s) for s in quality(lk)] == want
    most, align = rng.choice([(7, 86400), (1000, 60), (65536, 86400)])
    runs = list(quality_runs(lk, most, align))
    assert [(first + i, f, d) for first, fs, ds in runs for i, (f, d) in enumerate(zip(fs, ds))] == want
    assert all(len(fs) <= most and first // align == (first + len(fs) - 1) // align for first, fs, _ in runs)
    assert any(d is not None for *_, d in want) == bool(lk.outages)


def test_second_counts_count_as_a_counter():
    """A link's timeline (SecondCounts) counts what a Counter would, across spans and far gaps,
    frame by frame and in batches; dropping spans keeps the seconds after."""
    rng = random.Random(7)
    base = DEFAULT_START_NS // NS
    seconds = [base + rng.choice([0, 1, 4095, 4096, 9000, 86400 * 400]) + rng.randrange(50) for _ in range(3000)]
    counts, want = SecondCounts(), Counter()
    for s in seconds[:1000]:
        counts.add(s)
        want[s] += 1
    counts.update(seconds[1000:])
    want.update(seconds[1000:])
    for s in set(seconds) | {base - 1, base + 5000, base + 86400 * 400 + 60}:
        assert counts.get(s, 0) == want[s], s
    assert counts.get(base - 1, -1) == -1
    lo, hi = base - 100, base + 9200  # (across three spans, the first partly before any frame)
    assert counts.counts(lo, hi) == [want[s] for s in range(lo, hi)]
    counts.drop_before(base + 86400 * 400)
    assert [counts.get(s) for s in sorted(want)] == [want[s] if s >= base + 86400 * 400 else 0 for s in sorted(want)]


def test_a_timeline_costs_a_few_bytes_a_second():
    """Issue 44: a day of one link's frames per second is held in well under 1 MB (a Counter took
    about 100 bytes a second: a long capture's ingest grew with its duration)."""
    import tracemalloc

    tracemalloc.start()
    try:
        counts = SecondCounts()
        base = DEFAULT_START_NS // NS
        before = tracemalloc.get_traced_memory()[0]
        for k in range(0, 86400, 10):  # a frame a second, in batches of 10 seconds
            counts.update(range(base + k, base + k + 10))
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert held < 600_000, held


def _write(path: Path, payloads: list[bytes]) -> None:
    b = UdpBuilder("10.0.0.2", "10.0.0.1", 7013, 7013)
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for k, p in enumerate(payloads):
            w.write(DEFAULT_START_NS + k * NS // 10, b.headers(len(p), p, k + 1) + p)


def test_checksum_habit(tmp_path):
    """A link that carried checksums and then sends frames without: the note; one that never had one: none."""
    body = b":AB|N0|T2|QAutoGpsLat|D1.5|C"
    with_sum = b"[" + body + b"%02X]\r\n" % checksum(body)
    without = b"[:AB|N0|T2|QAutoGpsLat|D1.6]\r\n"
    _write(tmp_path / "habit.pcap", [with_sum] * 5 + [without] * 3)
    _write(tmp_path / "never.pcap", [without] * 8)
    d = stats_json(tmp_path / "habit.pcap")
    assert d["links"][0]["checksum_missing"] == 3
    assert d["links"][0]["notes"] == ["checksum missing on a link that carries them"]
    assert stats_json(tmp_path / "never.pcap")["links"][0]["notes"] == []
    assert "checksum missing on a link that carries them" in run_cli("stats", tmp_path / "habit.pcap").stdout
