"""What the commands that write a file share: running a generator with its errors turned into
usage errors, and the closing summary (JSON on stdout, or one line on stderr)."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from sharedlink.errors import UsageError

T = TypeVar("T")


def generate_to(opts: Any, generate: Callable[[Any, Path], T], out: Path) -> T:
    """``opts.validate()`` then ``generate(opts, out)``; a bad option or an unwritable file is a
    :class:`UsageError` (exit 2), never a traceback."""
    try:
        opts.validate()
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    try:
        return generate(opts, out)
    except OSError as exc:
        raise UsageError(f"{out}: {exc.strerror or exc}") from None


def report(summary: dict, as_json: bool, line: str) -> None:
    """The summary as JSON on stdout with ``--json``, else ``line`` on stderr."""
    if as_json:
        json.dump(summary, sys.stdout)
        print()
    else:
        print(line, file=sys.stderr)
