"""Issue 31's patterns for the Python commands, for ``make fuzz`` (scripts/fuzz.py's scaling
stage): each pattern of test_python_scaling.py written at its make-fuzz size N and 4N and run as
the ``sharedlink`` command a user runs (a fresh process; CPU time and peak RSS beyond a one-frame
baseline, ``scaling.check_scaling``). test_python_scaling.py checks the same patterns in-process
at the smaller sizes (the ``n in make test`` column is those sizes, for the record)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from pathlib import Path

FUZZ = Path(__file__).resolve().parent
if str(FUZZ) not in sys.path:
    sys.path.insert(0, str(FUZZ))

import test_python_scaling as tps  # noqa: E402

CLI = [sys.executable, "-m", "sharedlink"]


def make(pattern: Callable[[int], Sequence], *command: str,
         writer: Callable[[Path, Sequence], Path] = tps.write) -> Callable[[int, Path], list[str]]:
    """``sharedlink COMMAND CAPTURE ARGS`` on the pattern written at size n (``{}`` in the
    arguments is the capture)."""

    def run(n: int, tmp: Path) -> list[str]:
        suffix = ".pcapng" if writer is tps.write_serial else ".pcap"
        path = writer(tmp / f"{pattern.__name__}-{n}{suffix}", pattern(n))
        return [*CLI, *(str(path) if a == "{}" else a for a in command)]

    return run


# name -> (make, n in make test, n in make fuzz, growth limit)
PATTERNS: dict[str, tuple[Callable[[int, Path], list[str]], int, int, float]] = {
    # 4N = 48000 frames: 16000 new names per direction, past MAX_NAMES (dropped and counted)
    "stats-new-names": (make(tps.new_names, "stats", "{}"), 1000, 12000, 5.0),
    "export-new-names": (make(tps.new_names, "export", "{}", "--format", "jsonl", "--changes", "-o", "-"), 1000, 12000, 5.0),
    "diff-new-names": (make(tps.new_names, "diff", "{}", "{}"), 1000, 12000, 5.0),
    "stats-bad-checksums": (make(tps.bad_checksums, "stats", "{}"), 300, 1200, 5.0),
    "stats-replies-big-list": (make(tps.replies_in_a_big_list, "stats", "{}"), 8000, 32000, 5.0),
    "stats-conversations": (make(tps.conversations, "stats", "{}"), 1000, 10000, 5.0),
    # three MCAP channels a conversation: 4N = 20000 stays under MCAP's 65535 channels (past them
    # every message is an error line: test_mcap_of_more_conversations..., an xfail)
    "mcap-conversations": (make(tps.conversations, "export", "{}", "--format", "mcap", "-o", "/dev/null"), 2000, 5000, 5.0),
    "diff-conversations": (make(tps.conversations, "diff", "{}", "{}"), 1000, 10000, 5.0),
    "stats-serial-unterminated": (make(tps.sl_unterminated, "stats", "{}", writer=tps.write_serial), 4000, 15000, 5.0),
    "stats-serial-past-the-limit": (make(tps.past_the_limit, "stats", "{}", writer=tps.write_serial), 200, 4000, 5.0),
}
