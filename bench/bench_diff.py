"""diff: `sharedlink diff` of a full 1,000,000-frame beacon capture against its compressed form.

1. Throughput against a bare dpkt loop that only iterates over the packets of the same two
   files (``for ts, buf in dpkt.pcap.Reader(f): pass``), interleaved, best of three each: the
   default diff (each capture read in its own process) and the single-process diff
   (``--single-process``), so the second ratio shows the code's speed, not the extra core.
2. Memory: the CLI in a subprocess on 100,000-frame and on 1,000,000-frame captures; peak RSS
   (``ru_maxrss`` of the subprocess and its reader processes, from ``wait4``). Streaming means
   the two figures are about equal.
3. For the record, what compression saves on the default 60 s drive (the bulletin claims about
   60% for the beacon).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from bench import Result
from sharedlink.analysis.diff import DiffOptions, diff_captures
from sharedlink.generators.beacon import GenOptions, generate_file

BIG = 1_000_000
SMALL = 100_000
ROUNDS = 3


def dpkt_loop(paths: list[Path]) -> None:
    import dpkt

    for p in paths:
        with open(p, "rb") as f:
            for _ts, _buf in dpkt.pcap.Reader(f):
                pass


def peak_rss_mb(a: Path, b: Path) -> tuple[float, int]:
    """Run the CLI diff in a subprocess; its peak RSS (MB) and exit code."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sharedlink", "diff", str(a), str(b), "--json"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return usage.ru_maxrss / 1024, proc.returncode


def run(work: Path) -> list[Result]:
    files = {}
    for n in (SMALL, BIG):
        for compress in (False, True):
            p = work / f"diff-{n}-{'comp' if compress else 'full'}.pcap"
            generate_file(GenOptions(frames=n, compress=compress), p)
            files[n, compress] = p
    a, b = files[BIG, False], files[BIG, True]
    best_diff = best_single = best_dpkt = float("inf")
    agree = True
    for _ in range(ROUNDS):
        t = time.perf_counter()
        dpkt_loop([a, b])
        best_dpkt = min(best_dpkt, time.perf_counter() - t)
        t = time.perf_counter()
        report = diff_captures(a, b, DiffOptions())
        best_diff = min(best_diff, time.perf_counter() - t)
        agree = agree and report.agree and report.pairs == BIG
        t = time.perf_counter()
        report = diff_captures(a, b, DiffOptions(parallel=False))
        best_single = min(best_single, time.perf_counter() - t)
        agree = agree and report.agree and report.pairs == BIG
    frames = 2 * BIG
    ratio = best_dpkt / best_diff
    single_ratio = best_dpkt / best_single
    rss_small, rc_small = peak_rss_mb(files[SMALL, False], files[SMALL, True])
    rss_big, rc_big = peak_rss_mb(a, b)
    mem_ratio = rss_big / rss_small
    results = [
        Result(
            "diff 2x1M frames vs dpkt loop" + ("" if agree else " (DISAGREED!)"),
            f"{frames / best_diff:,.0f} frames/s",
            f"{frames / best_dpkt:,.0f} frames/s",
            ratio,
            ">= 1x",
            ratio >= 1.0 and agree,
        ),
        Result(
            "diff single process vs dpkt loop (info)" + ("" if agree else " (DISAGREED!)"),
            f"{frames / best_single:,.0f} frames/s",
            f"{frames / best_dpkt:,.0f} frames/s",
            single_ratio,
            "info",
            agree,
        ),
        Result(
            "diff peak RSS 1M vs 100k frames" + ("" if rc_small == rc_big == 0 else " (CLI FAILED)"),
            f"{rss_big:.1f} MB at 1M",
            f"{rss_small:.1f} MB at 100k",
            mem_ratio,
            "<= 1.2x",
            mem_ratio <= 1.2 and rc_small == rc_big == 0,
        ),
    ]
    # what the default 60 s drive really saves (informational: the bulletin says about 60%)
    full60, comp60 = work / "drive60-full.pcap", work / "drive60-comp.pcap"
    generate_file(GenOptions(), full60)
    generate_file(GenOptions(compress=True), comp60)
    r60 = diff_captures(full60, comp60, DiffOptions(parallel=False))
    saving = r60.saving_payload or 0.0
    results.append(
        Result(
            "compression saving, 60 s drive (info)",
            f"{saving:.1%} of SL bytes",
            "bulletin: ~60%",
            saving / 0.6,
            "info",
            r60.agree,
        )
    )
    return results
