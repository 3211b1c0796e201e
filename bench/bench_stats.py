"""stats and export against tshark and a bare dpkt loop, on one 200,000-frame compressed capture.

Issue 28's lines, measured side by side in this run (wall time, best of ``ROUNDS``, each command
in its own process as a user runs it):

* ``sharedlink stats`` against ``tshark`` with ``sharedlink.lua`` and its ``-z sharedlink,stats``
  tap (target: at least 10x faster), and against a bare dpkt read loop over the same file
  (target: within 4x);
* ``sharedlink export --format jsonl`` against ``tshark -T ek -j sharedlink`` with the
  dissector (target: at least 5x faster).

Each line names the machine's load average when it was measured: on a shared machine the
figures move with it (the ratios less than the times).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from bench import Result
from sharedlink.generators.beacon import GenOptions, generate_file

FRAMES = int(os.environ.get("SHAREDLINK_BENCH_FRAMES", "200000"))
ROUNDS = int(os.environ.get("SHAREDLINK_BENCH_ROUNDS", "2"))
REPO = Path(__file__).resolve().parent.parent
LUA = REPO / "dissector" / "sharedlink.lua"
TAP = REPO / "dissector" / "sharedlink_stats.lua"
CLI = [sys.executable, "-m", "sharedlink"]


def _load() -> str:
    return "load %.1f" % os.getloadavg()[0]


def _wall(cmd: list[str], out: Path | None = None) -> float:
    best = float("inf")
    for _ in range(ROUNDS):
        t = time.perf_counter()
        with open(out or os.devnull, "wb") as fh:
            subprocess.run(cmd, stdout=fh, stderr=subprocess.DEVNULL, check=True, env=_env())
        best = min(best, time.perf_counter() - t)
    return best


def _env() -> dict[str, str]:
    # tshark with an empty configuration: no personal plugins or preferences
    return dict(os.environ, HOME="/nonexistent-sharedlink-bench", XDG_CONFIG_HOME="/nonexistent-sharedlink-bench")


def dpkt_loop(path: str) -> None:  # pragma: no cover - run in a child process
    import dpkt

    with open(path, "rb") as fh:
        for _ts, _buf in dpkt.pcap.Reader(fh):
            pass


def run(work: Path) -> list[Result]:
    cap = work / "stats-200k.pcap"
    generate_file(GenOptions(frames=FRAMES, compress=True), cap)
    lua = ["-X", f"lua_script:{LUA}"]
    results = []
    load = _load()
    ours = _wall([*CLI, "stats", str(cap)])
    tap = _wall(["tshark", "-q", *lua, "-X", f"lua_script:{TAP}", "-z", "sharedlink,stats", "-r", str(cap)])
    bare = _wall([sys.executable, "-c", f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); "
                  f"import bench_stats; bench_stats.dpkt_loop({str(cap)!r})"])
    results.append(Result(f"stats vs tshark + tap ({FRAMES:,} frames, {load})", f"{ours:.2f} s", f"{tap:.2f} s",
                          tap / ours, ">= 10x", tap / ours >= 10))
    results.append(Result(f"stats vs a bare dpkt loop ({load})", f"{ours:.2f} s", f"{bare:.2f} s", ours / bare,
                          "<= 4x", ours / bare <= 4))
    load = _load()
    jsonl = _wall([*CLI, "export", "--format", "jsonl", str(cap)], work / "out.jsonl")
    ek = _wall(["tshark", *lua, "-T", "ek", "-j", "sharedlink", "-r", str(cap)], work / "out.ek")
    results.append(Result(f"export jsonl vs tshark -T ek ({load})", f"{jsonl:.2f} s", f"{ek:.2f} s", ek / jsonl,
                          ">= 5x", ek / jsonl >= 5))
    return results


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parent))
    import tempfile

    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        for r in run(Path(tmp)):
            print(f"{r.name}: {r.ours} vs {r.theirs}: {r.ratio:.2f}x (target {r.target}) {'ok' if r.ok else 'MISSED'}")
