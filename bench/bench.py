"""`make bench`: speed and memory ratios, each measured side by side in one run.

Every ``bench/bench_*.py`` module offers ``run(work: Path) -> list[Result]`` (or ``run_bench``
when its ``run`` serves its own command line); this script runs
them all, prints one table and exits 1 if a ratio misses its target (so a regression shows).
Figures on a shared machine are noisy: read the ratios, not the absolute times. Every line says
the machine's load while it was measured (the 1-minute load average at its start and end, and
the CPU count): a line that sets ``load`` itself (``started = load_now()`` before measuring,
``load=load_since(started)`` in its Result) is exact; the others get their module's span.
"""

from __future__ import annotations

import importlib.util
import os
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
    load: str = ""  # the machine's load over the measurement (load_since), "" = the module's span


def load_now() -> float:
    """The 1-minute load average now (take it when a measurement starts)."""
    return os.getloadavg()[0]


def load_since(started: float) -> str:
    """``"load 3.1->2.4/2 CPUs"``: the load average when the measurement started and now, and the
    CPU count (a load above the CPU count means the figures shared the cores)."""
    return f"load {started:.1f}->{load_now():.1f}/{os.cpu_count() or 1} CPUs"


def load(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod
    spec.loader.exec_module(mod)
    return mod


def main(argv: list[str]) -> int:
    names = sorted(path.stem[len("bench_") :] for path in HERE.glob("bench_*.py"))
    if {"-h", "--help"} & set(argv):
        print(f"usage: bench.py [MODULE ...]\n\n{__doc__.strip()}\n\nmodules: {' '.join(names)}")
        return 0
    unknown = set(argv) - set(names)
    if unknown:
        print(f"bench.py: no such module: {' '.join(sorted(unknown))} (modules: {' '.join(names)})", file=sys.stderr)
        return 2
    only = set(argv)
    sys.path.insert(0, str(HERE))
    results: list[Result] = []
    with tempfile.TemporaryDirectory(prefix="sharedlink-bench-") as tmp:
        for path in sorted(HERE.glob("bench_*.py")):
            name = path.stem[len("bench_") :]
            if only and name not in only:
                continue
            t = time.perf_counter()
            print(f"running {name} ... (load {load_now():.1f})", file=sys.stderr, flush=True)
            mod = load(path)
            started = load_now()
            lines = (mod.run_bench if hasattr(mod, "run_bench") else mod.run)(Path(tmp))
            span = load_since(started)
            for r in lines:
                r.load = r.load or span
                print(line(r), file=sys.stderr, flush=True)  # as each module ends: a long run shows its way
            results += lines
            print(f"  {name} took {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
    print(table(results))
    return 0 if all(r.ok for r in results) else 1


def line(r: Result) -> str:
    """One result as a line (a module run alone prints these)."""
    return (f"{r.name}: {r.ours} vs {r.theirs}: {r.ratio:.2f}x (target {r.target}) {'ok' if r.ok else 'MISSED'}"
            f" [{r.load or load_since(load_now())}]")


def table(results: list[Result]) -> str:
    """The results as a table: figure, reference, ratio, target, verdict and the load."""
    w = max((len(r.name) for r in results), default=10)
    rows = [f"{'benchmark':<{w}}  {'ours':>22}  {'reference':>22}  {'ratio':>8}  {'target':>8}  ok   load"]
    for r in results:
        rows.append(f"{r.name:<{w}}  {r.ours:>22}  {r.theirs:>22}  {r.ratio:>7.2f}x  {r.target:>8}  "
                    f"{'yes' if r.ok else 'NO ':<3}  {r.load}")
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
