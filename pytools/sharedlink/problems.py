"""The problems a capture can have that a CI job may fail on (``stats --fail-on NAME,...``).

They are named here, in one place: another check is one more :func:`problem` entry (its name,
the words for people, and how to count it in a ``CaptureStats``), and ``--fail-on``, its help,
docs/cli.md's list (a test holds them together) and the message follow.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["PROBLEMS", "Problem", "failures", "problem"]


@dataclass(frozen=True)
class Problem:
    name: str  # as --fail-on takes it
    word: str  # what one is called ("bad checksum")
    words: str  # and more than one ("bad checksums")
    count: Callable[[Any], int]  # how many in a CaptureStats


#: the problems --fail-on knows, by name, in the order messages list them
PROBLEMS: dict[str, Problem] = {}


def problem(name: str, word: str, words: str, count: Callable[[Any], int]) -> None:
    """Make ``name`` a problem ``--fail-on`` takes."""
    PROBLEMS[name] = Problem(name, word, words, count)


problem("checksum", "bad checksum", "bad checksums", lambda st: st.checksum_failures)
#: a full set more than the sync interval + 0.5 s after the one before (``sync_gaps``); a capture
#: whose frames went on while a full set was overdue and none came (``sync_late`` only) has one
problem("late", "late full set", "late full sets", lambda st: max(st.sync_gaps, 1 if st.sync_late else 0))
problem("outage", "outage", "outages", lambda st: len(st.health.outages()))


def failures(names: tuple[str, ...], st: Any) -> str | None:
    """What of ``names`` occurred in ``st``, for the message (``3 bad checksums, 1 late full
    set``), or None when nothing did."""
    found = [(PROBLEMS[n], PROBLEMS[n].count(st)) for n in names]
    said = [f"{c} {p.word if c == 1 else p.words}" for p, c in found if c]
    return ", ".join(said) or None
