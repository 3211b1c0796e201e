"""Issue 43, agreement beyond the generated fault captures (test_health_tap.py has those): the
-z sharedlink,stats tap, `stats`, `export --outages`, `ingest` and `watch --json --outages`
report the same outages (count, links, open or not, start and duration to the microsecond) on
the shared vector streams (tests/vectors/sharedlink*.json, the real-session ones included), and
`watch` over loopback (a `replay` of a capture with a planted outage, its arrival times) the
same outage as `stats` on the capture.

The vector streams are short (a second or so each): played one after another in one capture, 40
s apart, a link that recurs in a later stream has an outage between; with a threshold of 0.15 s
(`--outage-after`, the `outage_after` preference) their own 0.2 s spacings are outages too."""

from __future__ import annotations

import copy
import json
import os
import select
import signal
import socket
import subprocess
import time
from functools import partial
from pathlib import Path

import pytest
import sl_cli
from sl_agreement import exported_outages, health_tap, ingest, ingested_outages, python_outages, same_outages
from sl_cli import CLI
from sl_vectors import load_streams, write_stream

from sharedlink.capture.pcapio import NS, read_records

APART_S = 40
THRESHOLD = "0.15"


#: every run here must succeed
run_cli = partial(sl_cli.run_cli, check=True, timeout=300)


@pytest.fixture(scope="module")
def vector_caps(tmp_path_factory) -> dict[str, Path]:
    """The vector streams of each transport one after another in one capture, APART_S apart."""
    d = tmp_path_factory.mktemp("vectors")
    out = {}
    by: dict[str, list] = {}
    for s in load_streams():
        by.setdefault(s.get("transport", "udp"), []).append(s)
    for transport, streams in by.items():
        packets = []
        for k, s in enumerate(streams):
            for p in s["packets"]:
                p = copy.deepcopy(p)
                p["t"] = float(p["t"]) + k * APART_S
                packets.append(p)
        name = f"{transport}-{len(streams)}-streams"
        out[name] = write_stream({"name": name, "transport": transport, "packets": packets},
                                 d / (name + (".pcapng" if transport == "serial" else ".pcap")))
    return out


def _stats_rows(path: Path, *extra: object) -> list[dict]:
    return json.loads(run_cli("stats", "--json", path, *extra).stdout)["outages"]


@pytest.mark.parametrize("threshold", [None, THRESHOLD])
def test_tap_stats_export_watch_on_the_vectors(vector_caps, threshold):
    extra = ("--outage-after", threshold) if threshold else ()
    prefs = {"sharedlink.outage_after": threshold} if threshold else None
    seen = 0
    for name, cap in vector_caps.items():
        want, links = python_outages(cap, *extra)
        got, tap_links, _ = health_tap(cap, prefs)
        same_outages(got, want)
        assert set(tap_links) == {(lk["link"], lk["pair"]) for lk in links}, name
        for lk in links:
            assert tap_links[(lk["link"], lk["pair"])][0] == str(lk["frames"]), (name, lk)
        rows = _stats_rows(cap, *extra)
        assert exported_outages(run_cli("export", "--format", "jsonl", "--outages", *extra, cap).stdout) == rows
        if not threshold:  # (watch learns each link's threshold; it has no --outage-after)
            watched = run_cli("watch", cap, "--speed", "1000", "--json", "--outages", "-q").stdout
            assert exported_outages(watched) == rows
        seen += len(rows)
    assert seen >= (100 if threshold else 30)  # (links that recur; with the threshold, their own spacings)


def test_ingest_on_the_vectors(vector_caps, tmp_path):
    ds = ingest(tmp_path, vector_caps.values())
    for cap in vector_caps.values():
        want, _links = python_outages(cap)
        assert ingested_outages(ds, cap) == want


def test_the_vectors_have_no_outage_alone(tmp_path):
    """Each stream by itself (no link recurs): no outage (its spacings are at most 1 s, never
    more than the 1 s floor); the capture of them all has some (the fixture's are not empty)."""
    from sharedlink.analysis.stats import capture_stats

    for s in load_streams():
        cap = write_stream(s, tmp_path / ("s.pcapng" if s.get("transport") == "serial" else "s.pcap"))
        assert capture_stats(cap).health.outages() == [], s["name"]


# -- watch over loopback -------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _read_until(p: subprocess.Popen, done, deadline_s: float = 120) -> list[dict]:
    """watch's JSON lines until ``done(lines)`` (waiting on its output, never on the clock alone)."""
    fd = p.stdout.fileno()  # type: ignore[union-attr]
    buf, lines = b"", []
    end = time.monotonic() + deadline_s
    while not done(lines):
        ready, _, _ = select.select([fd], [], [], max(0.0, end - time.monotonic()))
        assert ready, f"watch printed {len(lines)} lines, then nothing"
        chunk = os.read(fd, 65536)
        assert chunk, f"watch ended: rc={p.poll()}"
        buf += chunk
        *whole, buf = buf.split(b"\n")
        lines += [json.loads(x) for x in whole if x]
    return lines


@pytest.mark.live
def test_watch_over_loopback_sees_the_outage_stats_sees(tmp_path):
    """replay at the capture's pace to a port the watch binds: the outage watch reports from the
    arrival times is the one stats finds in the capture (same pair; start and duration within
    the loopback's scheduling, 0.1 s)."""
    cap = tmp_path / "o.pcap"
    run_cli("gen", "-o", cap, "--duration", "6", "--outage", "2:2", "-q")
    frames = sum(1 for _ in read_records(cap))
    (want,) = _stats_rows(cap)
    first = next(iter(read_records(cap))).ts_ns / NS
    port = _free_port()
    w = subprocess.Popen([*CLI, "watch", "--port", str(port), "--bind-port", "--listen", "127.0.0.1", "--json",
                          "--outages"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        while b"(bound by the watch)" not in (line := w.stderr.readline()):  # type: ignore[union-attr]
            assert line, f"watch ended early: rc={w.poll()}"
        run_cli("replay", cap, "--to", f"127.0.0.1:{port}", "-q")
        lines = _read_until(w, lambda ls: sum(x["kind"] != "outage" for x in ls) >= frames)
    finally:
        w.send_signal(signal.SIGINT)
        _out, err = w.communicate(timeout=60)
    assert w.returncode == 0 and b"Traceback" not in err, err
    rows = [x for x in lines if x["kind"] == "outage"]
    assert len(rows) == 1, rows
    (got,) = rows
    t0 = next(x for x in lines if x["kind"] != "outage")["ts_ns"] / NS
    assert got["pair"] == want["pair"] and got["end"] is not None
    assert abs(got["duration_s"] - want["duration_s"]) < 0.1, (got, want)
    assert abs((got["start"] - t0) - (want["start"] - first)) < 0.1, (got, want)
    after = lines[lines.index(got) + 1]  # (the line after it: the frame that ends it)
    assert after["kind"] != "outage" and after["ts_ns"] / NS == pytest.approx(got["end"], abs=1e-6)
