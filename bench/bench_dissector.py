"""Benchmark the SharedLink Lua dissector against tshark's built-in syslog dissector.

    python bench/bench_dissector.py CAPTURE [--repeat N] [--dissector PATH]

For the same capture, in one run and side by side:

* ``lua``     tshark with ``-X lua_script:dissector/sharedlink.lua`` (port 7013 decoded by it)
* ``syslog``  tshark decoding port 7013 as syslog (``-d udp.port==7013,syslog``), with
  our script NOT loaded: the baseline is plain tshark with a C dissector for the payload.
  (Loading the script but disabling it would add the script's load time to the
  baseline; leaving it out makes the comparison stricter for the dissector.)

each for a summary pass (``tshark -r F`` to /dev/null) and a ``-V`` pass, measuring
wall time and peak memory (max RSS of the tshark child, via getrusage in a fresh
helper process).  Every tshark run uses an empty configuration directory so personal
preferences and plugins do not interfere.  Ratios lua/syslog are reported (the time
ratio on CPU time, robust on a busy machine; the wall-time ratio too); targets:
summary time <= 3x, memory <= 1.3x.

If no capture is given, ``--make N`` writes an N-frame beacon capture first.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DISSECTOR = REPO / "dissector" / "sharedlink.lua"
TSHARK = shutil.which("tshark") or "/usr/bin/tshark"

TIME_TARGET = 3.0
MEM_TARGET = 1.3

# Runs one command and prints {"wall": s, "cpu": s, "maxrss_kb": kb, "rc": rc} as JSON.
_MEASURE = r"""
import json, resource, subprocess, sys, time
t0 = time.perf_counter()
with open("/dev/null", "wb") as null:
    rc = subprocess.call(sys.argv[1:], stdout=null, stderr=subprocess.DEVNULL)
wall = time.perf_counter() - t0
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "maxrss_kb": ru.ru_maxrss, "rc": rc}))
"""


def _env(confdir: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["WIRESHARKCONFIGDIR"] = str(confdir / "wireshark")
    env["XDG_CONFIG_HOME"] = str(confdir)
    env["HOME"] = str(confdir)
    return env


def measure(cmd: list[str], env: dict[str, str]) -> tuple[float, float, int]:
    """(wall s, CPU s (user+sys), peak RSS KiB) of one command, measured in a fresh helper process."""
    out = subprocess.run([sys.executable, "-c", _MEASURE, *cmd], capture_output=True, text=True, env=env,
                         check=True).stdout
    res = json.loads(out)
    if res["rc"] != 0:
        raise RuntimeError(f"command failed ({res['rc']}): {' '.join(cmd)}")
    return float(res["wall"]), float(res["cpu"]), int(res["maxrss_kb"])


def commands(capture: Path, dissector: Path) -> dict[str, list[str]]:
    base = [TSHARK, "-n", "-r", str(capture)]
    lua = [*base, "-X", f"lua_script:{dissector}"]
    syslog = [*base, "-d", "udp.port==7013,syslog"]
    return {
        "lua summary": lua,
        "syslog summary": syslog,
        "lua -V": [*lua, "-V"],
        "syslog -V": [*syslog, "-V"],
    }


def run(capture: Path, repeat: int = 3, dissector: Path | None = None) -> list[tuple[str, float]]:
    """Measure; returns (name, value) pairs: times (s), peak memory (KiB) and ratios.

    Each configuration runs ``repeat`` times interleaved with the others; the best
    (lowest) value of each measure is kept.  The time ratios use CPU time (user+sys of
    tshark), which a busy machine disturbs much less than wall time; wall times are
    reported as well.
    """
    capture = Path(capture).resolve()
    dissector = Path(dissector or DEFAULT_DISSECTOR).resolve()
    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        confdir = Path(tmp)
        (confdir / "wireshark").mkdir()
        env = _env(confdir)
        cmds = commands(capture, dissector)
        best: dict[str, tuple[float, float, int]] = {}
        for _ in range(max(1, repeat)):
            for name, cmd in cmds.items():
                m = measure(cmd, env)
                old = best.get(name)
                best[name] = (min(m[0], old[0]), min(m[1], old[1]), min(m[2], old[2])) if old else m
    results: list[tuple[str, float]] = []
    for name, (wall, cpu, rss) in best.items():
        results.append((f"{name} wall s", round(wall, 3)))
        results.append((f"{name} cpu s", round(cpu, 3)))
        results.append((f"{name} peak KiB", float(rss)))
    for mode in ("summary", "-V"):
        lw, lc, lm = best[f"lua {mode}"]
        sw, sc, sm = best[f"syslog {mode}"]
        results.append((f"{mode} time ratio", round(lc / sc, 3)))
        results.append((f"{mode} wall time ratio", round(lw / sw, 3)))
        results.append((f"{mode} memory ratio", round(lm / sm, 3)))
    return results


def make_beacon_capture(path: Path, frames: int = 200_000, compress: bool = False) -> Path:
    """A beacon capture made by `sharedlink gen` (the project's one generator)."""
    from sharedlink.generators.beacon import GenOptions, generate_file

    generate_file(GenOptions(frames=frames, compress=compress), path)
    return path


def bench_results(results: list[tuple[str, float]], label: str, targets: bool) -> list:
    """The `make bench` rows for one capture."""
    from bench import Result

    r = dict(results)
    rows = []
    for mode, target in (("summary", TIME_TARGET), ("-V", None)):
        ratio = r[f"{mode} time ratio"]
        rows.append(Result(
            f"dissector {mode} CPU vs syslog ({label})", f"{r[f'lua {mode} cpu s']:.2f} s", f"{r[f'syslog {mode} cpu s']:.2f} s",
            ratio, f"<= {target:g}x" if target and targets else "(info)", ratio <= target if target and targets else True,
        ))
    mem = r["summary memory ratio"]
    rows.append(Result(
        f"dissector peak memory vs syslog ({label})", f"{r['lua summary peak KiB'] / 1024:.0f} MiB",
        f"{r['syslog summary peak KiB'] / 1024:.0f} MiB", mem,
        f"<= {MEM_TARGET:g}x" if targets else "(info)", mem <= MEM_TARGET if targets else True,
    ))
    return rows


def run_bench(work: Path) -> list:
    """`make bench`: the issue's 200,000-frame beacon capture (targets), and its compressed
    twin (for information)."""
    rows = []
    for label, compress in (("200k beacon frames", False), ("200k compressed", True)):
        cap = make_beacon_capture(work / f"dissector-{compress}.pcap", 200_000, compress)
        rows += bench_results(run(cap, repeat=2), label, targets=not compress)
        cap.unlink()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("capture", nargs="?", type=Path, help="capture to decode")
    ap.add_argument("--repeat", type=int, default=3, help="runs per configuration (best kept)")
    ap.add_argument("--dissector", type=Path, default=None, help="Lua dissector (default: the repo's)")
    ap.add_argument("--make", type=int, metavar="N", help="first write an N-frame beacon capture to CAPTURE "
                    "(or a temporary file)")
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    args = ap.parse_args(argv)

    tmpdir = None
    capture = args.capture
    if args.make:
        if capture is None:
            tmpdir = tempfile.TemporaryDirectory(prefix="sharedlink-bench-cap-")
            capture = Path(tmpdir.name) / "beacon.pcap"
        make_beacon_capture(capture, args.make)
    if capture is None:
        ap.error("a capture (or --make N) is required")
    try:
        results = run(capture, repeat=args.repeat, dissector=args.dissector)
    finally:
        if tmpdir is not None:
            tmpdir.cleanup()
    if args.json:
        print(json.dumps(dict(results), indent=2))
    else:
        width = max(len(n) for n, _ in results)
        for name, value in results:
            print(f"{name:<{width}}  {value:g}")
    ratios = dict(results)
    ok = ratios["summary time ratio"] <= TIME_TARGET and ratios["summary memory ratio"] <= MEM_TARGET
    print(f"targets (summary time <= {TIME_TARGET}x, memory <= {MEM_TARGET}x): {'met' if ok else 'NOT met'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
