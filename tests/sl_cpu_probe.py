"""A per-test CPU probe, on when ``SHAREDLINK_TEST_CPU=PREFIX`` is set (``tests/conftest.py``
loads it then; docs/testing.md, "Where the suite's CPU goes"). Each pytest process (each xdist
worker runs one test at a time) appends a JSON line a test to ``PREFIX.<worker>.jsonl``: the
test's wall time, the CPU (user + system) of the pytest process and of the children it reaped
during the test (``RUSAGE_SELF`` and ``RUSAGE_CHILDREN`` deltas), and the children by kind
(``cli`` a ``sharedlink`` run, ``cli-zygote`` one forked by ``sl_zygote``, ``tshark``,
``python``, other programs by name) with their count
and CPU, read from ``os.wait4`` for each child ``subprocess`` reaps (a child's figures include
the processes it reaped itself: tshark started by a ``sharedlink`` run counts as ``cli``).
``python tests/sl_cpu_probe.py PREFIX`` prints the totals and the top tests."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import pytest

_kinds: dict[int, str] = {}
_by_kind: dict[str, list[float]] = defaultdict(lambda: [0, 0.0])


def kind_of(args: Any) -> str:
    """The kind of a child from its argument list."""
    argv = [str(a) for a in args] if isinstance(args, (list, tuple)) else str(args).split()
    if not argv:
        return "?"
    prog = os.path.basename(argv[0])
    if prog == "sharedlink" or argv[1:3] == ["-m", "sharedlink"]:
        return "cli"
    if "tshark" in prog or any(os.path.basename(a) == "tshark" for a in argv[:4]):
        return "tshark"
    if prog.startswith("python"):
        return "python"
    return prog


_orig_execute = subprocess.Popen._execute_child  # type: ignore[attr-defined]
_orig_waitpid = os.waitpid


def _execute_child(self: subprocess.Popen[Any], args: Any, *rest: Any, **kw: Any) -> None:
    _orig_execute(self, args, *rest, **kw)
    _kinds[self.pid] = kind_of(args)


def _waitpid(pid: int, options: int) -> tuple[int, int]:
    if pid <= 0 or pid not in _kinds:
        return _orig_waitpid(pid, options)
    got, status, ru = os.wait4(pid, options)
    if got:
        tally = _by_kind[_kinds.pop(pid)]
        tally[0] += 1
        tally[1] += ru.ru_utime + ru.ru_stime
    return got, status


_orig_poll = subprocess.Popen._internal_poll  # type: ignore[attr-defined]


def _internal_poll(self: subprocess.Popen[Any], _deadstate: Any = None, **kw: Any) -> Any:
    return _orig_poll(self, _deadstate, _waitpid=_waitpid)


def _zygote_tally() -> list[float]:
    """``sl_zygote``'s runs and their CPU so far (its runs are the zygote's children, not ours)."""
    zygote = sys.modules.get("sl_zygote")
    return list(zygote.TALLY) if zygote is not None else [0, 0.0]


def _cpu(who: int) -> float:
    ru = resource.getrusage(who)
    return ru.ru_utime + ru.ru_stime


def _out() -> Path:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    return Path(f"{os.environ['SHAREDLINK_TEST_CPU']}.{worker}.jsonl")


def pytest_configure(config: pytest.Config) -> None:
    subprocess.Popen._execute_child = _execute_child  # type: ignore[attr-defined]
    subprocess.Popen._internal_poll = _internal_poll  # type: ignore[attr-defined]
    os.waitpid = _waitpid  # type: ignore[assignment]
    with _out().open("a") as f:
        f.write(json.dumps({"start": _cpu(resource.RUSAGE_SELF) + _cpu(resource.RUSAGE_CHILDREN)}) + "\n")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: Any) -> Any:
    _by_kind.clear()
    z0 = list(_zygote_tally())
    w0, s0, c0 = time.perf_counter(), _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN)
    yield
    z1 = _zygote_tally()
    if z1[0] > z0[0]:
        _by_kind["cli-zygote"] = [z1[0] - z0[0], z1[1] - z0[1]]
    rec = {"id": item.nodeid, "wall": round(time.perf_counter() - w0, 3),
           "self": round(_cpu(resource.RUSAGE_SELF) - s0, 3),
           "children": round(_cpu(resource.RUSAGE_CHILDREN) - c0 + _by_kind.get("cli-zygote", [0, 0.0])[1], 3),
           "kinds": {k: [n, round(c, 3)] for k, (n, c) in _by_kind.items()}}
    with _out().open("a") as f:
        f.write(json.dumps(rec) + "\n")


def pytest_unconfigure(config: pytest.Config) -> None:
    zygote = sys.modules.get("sl_zygote")
    if zygote is not None and zygote._zygote is not None:  # its CPU counted before the last line
        zygote._zygote.close()
    with _out().open("a") as f:
        f.write(json.dumps({"end": _cpu(resource.RUSAGE_SELF) + _cpu(resource.RUSAGE_CHILDREN)}) + "\n")


def _report(prefix: str, top: int = 30) -> None:
    tests: list[dict[str, Any]] = []
    workers = 0.0
    paths = sorted(Path(prefix).parent.glob(Path(prefix).name + ".*.jsonl"))
    if any(".gw" in p.name for p in paths):  # xdist: the controller runs no test (its children are the workers)
        paths = [p for p in paths if ".gw" in p.name]
    for path in paths:
        start = end = 0.0
        for line in path.read_text().splitlines():
            rec = json.loads(line)
            if "id" in rec:
                tests.append(rec)
            start = rec.get("start", start)
            end = rec.get("end", end)
        workers += end - start
    total = sum(t["self"] + t["children"] for t in tests)
    kinds: Counter[str] = Counter()
    counts: Counter[str] = Counter()
    for t in tests:
        for k, (n, c) in t["kinds"].items():
            kinds[k] += c
            counts[k] += n
    reaped = sum(kinds.values())
    print(f"{len(tests)} tests, CPU in tests {total:.1f} s (pytest processes {sum(t['self'] for t in tests):.1f} s,"
          f" children {sum(t['children'] for t in tests):.1f} s; the workers' own outside tests"
          f" {workers - total:.1f} s)")
    for k, c in kinds.most_common():
        print(f"  {k:12} {counts[k]:6} runs {c:8.1f} s  ({c / max(counts[k], 1):.3f} s a run)")
    print(f"  {'unreaped':12}        {sum(t['children'] for t in tests) - reaped:8.1f} s (children reaped outside subprocess)")
    print(f"top {top} tests by CPU:")
    for t in sorted(tests, key=lambda t: -(t["self"] + t["children"]))[:top]:
        ks = " ".join(f"{k}={n}/{c:.1f}" for k, (n, c) in sorted(t["kinds"].items()))
        print(f"  {t['self'] + t['children']:6.1f} s wall {t['wall']:5.1f}  {t['id']}  [{ks}]")
    files: Counter[str] = Counter()
    for t in tests:
        files[t["id"].split("::")[0]] += t["self"] + t["children"]
    print("top files by CPU:")
    for f, c in files.most_common(top):
        print(f"  {c:6.1f} s  {f}")


if __name__ == "__main__":
    _report(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 30)
