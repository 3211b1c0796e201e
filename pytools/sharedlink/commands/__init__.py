"""Sub-commands of the ``sharedlink`` CLI, one module each, and what they share.

A command module holds ``register(sub)`` and ``run(args) -> int`` and calls the library; what
several commands use lives here (as in pypa/twine ``twine/commands/__init__.py``), so that no
command imports another. Errors are raised (``sharedlink.errors``), never printed here:
``cli.main`` reports them once.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import struct
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from sharedlink.analysis.transform import transform_capture
from sharedlink.capture.pcapio import is_stdout
from sharedlink.errors import UsageError
from sharedlink.protocols.state import BEACON_VARIABLES, parse_variables

T = TypeVar("T")

# -- exit codes, for every command ------------------------------------------------------------

EXIT_OK, EXIT_FAIL, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
#: stopped by SIGTERM (128 + 15), cleaned up as on Ctrl-C
EXIT_TERMINATED = 143

# -- number options: one validator for all of them -----------------------------------------

#: the largest number of seconds any option takes (about 115 days)
MAX_SECONDS = 1e7
#: the highest rate in frames per second: one frame per nanosecond, the capture's resolution
MAX_RATE = 1e9


def number(
    low: float | None = None,
    high: float | None = None,
    *,
    above: bool = False,
    integer: bool = False,
    unit: str = "",
) -> Callable[[str], Any]:
    """An argparse ``type=`` for a number option: finite, at least ``low`` (more than it with
    ``above``), at most ``high``. NaN, infinities, huge or tiny values and words end in
    argparse's usage error (exit 2, ``argument --X: ...``), never in a traceback later on."""

    def bounds() -> str:
        lo = "" if low is None else (f"more than {low:g}" if above else f"at least {low:g}")
        hi = "" if high is None else f"at most {high:g}"
        return " and ".join(x for x in (lo, hi) if x) + (f" {unit}" if unit else "")

    def parse(text: str) -> int | float:
        try:
            value: int | float = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'a whole' if integer else 'a'} number") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        if (low is not None and (value < low or (above and value == low))) or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{text} is out of range: give a number {bounds()}")
        return value

    parse.__name__ = "integer" if integer else "number"  # argparse names the type in messages
    return parse


#: number types shared by several commands
SECONDS = number(0, MAX_SECONDS, above=True, unit="seconds")
SECONDS_OR_ZERO = number(0, MAX_SECONDS, unit="seconds")
RATE = number(0, MAX_RATE, above=True, unit="per second (a period of at least 1 ns)")
FRACTION = number(0, 1)
COUNT = number(1, 1e12, integer=True)
PORT = number(1, 65535, integer=True)
BAUD = number(1, 100_000_000, integer=True)

# -- options: --variables (one parser, one meaning in every command) and --sync-interval -----

VARIABLES_HELP = (
    "the a-priori outbound list positional frames are named by until the capture declares its own, "
    "NAME[:TYPE],... (TYPE 0 long, 2 double, 4 string; default the beacon's "
    "AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2)"
)


def add_variables_option(p: argparse.ArgumentParser) -> None:
    """``--variables NAME[:TYPE],...``, read by :func:`variables_option`."""
    p.add_argument("--variables", metavar="NAME[:TYPE],...", default=None, help=VARIABLES_HELP)


def variables_option(text: str | None) -> list[tuple[str, int | None]]:
    """The ``--variables`` list (the beacon's when not given); UsageError if bad."""
    if text is None:
        return list(BEACON_VARIABLES)
    try:
        return parse_variables(text)
    except ValueError as exc:
        raise UsageError(f"--variables: {exc}") from None


def name_list(text: str | None, option: str = "--vars") -> list[str] | None:
    """A comma-separated list of variable names (``--vars``): None when the option was not
    given; no name in it is a usage error."""
    if text is None:
        return None
    names = [v.strip() for v in text.split(",") if v.strip()]
    if not names:
        raise UsageError(f"{option}: no variable named")
    return names


def add_decode_options(p: argparse.ArgumentParser) -> None:
    """Options every capture-reading command of this family shares."""
    add_variables_option(p)
    p.add_argument(
        "--sync-interval", type=SECONDS, default=1.0, metavar="S",
        help="a full set is expected every S seconds (default 1; late = more than S + 0.5 s)",
    )


def decode_options(args: argparse.Namespace) -> tuple[list[tuple[str, int | None]], float]:
    """(variables, sync interval) from :func:`add_decode_options` options; UsageError if bad."""
    variables = variables_option(args.variables)
    if not args.sync_interval > 0:
        raise UsageError("--sync-interval must be positive")
    return variables, args.sync_interval


def check_capture(path: Path) -> None:
    """A capture to read must exist and be a file."""
    if not path.exists():
        raise UsageError(f"{path}: no such file")
    if path.is_dir():
        raise UsageError(f"{path}: is a directory, not a capture")


# -- commands that write a file (gen, serial) ----------------------------------------------------


#: about what one beacon record takes in a capture file (record header, headers, frame)
BEACON_RECORD_BYTES = 175
#: above this, a generator says what it is about to write before it starts
ANNOUNCE_BYTES = 1 << 30


def _size(n: float) -> str:
    for unit in ("bytes", "KB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} PB"  # pragma: no cover


def check_room(out: Path, records: int, record_bytes: int) -> None:
    """Say what a run would write: refuse (UsageError) when it cannot fit on the output's file
    system, announce it on stderr when it is large."""
    size = records * record_bytes
    if not is_stdout(out) and not str(out).startswith("/dev/"):
        folder = Path(out).resolve().parent
        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            free = None
        if free is not None and size > free:
            raise UsageError(f"{out}: would write {records:,} frames, about {_size(size)}, but {folder} has "
                             f"{_size(free)} free (lower --rate, --duration or --frames)")
    if size > ANNOUNCE_BYTES:
        print(f"writing {records:,} frames to {out}, about {_size(size)}", file=sys.stderr)


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
    except struct.error:  # a time stamp the file format cannot hold (the file is not left behind)
        raise UsageError(f"{out}: the times do not fit a nanosecond capture (pcap ends in 2106, pcapng in 2554): "
                         "give an earlier --start") from None


def report(summary: dict, as_json: bool, line: str) -> None:
    """The closing summary: JSON on stdout with ``--json``, else ``line`` on stderr."""
    if as_json:
        json.dump(summary, sys.stdout)
        print()
    else:
        print(line, file=sys.stderr)


# -- compress and expand -----------------------------------------------------------------------


def add_transform_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments ``compress`` and ``expand`` share."""
    p.add_argument("input", type=Path, help="pcap or pcapng capture to read")
    p.add_argument("output", type=Path, help="capture to write (same format as the input)")
    add_variables_option(p)
    p.add_argument("--json", action="store_true", help="print the summary as JSON")


def run_transform(args: argparse.Namespace, mode: str) -> int:
    """``compress`` / ``expand``: rewrite the capture, then the summary."""
    if not (args.sync_interval > 0 and math.isfinite(args.sync_interval)):
        raise UsageError("--sync-interval must be a positive number of seconds")
    variables = variables_option(args.variables)
    if args.json and is_stdout(args.output):
        raise UsageError("--json needs an output file (the capture goes to standard output)")
    st = transform_capture(args.input, args.output, mode, args.sync_interval, variables)
    if args.json:
        json.dump({"input": str(args.input), "output": str(args.output), "mode": mode, **st.to_dict()}, sys.stdout)
        print()
    else:
        saving = ""
        if st.saving is not None:
            saving = f" ({st.saving:.1%} smaller)" if st.saving >= 0 else f" ({-st.saving:.1%} larger)"
        print(
            f"wrote {args.output}: {st.records} records, {st.value_frames} value frames "
            f"({st.full} full, {st.delta} delta, {st.copied} copied unchanged), "
            f"SharedLink bytes {st.bytes_in} -> {st.bytes_out}{saving}",
            file=sys.stderr,
        )
    if st.error:
        print(f"sharedlink: error: {st.error} (the records before it were written)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK


# -- progress, for commands that read a whole capture ------------------------------------------

#: seconds of work before a progress bar appears (shorter runs never show one)
PROGRESS_AFTER_S = 2.0


class Progress:
    """A progress bar on stderr (rich) for a command reading ``path``: records, bytes, rate and
    time left. It appears only after :data:`PROGRESS_AFTER_S` seconds, and only when stdout and
    stderr are both terminals and ``quiet`` is False (never on a pipe, with ``--json`` or
    ``--quiet``). Call it with (bytes read, records read); use it as a context manager."""

    def __init__(self, path: Path | str | None, quiet: bool = False, what: str = "reading", unit: str = "records") -> None:
        import time

        self._clock = time.monotonic
        self.enabled = not quiet and sys.stdout.isatty() and sys.stderr.isatty()
        self.after = float(os.environ.get("SHAREDLINK_PROGRESS_AFTER", PROGRESS_AFTER_S))  # (tests: 0)
        self.start = self._clock()
        self.what, self.unit = what, unit
        self.total: int | None = None
        if self.enabled and path is not None:
            try:
                p = Path(path)
                self.total = p.stat().st_size if p.is_file() else None
            except OSError:
                self.total = None
        self._bar: Any = None
        self._task: Any = None

    def __call__(self, done: int, records: int = 0) -> None:
        if not self.enabled:
            return
        if self._bar is None:
            if self._clock() - self.start < self.after:
                return
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                DownloadColumn,
                TextColumn,
                TimeRemainingColumn,
                TransferSpeedColumn,
            )
            from rich.progress import Progress as Bar

            self._bar = Bar(TextColumn("{task.description}"), BarColumn(), DownloadColumn(), TransferSpeedColumn(),
                            TimeRemainingColumn(), console=Console(stderr=True), transient=True)
            self._task = self._bar.add_task(self.what, total=self.total)
            self._bar.start()
        self._bar.update(self._task, completed=done, description=f"{self.what}: {records:,} {self.unit}")

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
