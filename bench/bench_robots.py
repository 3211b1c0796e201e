"""P2OS `stats` and `export --format jsonl` against tshark with the dissectors (issue 42's limit),
on one generated MobileSim session of about 200,000 P2OS packets (TCP port 8101).

CPU time (user + system of the child, from the operating system's accounting), best of
``ROUNDS``, each command in its own process as a user runs it; targets at least 5x:

* ``sharedlink stats`` against ``tshark -T fields`` of the P2OS packets' header, direction and
  checksum status with every dissector loaded (the counts ``stats --json`` gives under "p2os");
* ``sharedlink export --format jsonl`` against ``tshark -T ek -j p2os`` with the dissectors.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

from bench import Result, load_now, load_since
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file

PACKETS = int(os.environ.get("SHAREDLINK_BENCH_FRAMES", "200000"))
ROUNDS = int(os.environ.get("SHAREDLINK_BENCH_ROUNDS", "2"))
REPO = Path(__file__).resolve().parent.parent
SCRIPTS = [a for s in sorted((REPO / "dissector").glob("*.lua")) for a in ("-X", f"lua_script:{s}")]
CLI = [sys.executable, "-m", "sharedlink"]
#: packets a second of the generated session (a SIP and an ENCODER packet every 100 ms, commands)
PACKETS_PER_S = 21.14


def _env() -> dict[str, str]:
    # tshark with an empty configuration: no personal plugins or preferences
    return dict(os.environ, HOME="/nonexistent-sharedlink-bench", XDG_CONFIG_HOME="/nonexistent-sharedlink-bench")


def _cpu(cmd: list[str], out: Path | None = None) -> float:
    """The least user + system seconds of ``ROUNDS`` runs of ``cmd``."""
    best = float("inf")
    for _ in range(ROUNDS):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        with open(out or os.devnull, "wb") as fh:
            subprocess.run(cmd, stdout=fh, stderr=subprocess.DEVNULL, check=True, env=_env())
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        best = min(best, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return best


def run(work: Path) -> list[Result]:
    cap = work / "p2os-200k.pcap"
    gen = generate_p2os_file(P2osGenOptions(duration=PACKETS / PACKETS_PER_S), cap)
    results = []
    started = load_now()
    ours = _cpu([*CLI, "stats", "--json", str(cap)])
    theirs = _cpu(["tshark", "-n", *SCRIPTS, "-T", "fields", "-e", "p2os.header", "-e", "p2os.direction",
                   "-e", "p2os.checksum.status", "-r", str(cap)])
    results.append(Result(f"P2OS stats vs tshark -T fields, CPU ({gen.packets:,} packets)", f"{ours:.2f} s",
                          f"{theirs:.2f} s", theirs / ours, ">= 5x", theirs / ours >= 5, load_since(started)))
    started = load_now()
    ours = _cpu([*CLI, "export", "--format", "jsonl", str(cap)], work / "p2os.jsonl")
    theirs = _cpu(["tshark", "-n", *SCRIPTS, "-T", "ek", "-j", "p2os", "-r", str(cap)], work / "p2os.ek")
    results.append(Result("P2OS export jsonl vs tshark -T ek -j p2os, CPU", f"{ours:.2f} s", f"{theirs:.2f} s",
                          theirs / ours, ">= 5x", theirs / ours >= 5, load_since(started)))
    return results


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    import tempfile

    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        for r in run(Path(tmp)):
            print(f"{r.name}: {r.ours} vs {r.theirs}: {r.ratio:.2f}x (target {r.target}) {'ok' if r.ok else 'MISSED'}")
