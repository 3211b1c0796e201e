"""The sharedlink.lua scaling patterns of issue 31 for ``make fuzz`` (scripts/fuzz.py, stage 5
reads every ``tests/fuzz/scaling_*.py`` with a PATTERNS table): the patterns of
``test_scaling_sharedlink.py`` (which ``make test`` runs at its N), here at 4 times that N.
A pattern ``test_scaling_sharedlink.BORDERLINE`` names (known to sit near the bound) gets 8x here
instead of 5x, so ``make fuzz`` reports its growth without failing on what the suite already
reports as a non-strict xfail."""

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
    name: (_make(name), n, 4 * n, 8.0 if name in tss.BORDERLINE else 5.0)
    for name, (_gen, n, _args) in tss.PATTERNS.items()
}
