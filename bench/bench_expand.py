"""expand against stats, one line for each kind of capture `sharedlink gen` makes: `sharedlink
expand` of the capture against `sharedlink stats` of the same file, in CPU time (user + system of
each command's process, as a user runs it; best of ``ROUNDS``). Issue 39's target: expand at
most 2x stats' CPU on every kind (before expand's run taker, analysis/core/expand.py, about 19x on
named compressed frames; before its positional lanes and pcapng records, 2.6-3.3x on positional
frames and 6-7x on a pcapng file).

The kinds: SharedLink beacons (``FRAMES`` frames) named and positional, full and compressed, with
faults (drops and bad checksums), in pcap and pcapng; a SharedLink serial session (a fortieth of
``FRAMES``: stats reads serial frames at a twentieth of the speed); a P2OS and a blackboard robot session
(their frames are copied as they are, as expand copies every frame that is not a SharedLink
value frame).
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

from bench import Result, load_now, load_since

FRAMES = int(os.environ.get("SHAREDLINK_BENCH_FRAMES", "200000"))
ROUNDS = int(os.environ.get("SHAREDLINK_BENCH_ROUNDS", "2"))
CLI = [sys.executable, "-m", "sharedlink"]
FAULTS = ["--drop", "0.01", "--bad-checksum", "0.01"]
#: (name, file name, `gen` options)
KINDS: list[tuple[str, str, list[str]]] = [
    ("named full", "named-full.pcap", []),
    ("named compressed", "named-comp.pcap", ["--compress"]),
    ("named compressed, faults", "named-faults.pcap", ["--compress", *FAULTS]),
    ("positional full", "pos-full.pcap", ["--form", "positional"]),
    ("positional compressed", "pos-comp.pcap", ["--form", "positional", "--compress"]),
    ("positional compressed, faults", "pos-faults.pcap", ["--form", "positional", "--compress", *FAULTS]),
    ("named compressed, pcapng", "named-comp.pcapng", ["--compress"]),
    ("positional compressed, pcapng", "pos-comp.pcapng", ["--form", "positional", "--compress"]),
]
#: (name, file name, `gen` options) with their own length
SESSIONS: list[tuple[str, str, list[str]]] = [
    ("serial session", "serial.pcapng", ["--frames", str(max(FRAMES // 40, 100)), "--compress", "--transport", "serial"]),
    ("P2OS robot session", "p2os.pcap", ["--protocol", "p2os", "--duration", str(max(FRAMES // 65, 60))]),
    ("blackboard robot session", "blackboard.pcap", ["--protocol", "blackboard", "--duration", str(max(FRAMES // 65, 60))]),
]


def cpu(cmd: list[str]) -> float:
    """The least CPU seconds (user + system) of ``ROUNDS`` runs of ``cmd``."""
    best = float("inf")
    for _ in range(ROUNDS):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        best = min(best, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return best


def side_by_side(work: Path, name: str, file: str, gen: list[str]) -> Result:
    """One kind's line: the capture made, then stats and expand of it."""
    cap = work / f"expand-{file}"
    subprocess.run([*CLI, "gen", "-q", "-o", str(cap), *gen], check=True)
    started = load_now()
    stats = cpu([*CLI, "stats", str(cap)])
    expand = cpu([*CLI, "expand", str(cap), "-o", str(work / f"expanded-{file}"), "--force"])
    ratio = expand / stats
    return Result(f"expand vs stats, CPU ({name})", f"{expand:.2f} s", f"{stats:.2f} s", ratio, "<= 2x", ratio <= 2,
                  load_since(started))


def run(work: Path) -> list[Result]:
    kinds = [(f"{name}, {FRAMES:,} frames", file, ["--frames", str(FRAMES), *gen]) for name, file, gen in KINDS]
    return [side_by_side(work, *kind) for kind in kinds + SESSIONS]


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    import tempfile

    from bench import line

    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        for r in run(Path(tmp)):
            print(line(r))
