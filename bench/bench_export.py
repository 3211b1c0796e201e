"""export (issue 28): `sharedlink export` in jsonl, csv and MCAP against `tshark -T ek -j sharedlink`
with the dissector, on one 200,000-frame compressed beacon capture (``sharedlink gen --compress``).

Each command runs in its own process as a user runs it (the CLI, output to a file), interleaved,
best of ``ROUNDS``; the figure is the process's CPU time (user + system, from ``wait4``: foxglove
-sdk's writer threads included), which a loaded shared machine disturbs far less than wall time
(the wall time is shown beside it). Targets: jsonl and csv at least 5x faster than tshark -T ek;
MCAP at least as fast as jsonl. Every line says the load while it was measured.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from bench import Result, line, load_now, load_since
from sharedlink.generators.beacon import GenOptions, generate_file

FRAMES = int(os.environ.get("SHAREDLINK_BENCH_FRAMES", "200000"))
ROUNDS = int(os.environ.get("SHAREDLINK_BENCH_ROUNDS", "2"))
REPO = Path(__file__).resolve().parent.parent
LUA = REPO / "dissector" / "sharedlink.lua"
CLI = [sys.executable, "-m", "sharedlink"]


def _env() -> dict[str, str]:
    # tshark with an empty configuration: no personal plugins or preferences
    return dict(os.environ, HOME="/nonexistent-sharedlink-bench", XDG_CONFIG_HOME="/nonexistent-sharedlink-bench")


def cpu_run(cmd: list[str], stdout: Path | None = None) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of one command in a process of its own."""
    t = time.perf_counter()
    with open(stdout or os.devnull, "wb") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.DEVNULL, env=_env())
        _, status, usage = os.wait4(proc.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{cmd[:4]} failed ({status})")
    return usage.ru_utime + usage.ru_stime, time.perf_counter() - t


def run(work: Path) -> list[Result]:
    cap = work / "export-200k.pcap"
    generate_file(GenOptions(frames=FRAMES, compress=True), cap)
    cmds = {
        "ek": (["tshark", "-X", f"lua_script:{LUA}", "-T", "ek", "-j", "sharedlink", "-r", str(cap)], work / "out.ek"),
        "jsonl": ([*CLI, "export", "--format", "jsonl", str(cap), "-o", str(work / "out.jsonl")], None),
        "csv": ([*CLI, "export", "--format", "csv", str(cap), "-o", str(work / "out.csv")], None),
        "mcap": ([*CLI, "export", "--format", "mcap", str(cap), "-o", str(work / "out.mcap")], None),
    }
    best = {k: (float("inf"), 0.0) for k in cmds}
    started = load_now()
    for _ in range(ROUNDS):
        for k, (cmd, out) in cmds.items():
            best[k] = min(best[k], cpu_run(cmd, out))
    load = load_since(started)
    for f in work.glob("out.*"):
        f.unlink()

    def fig(k: str) -> str:
        cpu, wall = best[k]
        return f"{cpu:.2f} s CPU ({wall:.1f} s wall)"

    ek = best["ek"][0]
    out = []
    for k in ("jsonl", "csv"):
        ratio = ek / best[k][0]
        out.append(Result(f"export {k} vs tshark -T ek -j sharedlink ({FRAMES:,} frames, CPU)", fig(k), fig("ek"),
                          ratio, ">= 5x", ratio >= 5, load))
    ratio = best["jsonl"][0] / best["mcap"][0]
    out.append(Result("export mcap vs jsonl (CPU)", fig("mcap"), fig("jsonl"), ratio, ">= 1x", ratio >= 1, load))
    return out


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        for r in run(Path(tmp)):
            print(line(r))
