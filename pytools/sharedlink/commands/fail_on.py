"""``stats --fail-on NAME,...``: exit 1 when the named problems occur in a capture (for CI).

The problems are named here, in one place: another check is one more :func:`problem` entry
(its name, the words for people, and how to count it in a ``CaptureStats``), and ``--fail-on``,
its help, docs/cli.md's list (a test holds them together) and the message follow.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["PROBLEMS", "Problem", "add_fail_on_option", "failures", "problem"]


@dataclass(frozen=True)
class Problem:
    name: str  # as --fail-on takes it
    words: str  # what a count of them is called, plural ("bad checksums")
    count: Callable[[Any], int]  # how many in a CaptureStats


#: the problems --fail-on knows, by name, in the order messages list them
PROBLEMS: dict[str, Problem] = {}


def problem(name: str, words: str, count: Callable[[Any], int]) -> None:
    """Make ``name`` a problem ``--fail-on`` takes."""
    PROBLEMS[name] = Problem(name, words, count)


problem("checksum", "bad checksums", lambda st: st.checksum_failures)
problem("late", "late full sets", lambda st: st.sync_late)


def _names(text: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    unknown = [n for n in names if n not in PROBLEMS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"{','.join(unknown) or repr(text)}: give one or more of {','.join(PROBLEMS)}")
    return names


_names.__name__ = "problem list"


def add_fail_on_option(p: argparse.ArgumentParser | Any) -> None:
    p.add_argument("--fail-on", type=_names, default=(), metavar="PROBLEM,...",
                   help=f"exit 1 when any of these occur in the capture (for CI): {', '.join(PROBLEMS)} "
                   f"({'; '.join(f'{k}: {v.words}' for k, v in PROBLEMS.items())})")


def failures(names: tuple[str, ...], st: Any) -> str | None:
    """What of ``names`` occurred in ``st``, for the message (``3 bad checksums, 1 late full
    set``), or None when nothing did."""
    found = [(PROBLEMS[n], PROBLEMS[n].count(st)) for n in names]
    said = [f"{c} {p.words if c != 1 else p.words.replace('checksums', 'checksum').replace('sets', 'set')}"
            for p, c in found if c]
    return ", ".join(said) or None
