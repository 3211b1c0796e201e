"""CPU time of several dissector folders against syslog, side by side (interleaved runs).

    python bench/ab_dissector.py [--frames N] [--repeat N] [--passes=summary,-2,-V,-Y,compressed]
                                 NAME=DIR [NAME=DIR ...]

Each DIR is a ``dissector/`` folder (this checkout's, or an old one's in a ``git worktree``, e.g.
ff41cb3's), installed as ``make install`` leaves it in a HOME of its own; the captures are the
bench's (``sharedlink gen``). Prints, per pass, syslog's CPU seconds and each folder's with its
ratio, best of ``--repeat``. For telling whether a change gains in time what callgrind says it
gains in instructions: the runs of all folders alternate, so the machine's load moves them alike.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import bench_dissector as bd

PASSES = {"summary": ([], False, False), "-2": (["-2"], False, False), "-V": (["-V"], False, False),
          "-Y": ([], True, False), "compressed": ([], False, True)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", metavar="NAME=DIR", help="a dissector folder to time, named")
    ap.add_argument("--frames", type=int, default=200_000, help="beacon frames a capture (default 200000)")
    ap.add_argument("--repeat", type=int, default=3, help="runs a configuration, best kept (default 3)")
    ap.add_argument("--passes", default="summary,-2,compressed", help="among " + ",".join(PASSES) + " (write --passes=-2,-V: a list starting with - takes the =)")
    args = ap.parse_args(argv)
    passes = args.passes.split(",")
    if bad := [p for p in passes if p not in PASSES]:
        ap.error(f"unknown pass: {', '.join(bad)}")
    folders: dict[str, Path] = {}
    for f in args.folders:
        name, _, d = f.partition("=")
        if not d or not Path(d).is_dir():
            ap.error(f"not NAME=DIR with DIR a folder: {f}")
        folders[name] = Path(d)
    with tempfile.TemporaryDirectory(prefix="sharedlink-ab-") as tmp:
        work = Path(tmp)
        beacon = bd.make_beacon_capture(work / "beacon.pcap", args.frames)
        compressed = bd.make_beacon_capture(work / "compressed.pcap", args.frames, compress=True)
        homes = {k: bd.make_home(work / f"home-{k}", sorted(d.glob("*.lua"))) for k, d in folders.items()}
        syslog = bd.make_home(work / "home-none", [])
        best: dict[tuple[str, str], float] = {}
        for _ in range(max(1, args.repeat)):
            for p in passes:
                opts, filtered, comp = PASSES[p]
                cmd = [bd.TSHARK, "-n", "-r", str(compressed if comp else beacon), *opts]
                runs = {k: (cmd + (["-Y", bd.LUA_FILTER] if filtered else []), env) for k, env in homes.items()}
                runs["syslog"] = (cmd + bd.SYSLOG + (["-Y", bd.SYSLOG_FILTER] if filtered else []), syslog)
                for who, (c, env) in runs.items():
                    cpu = bd.measure(c, env).cpu
                    best[p, who] = min(best.get((p, who), cpu), cpu)
        for p in passes:
            s = best[p, "syslog"]
            cells = "  ".join(f"{k} {best[p, k]:.2f} s {best[p, k] / s:.2f}x" for k in folders)
            print(f"{p:<11} syslog {s:.2f} s  {cells}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
