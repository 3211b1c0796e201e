"""`make bench`: speed and memory ratios, each measured side by side in one run.

Every ``bench/bench_*.py`` module offers ``run(work: Path) -> list[Result]`` (or ``run_bench``
when its ``run`` serves its own command line); this script runs
them all, prints one table and exits 1 if a ratio misses its target (so a regression shows).
Figures on a shared machine are noisy: read the ratios, not the absolute times.
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent


@dataclass
class Result:
    name: str  # what was measured
    ours: str  # our figure, with unit
    theirs: str  # the reference figure, with unit
    ratio: float  # the figure the target applies to
    target: str  # e.g. ">= 100x" or "<= 3x"
    ok: bool


def load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod
    spec.loader.exec_module(mod)
    return mod


def main(argv: list[str]) -> int:
    only = set(argv)
    sys.path.insert(0, str(HERE))
    results: list[Result] = []
    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        for path in sorted(HERE.glob("bench_*.py")):
            name = path.stem[len("bench_") :]
            if only and name not in only:
                continue
            t = time.perf_counter()
            print(f"running {name} ...", file=sys.stderr, flush=True)
            mod = load(path)
            results += (mod.run_bench if hasattr(mod, "run_bench") else mod.run)(Path(tmp))
            print(f"  {name} took {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
    w = max((len(r.name) for r in results), default=10)
    print(f"{'benchmark':<{w}}  {'ours':>22}  {'reference':>22}  {'ratio':>8}  {'target':>8}  ok")
    for r in results:
        print(f"{r.name:<{w}}  {r.ours:>22}  {r.theirs:>22}  {r.ratio:>7.2f}x  {r.target:>8}  {'yes' if r.ok else 'NO'}")
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
