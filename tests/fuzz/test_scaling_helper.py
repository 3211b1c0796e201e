"""tests/fuzz/scaling.py fails a command that grows quadratically and passes a linear one."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from scaling import ScalingError, check_scaling, measure

LOOP = "import sys\nn = int(sys.argv[1])\ns = 0\nfor i in range({work}):\n    s += i\n"
ALLOC = "import sys, time\nn = int(sys.argv[1])\nb = bytearray({size})\nb[::4096] = b'x' * len(b[::4096])\n"


def _py(code: str):
    def make(n: int, tmp: Path) -> list[str]:
        return [sys.executable, "-c", code, str(n)]

    return make


def test_measure_reports_time_memory_and_exit_status():
    r = measure([sys.executable, "-c", ALLOC.format(size="n * 1024 * 1024"), "64"])
    assert r.returncode == 0 and r.seconds > 0
    assert r.peak_kb >= 64 * 1024, r
    with pytest.raises(ScalingError, match="exit 3"):
        measure([sys.executable, "-c", "raise SystemExit(3)"])
    assert measure([sys.executable, "-c", "raise SystemExit(3)"], check=False).returncode == 3


def test_linear_time_and_memory_pass(tmp_path: Path):
    rep = check_scaling(_py(LOOP.format(work="n * 2000")), 400, tmp_path)
    assert rep.time_growth <= 5
    rep = check_scaling(_py(ALLOC.format(size="n * 1024 * 64")), 400, tmp_path)
    assert rep.memory_growth <= 5


def test_quadratic_time_fails(tmp_path: Path):
    with pytest.raises(ScalingError, match="does not scale"):
        check_scaling(_py(LOOP.format(work="n * n")), 800, tmp_path, min_seconds=0.05)


def test_quadratic_memory_fails(tmp_path: Path):
    with pytest.raises(ScalingError, match="memory"):
        check_scaling(_py(ALLOC.format(size="n * n * 8")), 2048, tmp_path)
