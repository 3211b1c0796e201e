"""The sharedlink.lua scaling patterns of issue 31 for ``make fuzz`` (scripts/fuzz.py, stage 5
reads every ``tests/fuzz/scaling_*.py`` with a PATTERNS table): the patterns of
``test_scaling_sharedlink.py`` (which ``make test`` runs at its N), here at 4 times that N.
Memory may grow 5x, time ``scaling.TIME_LIMIT`` (8x)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import test_scaling_sharedlink as tss


def _make(name: str) -> Callable[[int, Path], list[str]]:
    gen, _n, args = tss.PATTERNS[name]

    def make(size: int, tmp: Path) -> list[str]:
        return tss._cmd(tss._write(tmp / f"{name}-{size}.pcap", gen(size)), *args)

    return make


# name -> (make, n in make test, n in make fuzz, growth limit)
PATTERNS: dict[str, tuple[Callable[[int, Path], list[str]], int, int, float]] = {
    name: (_make(name), n, 4 * n, 5.0)
    for name, (_gen, n, _args) in tss.PATTERNS.items()
}
