"""export: `export --format mcap` against `export --format jsonl` on the same capture.

A compressed 15,000-frame beacon capture is exported both ways in this process, interleaved,
best of three each. Figures are CPU time of the process (foxglove-sdk's writer threads
included), which a loaded shared machine disturbs less than wall time; frames/s are per CPU
second.
"""

from __future__ import annotations

import time
from pathlib import Path

from bench import Result
from sharedlink.analysis.export import ExportOptions, export_file
from sharedlink.generators.beacon import GenOptions, generate_file

FRAMES = 15_000
ROUNDS = 3


def cpu_seconds(cap: Path, out: Path, fmt: str) -> float:
    t = time.process_time()
    result = export_file(cap, out, ExportOptions(fmt=fmt))
    spent = time.process_time() - t
    assert result.frames == FRAMES and result.error is None, result
    return spent


def run(work: Path) -> list[Result]:
    cap = work / "export.pcap"
    generate_file(GenOptions(frames=FRAMES, compress=True), cap)
    best = {"jsonl": float("inf"), "mcap": float("inf")}
    for _ in range(ROUNDS):
        for fmt in best:
            best[fmt] = min(best[fmt], cpu_seconds(cap, work / f"export.{fmt}", fmt))
    ratio = best["jsonl"] / best["mcap"]
    return [
        Result(
            "export mcap vs jsonl (CPU time)",
            f"{FRAMES / best['mcap']:,.0f} frames/s",
            f"{FRAMES / best['jsonl']:,.0f} frames/s",
            ratio,
            ">= 1x",
            ratio >= 1.0,
        )
    ]
