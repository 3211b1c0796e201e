"""Progress bars: on a terminal (after a while), never on a pipe or with --json/--quiet.

The commands run in a real pseudo-terminal; SHAREDLINK_PROGRESS_AFTER=0 shows the bar at once
(by default it waits 2 s, longer than these small captures take).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli
from sl_pipes import on_pty

from sharedlink.generators.beacon import GenOptions, generate_file

CLI = [sys.executable, "-m", "sharedlink"]


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("progress") / "c.pcap"
    generate_file(GenOptions(frames=20_000, compress=True, seed=1), p)
    return p


@pytest.fixture(scope="module")
def transform_capture(tmp_path_factory) -> Path:
    """Compress and expand give progress every 4096 records: 9,000 frames give it twice (the
    20,000 of ``capture`` timed each of their three runs at about 3 s on a loaded machine)."""
    p = tmp_path_factory.mktemp("progress") / "t.pcap"
    generate_file(GenOptions(frames=9_000, compress=True, seed=1), p)
    return p


def _run(args: list, tty: bool, after: str = "0") -> tuple[int, str]:
    """Run the CLI with stdout and stderr on a pseudo-terminal (``tty``) or pipes; its stderr."""
    env = dict(os.environ, SHAREDLINK_PROGRESS_AFTER=after, COLUMNS="120")
    if not tty:
        r = run_cli(*map(str, args), timeout=120, env=env)
        return r.returncode, r.stderr
    return on_pty([*CLI, *map(str, args)], env)


def test_a_terminal_gets_a_progress_bar(capture):
    rc, err = _run(["stats", capture], tty=True)
    assert rc == 0 and "reading:" in err and "records" in err, err[-2000:]


def test_no_bar_before_its_time(capture):
    rc, err = _run(["stats", capture], tty=True, after="600")
    assert rc == 0 and "reading:" not in err


@pytest.mark.parametrize("args", [["stats", "--json"], ["export", "--format", "jsonl", "--json", "-o", "OUT"],
                                  ["export", "--format", "jsonl"]])
def test_no_bar_with_json_or_to_standard_output(capture, tmp_path, args):
    args = [a if a != "OUT" else tmp_path / "o.jsonl" for a in args]
    rc, err = _run([args[0], capture, *args[1:]], tty=True)
    assert rc == 0 and "reading:" not in err and "exporting:" not in err


def test_no_bar_on_a_pipe(capture, tmp_path):
    for args in (["stats", capture], ["export", capture, "-o", tmp_path / "o.csv"]):
        rc, err = _run(args, tty=False)
        assert rc == 0 and "reading:" not in err and "exporting:" not in err


def test_export_to_a_file_gets_a_bar(capture, tmp_path):
    rc, err = _run(["export", capture, "-o", tmp_path / "o.csv"], tty=True)
    assert rc == 0 and "exporting:" in err


def test_plot_to_a_file_gets_a_bar(capture, tmp_path):
    rc, err = _run(["plot", capture, "-o", tmp_path / "p.png"], tty=True)
    assert rc == 0 and "plotting:" in err and "records" in err, err[-2000:]


def test_ingest_gets_a_bar_but_not_with_quiet_json_or_on_a_pipe(capture, tmp_path):
    """ingest's bar counts the bytes and records of every capture (one worker: while each is
    decoded)."""
    rc, err = _run(["ingest", capture, "-o", tmp_path / "ds"], tty=True)
    assert rc == 0 and "ingesting:" in err and "records" in err, err[-2000:]
    for i, extra in enumerate((["--quiet"], ["--json"])):
        rc, err = _run(["ingest", capture, "-o", tmp_path / f"ds{i}", *extra], tty=True)
        assert rc == 0 and "ingesting:" not in err
    rc, err = _run(["ingest", capture, "-o", tmp_path / "ds-pipe"], tty=False)
    assert rc == 0 and "ingesting:" not in err


def test_ingest_progress_covers_every_capture(tmp_path):
    """The library's progress: bytes grow to the captures' total size, records to theirs."""
    from sharedlink.fleet.ingest import ingest

    caps = []
    for i in range(2):
        caps.append(tmp_path / f"c{i}.pcap")
        generate_file(GenOptions(frames=9000, seed=i + 1), caps[-1])
    calls: list[tuple[int, int]] = []
    report = ingest(caps, tmp_path / "ds", progress=lambda b, r: calls.append((b, r)))
    assert report.ok
    assert calls[-1] == (sum(c.stat().st_size for c in caps), 18000)
    assert [b for b, _ in calls] == sorted(b for b, _ in calls) and len(calls) > 3


@pytest.mark.parametrize("command,what", [("compress", "compressing"), ("expand", "expanding")])
def test_compress_and_expand_get_a_bar_but_not_with_json_or_on_a_pipe(transform_capture, tmp_path, command, what):
    capture = transform_capture
    rc, err = _run([command, capture, "-o", tmp_path / "o.pcap"], tty=True)
    assert rc == 0 and f"{what}:" in err and "records" in err, err[-2000:]
    rc, err = _run([command, capture, "-o", tmp_path / "j.pcap", "--json"], tty=True)
    assert rc == 0 and f"{what}:" not in err
    rc, err = _run([command, capture, "-o", tmp_path / "p.pcap"], tty=False)
    assert rc == 0 and f"{what}:" not in err


@pytest.mark.parametrize("extra", [[], ["--single-process"]])
def test_diff_gets_a_bar_but_not_with_json_or_on_a_pipe(capture, extra):
    rc, err = _run(["diff", capture, capture, *extra], tty=True)
    assert rc == 0 and "comparing:" in err and "frames" in err, err[-2000:]
    rc, err = _run(["diff", capture, capture, "--json", *extra], tty=True)
    assert rc == 0 and "comparing:" not in err
    rc, err = _run(["diff", capture, capture, *extra], tty=False)
    assert rc == 0 and "comparing:" not in err


def test_transform_progress_counts_bytes_and_records(capture, tmp_path):
    """The library's progress: records every few thousand, bytes growing towards the size."""
    from sharedlink.analysis.transform import transform_capture

    calls: list[tuple[int, int]] = []
    st = transform_capture(capture, tmp_path / "o.pcap", "expand", progress=lambda b, r: calls.append((b, r)))
    assert len(calls) >= 3 and calls == sorted(calls)
    assert calls[-1][1] <= st.records and st.records - calls[-1][1] < 5000
    size = capture.stat().st_size
    assert 0 < calls[-1][0] <= size and calls[-1][0] / calls[-1][1] * st.records == pytest.approx(size, rel=0.05)


@pytest.mark.parametrize("parallel", [True, False])
def test_diff_progress_counts_both_captures(tmp_path, parallel):
    """diff's progress, from the parent as chunks arrive: bytes of both files, frames of both."""
    from sharedlink.analysis.diff import DiffOptions, diff_captures

    caps = []
    for i, n in enumerate((60_000, 30_000)):
        caps.append(tmp_path / f"c{i}.pcap")
        generate_file(GenOptions(frames=n, seed=i + 1), caps[-1])
    calls: list[tuple[int, int]] = []
    report = diff_captures(*caps, DiffOptions(parallel=parallel), progress=lambda b, f: calls.append((b, f)))
    assert len(calls) >= 3 and calls == sorted(calls)
    assert calls[-1][1] == report.a.frames + report.b.frames == 90_000
    total = sum(c.stat().st_size for c in caps)
    assert total * 0.9 < calls[-1][0] <= total
