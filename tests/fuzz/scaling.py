"""Scaling checks: does a command's wall time and peak memory grow linearly with its input?

A pattern that is quadratic (a table copied per frame, a buffer rebuilt per record) takes 16
times as long on 4N as on N; linear code takes 4 times as long. ``check_scaling`` runs a
command on a generated input of size N and of size 4N (and on a tiny one, the start-up
baseline that is subtracted from both), each in a fresh process, and fails when the growth
beyond the baseline is more than ``limit`` (default 5) times in peak memory, or more than
``time_limit`` (default :data:`TIME_LIMIT`, 8) times in CPU time.

Why time gets more room than memory: peak memory is a count of bytes, while CPU time also pays
for the memory hierarchy, and a working set 4 times as big can cost more per item (caches, TLB,
the allocator) without one more instruction. Measured: ``-2`` over new names with every name kept
ran 4.0-7.4x in time while callgrind counted its instructions linear (1.526 and 1.522 thousand
million a 1,000 frames); CI read 6.1x (``stats`` over 2,000 and 8,000 conversations) and 6.8x
(blackboard ``-2`` over endpoints) on patterns whose cost per item is flat from 500 to 32,000 here.
A quadratic path costs 16x from N to 4N, so 8x still fails it while it is a third of the N run.

API (small on purpose; tshark and Python commands alike)::

    from scaling import check_scaling, measure

    def make(n: int, tmp: Path) -> list[str]:     # writes an input of size n, returns the command
        path = tmp / f"in-{n}.pcap"
        write_my_pattern(path, n)
        return ["tshark", "-r", str(path), ...]

    report = check_scaling(make, n=2000, tmp=tmp_path)   # raises ScalingError when it does not scale
    print(report)                                        # the figures, for a log

Patterns for ``make fuzz``: a module ``tests/fuzz/scaling_<area>.py`` with a table
``PATTERNS = {name: (make, n_in_make_test, n_in_make_fuzz, limit)}`` (and optionally ``env()``,
the environment its commands run in) is found by scripts/fuzz.py, which checks every pattern at
its bigger size; the module's own test (e.g. test_scaling_small.py) checks the smaller one.

``measure(cmd)`` runs one command and returns a ``Run``: wall seconds, peak resident memory
(KB, of the command and its children: ``getrusage(RUSAGE_CHILDREN)`` read in a fresh
wrapper process, so earlier commands do not count), return code and output. A command that
exits non-zero raises ``ScalingError`` unless ``check=False``.

Noise: the machine may be busy (other jobs share its cores), so the time compared is the
command's CPU time (user + system, its children included) by default; ``metric="wall"``
compares wall time instead. Each size is run ``repeat`` times and the fastest run counts (peak
memory is taken from that run too; it hardly varies). Growth below ``min_seconds`` / ``min_kb``
beyond the baseline is treated as that floor, so a fast linear command is never failed for a
start-up jitter. When a check fails it is measured once more before it raises.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Run", "Report", "ScalingError", "TIME_LIMIT", "measure", "check_scaling"]

#: the most CPU time may grow from N to 4N (linear 4x, quadratic 16x; see the module docstring)
TIME_LIMIT = 8.0

# the wrapper: runs the command, then reports its wall time and its (children's) peak RSS
_WRAPPER = r"""
import json, resource, subprocess, sys, time
cmd = json.loads(sys.argv[1])
t0 = time.perf_counter()
p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
wall = time.perf_counter() - t0
ru = resource.getrusage(resource.RUSAGE_CHILDREN)
sys.stderr.buffer.write(p.stderr)
sys.stdout.buffer.write(p.stdout)
sys.stdout.flush()
with open(sys.argv[2], "w") as f:
    json.dump({"wall": wall, "maxrss": ru.ru_maxrss, "cpu": ru.ru_utime + ru.ru_stime, "rc": p.returncode}, f)
"""


class ScalingError(AssertionError):
    """A command did not scale, or did not run."""


@dataclass(frozen=True)
class Run:
    """One measured run: wall and CPU seconds, peak resident memory in KB, exit status, output."""

    seconds: float
    cpu_seconds: float
    peak_kb: int
    returncode: int
    stdout: str
    stderr: str


@dataclass(frozen=True)
class Report:
    """The three runs of a check and the growth from N to 4N beyond the baseline."""

    metric: str
    n: int
    factor: int
    base: Run
    small: Run
    big: Run
    time_growth: float
    memory_growth: float

    def __str__(self) -> str:
        def mb(kb: int) -> str:
            return "%.1f MB" % (kb / 1024)

        def run(r: Run) -> str:
            return f"{r.cpu_seconds:.2f} s CPU ({r.seconds:.2f} s wall) {mb(r.peak_kb)}"

        return (
            f"N={self.n}: {run(self.small)}; {self.factor}N: {run(self.big)}; baseline {run(self.base)}; "
            f"growth beyond the baseline: {self.metric} time {self.time_growth:.1f}x, memory {self.memory_growth:.1f}x"
        )


def measure(cmd: Sequence[str], env: Mapping[str, str] | None = None, timeout: float = 600,
            check: bool = True) -> Run:
    """Run ``cmd`` in a fresh wrapper process; its wall time, CPU time and peak RSS (KB)."""
    fd, out = tempfile.mkstemp(prefix="scaling-", suffix=".json")
    os.close(fd)
    try:
        try:
            p = subprocess.run(
                [sys.executable, "-c", _WRAPPER, json.dumps([str(c) for c in cmd]), out],
                capture_output=True, env=dict(env) if env is not None else None, timeout=timeout,
                encoding="utf-8", errors="replace",
            )
        except subprocess.TimeoutExpired as e:
            raise ScalingError(f"over {timeout:.0f} s: {' '.join(map(str, cmd))}") from e
        try:
            with open(out) as f:
                r = json.load(f)
        except (OSError, ValueError) as e:
            raise ScalingError(f"the wrapper did not report ({p.returncode}): {p.stderr[-2000:]}") from e
    finally:
        os.unlink(out)
    run = Run(r["wall"], r["cpu"], int(r["maxrss"]), r["rc"], p.stdout, p.stderr)
    if check and run.returncode != 0:
        raise ScalingError(f"exit {run.returncode}: {' '.join(map(str, cmd))}\n{run.stderr[-2000:]}")
    return run


def _seconds(run: Run, metric: str) -> float:
    return run.cpu_seconds if metric == "cpu" else run.seconds


def _best(cmd: Sequence[str], repeat: int, env: Mapping[str, str] | None, timeout: float, metric: str) -> Run:
    runs = [measure(cmd, env=env, timeout=timeout) for _ in range(max(1, repeat))]
    return min(runs, key=lambda r: _seconds(r, metric))


def check_scaling(
    make: Callable[[int, Path], Sequence[str]],
    n: int,
    tmp: Path | str | None = None,
    *,
    factor: int = 4,
    limit: float = 5.0,
    time_limit: float = TIME_LIMIT,
    base_n: int = 1,
    repeat: int = 1,
    min_seconds: float = 0.25,
    min_kb: int = 16 * 1024,
    metric: str = "cpu",
    env: Mapping[str, str] | None = None,
    timeout: float = 600,
) -> Report:
    """Run ``make(size, tmp)``'s command at ``base_n``, ``n`` and ``factor * n``; raise
    ``ScalingError`` when peak memory beyond the baseline grows more than ``limit`` times, or
    time more than ``max(limit, time_limit)`` times, from ``n`` to ``factor * n``. ``make`` writes the input of that size into ``tmp``
    (a fresh temporary folder when None) and returns the command line to measure. ``metric``:
    "cpu" (CPU seconds, the default) or "wall" (wall seconds)."""
    if metric not in ("cpu", "wall"):
        raise ValueError(f"metric must be 'cpu' or 'wall', not {metric!r}")
    own_tmp = None
    if tmp is None:
        own_tmp = tempfile.TemporaryDirectory(prefix="scaling-")
        tmp = own_tmp.name
    tmp = Path(tmp)
    try:
        cmds = {size: list(make(size, tmp)) for size in (base_n, n, factor * n)}
        report = None
        time_limit = max(limit, time_limit)
        for attempt in range(2):  # a failure is measured once more: the machine may be busy
            base, small, big = (_best(cmds[k], repeat, env, timeout, metric) for k in (base_n, n, factor * n))
            t0 = _seconds(base, metric)
            dt = max(_seconds(small, metric) - t0, min_seconds)
            dm = max(small.peak_kb - base.peak_kb, min_kb)
            report = Report(metric, n, factor, base, small, big, (_seconds(big, metric) - t0) / dt,
                            (big.peak_kb - base.peak_kb) / dm)
            if report.time_growth <= time_limit and report.memory_growth <= limit:
                return report
            if attempt == 0 and big.seconds > 60:
                break  # far off and slow: no second look
        raise ScalingError(f"does not scale (limits: time {time_limit:.1f}x, memory {limit:.1f}x): {report}\ncommand: {' '.join(cmds[factor * n])}")
    finally:
        if own_tmp is not None:
            own_tmp.cleanup()
