"""`make mutate`: mutation testing of the core modules with mutmut, one module at a time.

Each module is mutated against its own fast subset of the tests. For every module, a scratch
copy of the package (laid out as ``src/sharedlink``, the layout mutmut understands) and of
``tests/`` is made under ``out/mutate/<module>/``, with a ``pyproject.toml`` holding that
module's mutmut settings; ``mutmut run`` is started there. The share of mutants killed is
printed per module and in total, and the survivors are written to
``out/mutate/<module>/survivors.txt`` (with their diffs, from ``mutmut show``).

Tests that run the CLI in a subprocess import the mutated copy too (``PYTHONPATH`` points at
it, and the mutant to activate is in the environment), so they kill mutants as well; but mutmut
only learns which tests reach a function from calls in its own process, so a function only the
CLI reaches has "no tests". Those count as not killed.

    python scripts/mutate.py                      # every module
    python scripts/mutate.py diff serial_format   # some of them
    python scripts/mutate.py --resume diff        # go on with an interrupted run
    python scripts/mutate.py --sample 10          # every tenth mutant: a quicker estimate
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MUTMUT = Path(sys.executable).with_name("mutmut")


@dataclass(frozen=True)
class Target:
    path: str  # below pytools/sharedlink
    tests: tuple[str, ...]  # the fast subset, below tests/
    only: tuple[str, ...] = ()  # mutant name patterns (mutmut run NAMES...); () = every mutant
    note: str = ""


#: the core modules, each with the tests that exercise it directly
TARGETS: dict[str, Target] = {
    "codec": Target("protocols/codec.py", ("protocols/test_codec.py", "protocols/test_state.py")),
    "state": Target("protocols/state.py", ("protocols/test_state.py", "protocols/test_codec.py")),
    "stream": Target("capture/stream.py", ("capture/test_serial_stream.py", "analysis/test_diff.py")),
    "diff": Target("analysis/diff.py", ("analysis/test_diff.py",)),
    "serial_format": Target("capture/serial_format.py", ("capture/test_serial.py",)),
    "replay": Target(
        "replay.py",
        ("tools/test_replay.py",),
        ("sharedlink.replay.xǁReplayer*", "sharedlink.replay.xǁReplayOptions*"),
        "replay scheduling only: Replayer and ReplayOptions",
    ),
    "pacing": Target(
        "pacing.py",
        ("tools/test_replay.py",),
        ("sharedlink.pacing.xǁSchedule*", "sharedlink.pacing.xǁPacer*"),
        "replay's deadlines and its waits for them: Schedule and Pacer",
    ),
}

KILLED = {"killed", "timeout", "caught by type check", "segfault"}
STATUS = {1: "killed", 3: "killed", 0: "survived", 5: "no tests", 33: "no tests", 34: "skipped", 35: "suspicious",
          36: "timeout", 37: "caught by type check", 24: "timeout", -24: "timeout", 152: "timeout", 255: "timeout",
          -11: "segfault", -9: "segfault", None: "not checked"}


@dataclass
class Result:
    name: str
    counts: Counter = field(default_factory=Counter)
    survivors: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def total(self) -> int:
        return sum(n for s, n in self.counts.items() if s not in ("skipped", "not checked"))

    @property
    def killed(self) -> int:
        return sum(n for s, n in self.counts.items() if s in KILLED)


def prepare(name: str, t: Target, work: Path, resume: bool) -> None:
    if work.exists() and not resume:
        shutil.rmtree(work)
    (work / "src").mkdir(parents=True, exist_ok=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", ".hypothesis", "fuzz-regressions")
    for src, dst in ((REPO / "pytools" / "sharedlink", work / "src" / "sharedlink"), (REPO / "tests", work / "tests")):
        shutil.copytree(src, dst, ignore=ignore, dirs_exist_ok=True)
    for d in ("dissector", "captures"):  # read by a few tests through the repository root
        if not (work / d).exists():
            shutil.copytree(REPO / d, work / d, ignore=ignore)
    q = json.dumps
    (work / "pyproject.toml").write_text(
        "[tool.mutmut]\n"
        f"source_paths = [{q('src/sharedlink/' + t.path)}]\n"
        f"pytest_add_cli_args_test_selection = [{', '.join(q('tests/' + p) for p in t.tests)}]\n"
        'pytest_add_cli_args = ["-p", "no:cacheprovider", "-p", "no:xdist", "-q", "-x"]\n'
        f"also_copy = [{q('src/')}, {q('dissector/')}, {q('captures/')}]\n"
        "use_git_change_detection = false\n"
    )


def collect(name: str, t: Target, work: Path, only: list[str]) -> Result:
    meta = work / "mutants" / "src" / "sharedlink" / (t.path + ".meta")
    res = Result(name)
    if not meta.exists():
        return res
    codes = json.loads(meta.read_text())["exit_code_by_key"]
    for key, code in codes.items():
        if only and not any(_match(key, p) for p in only):
            continue
        status = STATUS.get(code, "suspicious")
        res.counts[status] += 1
        if status not in KILLED and status not in ("skipped", "not checked"):
            res.survivors.append(f"{key}\t{status}")
    return res


def _match(key: str, pattern: str) -> bool:
    import fnmatch

    return fnmatch.fnmatchcase(key, pattern)


def patterns(t: Target, sample: int) -> list[str]:
    """mutmut run's name patterns: the target's, narrowed to a systematic sample (every mutant
    whose number ends in 0 for 10, in 0 or 5 for 5, in an even digit for 2)."""
    tail = {1: "", 2: "__mutmut_*[02468]", 5: "__mutmut_*[05]", 10: "__mutmut_*0"}[sample]
    if not tail:
        return list(t.only)
    return [p + tail for p in t.only] if t.only else ["*" + tail]


def run(name: str, jobs: int, resume: bool, timeout: float | None, sample: int = 1) -> Result:
    t = TARGETS[name]
    work = REPO / "out" / "mutate" / name
    prepare(name, t, work, resume)
    env = dict(os.environ)
    # subprocesses (CLI tests) import the mutated copy too; MUTANT_UNDER_TEST, which mutmut
    # sets, passes to them in the environment
    # (made now: a folder missing when the interpreter starts would be skipped for good)
    (work / "mutants" / "src").mkdir(parents=True, exist_ok=True)
    env["PYTHONPATH"] = str(work / "mutants" / "src")
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    cmd = [str(MUTMUT), "run", "--max-children", str(jobs), *patterns(t, sample)]
    t0 = time.monotonic()
    with open(work / "run.log", "w") as log:
        try:
            subprocess.run(cmd, cwd=work, env=env, stdout=log, stderr=subprocess.STDOUT, timeout=timeout, check=False)
        except subprocess.TimeoutExpired:
            print(f"  {name}: stopped after {timeout:.0f} s (go on with --resume {name})")
    res = collect(name, t, work, patterns(t, sample))
    res.seconds = time.monotonic() - t0
    lines = []
    for s in res.survivors:
        key = s.split("\t")[0]
        shown = subprocess.run([str(MUTMUT), "show", key], cwd=work, env=env, capture_output=True, text=True)
        lines.append(f"## {s}\n{shown.stdout.strip()}\n")
    (work / "survivors.txt").write_text("\n".join(lines))
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("modules", nargs="*", help=f"modules (default: all): {', '.join(TARGETS)}", metavar="MODULE")
    ap.add_argument("--jobs", type=int, default=2, help="mutants tested at once (default 2)")
    ap.add_argument("--resume", action="store_true", help="keep the scratch copies and results of an earlier run")
    ap.add_argument("--timeout", type=float, default=None, help="seconds per module before it is stopped")
    ap.add_argument("--sample", type=int, choices=(1, 2, 5, 10), default=1,
                    help="test every Nth mutant only (by the last digit of its number; default 1: all)")
    args = ap.parse_args(argv)
    if not MUTMUT.exists():
        print(f"mutate: {MUTMUT} not found: pip install -e '.[mutate]'", file=sys.stderr)
        return 2
    names = args.modules or list(TARGETS)
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        print(f"mutate: unknown module {', '.join(unknown)} (one of {', '.join(TARGETS)})", file=sys.stderr)
        return 2
    results = []
    for name in names:
        t = TARGETS[name]
        print(f"{name}: {t.path} against {', '.join(t.tests)}" + (f" ({t.note})" if t.note else ""), flush=True)
        r = run(name, args.jobs, args.resume, args.timeout, args.sample)
        results.append(r)
        extra = ", ".join(f"{s} {n}" for s, n in sorted(r.counts.items()) if s not in KILLED | {"survived"})
        share = f"{100 * r.killed / r.total:.1f}%" if r.total else "-"
        print(f"  {r.killed}/{r.total} killed ({share}); survived {r.counts['survived']}"
              + (f"; {extra}" if extra else "") + f"; {r.seconds:.0f} s; survivors in out/mutate/{name}/survivors.txt",
              flush=True)
    killed, total = sum(r.killed for r in results), sum(r.total for r in results)
    if total:
        print(f"total: {killed}/{total} mutants killed ({100 * killed / total:.1f}%)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
