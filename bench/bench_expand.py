"""expand against stats: `sharedlink expand` of a 200,000-frame compressed beacon capture against
`sharedlink stats` of the same file, in CPU time (user + system of each command's process, as a
user runs it; best of ``ROUNDS``). Issue 39's target: expand at most 2x stats' CPU (it was
about 19x before expand's run taker, analysis/core/expand.py).
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

from bench import Result, load_now, load_since
from sharedlink.generators.beacon import GenOptions, generate_file

FRAMES = int(os.environ.get("SHAREDLINK_BENCH_FRAMES", "200000"))
ROUNDS = int(os.environ.get("SHAREDLINK_BENCH_ROUNDS", "2"))
CLI = [sys.executable, "-m", "sharedlink"]


def cpu(cmd: list[str]) -> float:
    """The least CPU seconds (user + system) of ``ROUNDS`` runs of ``cmd``."""
    best = float("inf")
    for _ in range(ROUNDS):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        best = min(best, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return best


def run(work: Path) -> list[Result]:
    cap = work / "expand-200k.pcap"
    generate_file(GenOptions(frames=FRAMES, compress=True), cap)
    started = load_now()
    stats = cpu([*CLI, "stats", str(cap)])
    expand = cpu([*CLI, "expand", str(cap), "-o", str(work / "expanded.pcap"), "--force"])
    ratio = expand / stats
    return [Result(f"expand vs stats, CPU ({FRAMES:,} compressed frames)", f"{expand:.2f} s", f"{stats:.2f} s", ratio,
                   "<= 2x", ratio <= 2, load_since(started))]


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    import tempfile

    from bench import line

    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        for r in run(Path(tmp)):
            print(line(r))
