"""Issue 44's memory patterns for ``make fuzz`` (scripts/fuzz.py's scaling stage reads every
``tests/fuzz/scaling_*.py`` with a PATTERNS table; this one's ``check`` is the memory rule of
memory_patterns.check_memory: 4N at most twice N's peak memory plus 50 MB, 8x its CPU time).
test_memory_patterns.py runs (in ``make test-long``) the patterns with an ``n in make test-long`` at that small size (a few
seconds each), its memory compared beyond start-up; the others (0) only in ``make fuzz``: at the
small sizes their leaks and quadratics were below the timer and the slack (the diff reader's cycles
and the total of pending queries have targeted tests there instead)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import memory_patterns as mp

check = mp.check_memory


def env() -> dict[str, str]:
    """The environment tshark_util runs tshark in (no personal configuration)."""
    return mp.tu._clean_env()


_IFACES = mp.serial_interfaces(mp.many_interfaces)

# name -> (make, n in make test-long (0: make fuzz only), n in make fuzz, growth limit: unused by check_memory)
PATTERNS: dict[str, tuple[Callable[[int, Path], list[str]], int, int, float]] = {
    "tshark-repeated-declaration": (mp.make_tshark(mp.repeated_declaration), 300, 20000, 2.0),
    "tshark-repeated-declaration-2": (mp.make_tshark(mp.repeated_declaration, "-2"), 0, 20000, 2.0),
    "tshark-new-layouts": (mp.make_tshark(mp.new_layouts), 300, 2500, 2.0),
    "tshark-bytewise-serial": (mp.make_tshark(mp.bytewise_frames, writer=mp.write_serial), 0, 8000, 2.0),
    # queriers of 256 names each: past max_pending_total (65,536 entries) from 256 queriers on, and
    # flat from about 1,200 (the Lua heap's collections); the fast form with a smaller total
    "tshark-many-queriers": (mp.make_tshark(mp.many_queriers), 0, 2000, 2.0),
    "tshark-many-queriers-total-4096": (mp.make_tshark(mp.many_queriers, "-o", "sharedlink.max_pending_total:4096"),
                                        100, 2000, 2.0),
    "stats-repeated-declaration": (mp.make_cli(mp.repeated_declaration, "stats", "{}"), 0, 20000, 2.0),
    "export-repeated-declaration": (mp.make_cli(mp.repeated_declaration, "export", "{}", "--format", "jsonl",
                                                "-o", "/dev/null"), 0, 20000, 2.0),
    "diff-repeated-declaration": (mp.make_cli(mp.repeated_declaration, "diff", "{}", "{}"), 0, 20000, 2.0),
    "plot-repeated-declaration": (mp.make_cli(mp.repeated_declaration, "plot", "{}", "-o", "{out}.png", "--force"),
                                  0, 20000, 2.0),
    "stats-many-queriers": (mp.make_cli(mp.many_queriers, "stats", "{}"), 300, 2000, 2.0),
    "stats-many-interfaces": (mp.make_cli(mp.many_interfaces, "stats", "{}", writer=_IFACES), 0, 4000, 2.0),
    "ingest-small-captures": (mp.make_ingest, 0, 400, 2.0),
}
