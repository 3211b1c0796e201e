"""The `sharedlink` command as a process, for the tests that run it: ``CLI`` (this Python's
``-m sharedlink``, so the worktree's package), :func:`run_cli`, its one runner, and
:func:`in_zone`, the environment of a run in another time zone."""

from __future__ import annotations

import os
import subprocess
import sys
from typing import Any

import sl_zygote

CLI = [sys.executable, "-m", "sharedlink"]


def run_cli(*args: object, timeout: float = 120, check: bool = False, text: bool = True,
            **kw: Any) -> subprocess.CompletedProcess[Any]:
    """``sharedlink ARGS`` (each argument as ``str``), its standard output and error captured
    (as text unless ``text`` is false); ``timeout`` guards against a hang only; ``check``: exit
    status 0 asserted (its standard error shown on failure). ``kw`` goes to ``subprocess.run``
    (``env``, ``cwd``, ``input``, ``stdin``). The run is forked from a loaded interpreter
    (``sl_zygote``: a real process, spared the start-up) when the zygote can reproduce it, else
    a plain ``subprocess.run``; ``SHAREDLINK_ZYGOTE=0`` starts every run as a plain process."""
    cmd = [*CLI, *map(str, args)]
    r = sl_zygote.run(cmd, timeout, text, **kw)
    if r is None:
        r = subprocess.run(cmd, capture_output=True, text=text, timeout=timeout, **kw)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def in_zone(tz: str) -> dict[str, str]:
    """This environment with the time zone ``tz`` (``TZ``) and a terminal 200 columns wide."""
    return {**os.environ, "TZ": tz, "COLUMNS": "200"}
