"""Sub-commands of the ``sharedlink`` CLI, one module each, and what they share.

A command module holds ``register(sub)`` and ``run(args) -> int`` and calls the library; what
several commands use lives here (as in pypa/twine ``twine/commands/__init__.py``), so that no
command imports another. Errors are raised (``sharedlink.errors``), never printed here:
``cli.main`` reports them once.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import shutil
import struct
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from sharedlink.capture.pcapio import NS, is_stdout, replacing_links
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

#: a time factor (replay, watch): 2 plays twice as fast
SPEED = number(1e-3, 1e6, unit="(1e-3: a thousand times slower)")


def add_speed_option(p: argparse.ArgumentParser | Any, help: str) -> None:
    """``--speed X``: the one time factor."""
    p.add_argument("--speed", type=SPEED, default=1.0, metavar="X", help=help)


# -- options: --variables (one parser, one meaning in every command) and --sync-interval -----

VARIABLES_HELP = (
    "the lists positional frames are named by until the capture declares its own: NAME[:TYPE],... "
    "(TYPE 0 long, 2 double, 4 string), which names only frames with as many slots as it has "
    "(default the beacon's AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2), and/or a list per "
    "node pair that names every frame of that pair, 'B>A: NAME[:TYPE],...; A>B: ...' (as sharedlink lists prints them)"
)


def add_variables_option(p: argparse.ArgumentParser) -> None:
    """``--variables NAME[:TYPE],...`` (or per-pair lists), read by :func:`variables_option`."""
    p.add_argument("--variables", metavar="LIST", default=None, help=VARIABLES_HELP)


def variables_option(text: str | None) -> list[tuple[str, int | None]]:
    """The ``--variables`` lists (the beacon's when not given) as one flat list
    (:func:`sharedlink.protocols.state.parse_variables`: per-pair lists as ``"B>A:name"``
    entries); UsageError if bad, a type that is not a SharedLink type code (0, 2, 4) included."""
    if text is None:
        return list(BEACON_VARIABLES)
    try:
        return parse_variables(text)
    except ValueError as exc:
        raise UsageError(f"--variables: {exc}") from None


def name_list(text: str | None, option: str = "--select") -> list[str] | None:
    """A comma-separated list of variable names (``--select``): None when the option was not
    given; no name in it is a usage error."""
    if text is None:
        return None
    names = [v.strip() for v in text.split(",") if v.strip()]
    if not names:
        raise UsageError(f"{option}: no variable named")
    return names


def add_select_option(p: argparse.ArgumentParser | Any, help: str) -> None:
    """``--select NAME,...``: the variables a command shows (``--vars`` the old spelling); read
    with :func:`name_list`, the names checked against the capture's."""
    p.add_argument("--select", default=None, metavar="NAME,...", help=help)
    add_old_spelling(p, "--vars", "--select", "select")


#: the variables a track is drawn from, by option (the beacon's)
LOCATION = {"lat": "AutoGpsLat", "lon": "AutoGpsLon", "heading": "AutoGpsHead", "velocity": "AutoGpsVel"}
_LOCATION_HELP = {"lat": "latitude variable", "lon": "longitude variable", "heading": "heading variable (degrees)",
                  "velocity": "speed variable"}


def add_location_options(p: argparse.ArgumentParser | Any, what: str, *, names: tuple[str, ...] = tuple(LOCATION),
                         checked: bool = True) -> None:
    """``--lat``, ``--lon``, ``--heading``, ``--velocity`` (those in ``names``): the variables
    a track is drawn from. ``checked``: left None when not given, so that :func:`given_names`
    knows which the user named (and fills in the beacon's for the others)."""
    for key in names:
        p.add_argument(f"--{key}", default=None if checked else LOCATION[key], metavar="NAME",
                       help=f"{_LOCATION_HELP[key]} for {what} (default {LOCATION[key]})")


def given_names(args: argparse.Namespace) -> dict[str, list[str]]:
    """The variable names the user gave (``--select`` and the location options given), by
    option, to check once the capture's variables are known; fills in the defaults."""
    given: dict[str, list[str]] = {}
    selected = name_list(getattr(args, "select", None))
    if selected:
        given["--select"] = selected
    for key, default in LOCATION.items():
        if hasattr(args, key):
            if getattr(args, key) is None:
                setattr(args, key, default)
            else:
                given[f"--{key}"] = [getattr(args, key)]
    return given


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
    """A capture to read must exist and be a file: the one wording of these messages."""
    if not path.exists():
        raise UsageError(f"{path}: no such file")
    if path.is_dir():
        raise UsageError(f"{path}: is a directory, not a capture")


#: what ``-`` reads as a capture: standard input, read once front to back
STDIN = Path("/dev/stdin")


def capture_input(path: Path) -> Path:
    """The capture a command reads: ``-`` is standard input (every command reads its capture
    once, front to back, or copies a pipe: ``replay``), refused when it is a terminal; any other
    path must be a file (:func:`check_capture`)."""
    if str(path) == "-":
        if sys.stdin is None or sys.stdin.isatty():
            raise UsageError("-: standard input is a terminal: pipe a capture in (< capture.pcap)")
        return STDIN
    check_capture(path)
    return path


def unknown_names(wanted: dict[str, list[str]], known: list[str] | set[str]) -> None:
    """Names the user gave (``{"--select": [...], "--lat": [...]}``) that the capture never
    carries: a UsageError naming the first option and what the capture has."""
    have = set(known)
    for option, names in wanted.items():
        missing = [n for n in names if n not in have]
        if missing:
            what = ", ".join(sorted(have)) if have else "no variables"
            raise UsageError(f"{option}: no variable {', '.join(missing)} in the capture (it has {what})")


# -- the vocabulary: shared options and the old spellings (docs/cli.md) -----------------------

#: the note an old spelling prints on standard error, once per use
DEPRECATED = "sharedlink: warning: {old} is deprecated, use {new} (the old spelling goes in the next release)"


def deprecated(old: str, new: str) -> None:
    """Say on standard error that ``old`` is an old spelling of ``new``."""
    print(DEPRECATED.format(old=old, new=new), file=sys.stderr)


class OldSpelling(argparse.Action):
    """An old spelling kept for one release: stores into the new option's ``dest`` and says so
    on standard error. Hidden from ``--help``; docs/cli.md lists every one. As a positional
    (``nargs="?"``) it does nothing when absent."""

    def __init__(self, option_strings: list[str], dest: str, new: str, **kwargs: Any) -> None:
        self.new = new
        kwargs.setdefault("help", argparse.SUPPRESS)
        kwargs.setdefault("default", argparse.SUPPRESS if option_strings else None)
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        if values is None or values == []:  # an absent optional positional
            return
        if option_string is None:  # the positional: sharedlink gen OUT -> sharedlink gen -o OUT
            deprecated(f"'{parser.prog} {self.metavar}'", f"'{parser.prog} {self.new}'")
        else:
            deprecated(f"{parser.prog.split(' ', 1)[-1]} {option_string}", self.new)
        setattr(namespace, self.dest, values)


class OldFlag(argparse.Action):
    """An old spelling of a flag (no value), kept for one release: sets the new flag's ``dest``
    and says so on standard error; hidden from ``--help``."""

    def __init__(self, option_strings: list[str], dest: str, new: str, **kwargs: Any) -> None:
        self.new = new
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        deprecated(str(option_string), self.new)
        setattr(namespace, self.dest, True)


class OptionalPositional(argparse.Action):
    """An optional positional (``nargs="?"``) that leaves its ``dest`` alone when absent, so
    that an old option spelling of it (``watch --from``) is not overwritten."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        if values is not None:
            setattr(namespace, self.dest, values)


def add_old_spelling(p: argparse.ArgumentParser | Any, old: str, new: str, dest: str, **kwargs: Any) -> None:
    """``old`` as a hidden old spelling of ``new``: an option (``--out``) stores into ``dest``;
    a positional (``OUT``, optional) into ``old_<dest>``, which :func:`require_output` reads."""
    if old.startswith("-"):
        p.add_argument(old, dest=dest, action=OldSpelling, new=new, **kwargs)
    else:
        p.add_argument(f"old_{dest}", action=OldSpelling, new=new, nargs="?", metavar=old, **kwargs)


def add_output_option(p: argparse.ArgumentParser | Any, help: str, *, dest: str = "output", required: bool = False,
                      default: Any = None, metavar: str = "FILE", type: Callable[[str], Any] = Path) -> None:
    """``-o/--output FILE`` (``-``: standard output), the one name of every output."""
    p.add_argument("-o", "--output", dest=dest, type=type, default=default, required=required, metavar=metavar,
                   help=help)


def require_output(args: argparse.Namespace, dest: str = "output") -> Path:
    """The output, given as ``-o`` or by the old positional spelling; a UsageError when neither
    or both."""
    old, new = getattr(args, f"old_{dest}", None), getattr(args, dest, None)
    if old is not None and new is not None:
        raise UsageError(f"two outputs: {old} and -o {new}")
    out = new if new is not None else old
    if out is None:
        raise UsageError("no output: give -o FILE (-: standard output)")
    setattr(args, dest, Path(out))
    return Path(out)


def refuse_terminal(out: Path | str | None, what: str = "a capture") -> None:
    """Binary output (``-o -``) is refused when standard output is a terminal, as gzip and
    tcpdump -w - do: a UsageError, nothing written."""
    if out is not None and is_stdout(out) and sys.stdout is not None and sys.stdout.isatty():
        raise UsageError(f"-: standard output is a terminal and {what} is binary: redirect it (> file) or give -o FILE")


def format_from_suffix(out: Path | str | None, formats: dict[str, str], default: str, given: str | None) -> str:
    """The format an output is written in: ``given`` (``--format``) when given, else its file
    name's suffix (``formats``: suffix -> format), else ``default`` for a name without one or
    standard output. A suffix of no known format (``-o x.xlsx``) is a UsageError unless
    ``--format`` says what to write."""
    if given is not None:
        return given
    if out is None or is_stdout(out) or str(out).startswith("/dev/"):
        return default
    suffix = Path(out).suffix.lower()
    if not suffix:
        return default
    if suffix not in formats:
        known = ", ".join(sorted(formats))
        raise UsageError(f"{out}: {suffix} is not a format written here ({known}): give --format to write it anyway")
    return formats[suffix]


def add_json_option(p: argparse.ArgumentParser | Any, what: str = "the summary") -> None:
    """``--json``: what the command reports, as JSON on standard output."""
    p.add_argument("--json", action="store_true", help=f"print {what} as JSON on standard output")


def add_outage_after_option(p: argparse.ArgumentParser | Any) -> None:
    """``--outage-after S``: link health's fixed outage threshold (issue 43; default: learnt)."""
    p.add_argument("--outage-after", type=number(0, 86_400, above=True, unit="seconds"), default=None, metavar="S",
                   help="a silence longer than S seconds is an outage (default: the larger of 1 s and 3 periods of "
                   "each link's learnt rate)")


def start_time(high_ns: int | None = None) -> Callable[[str], int]:
    """An argparse ``type=`` for ``--start``: a UTC ISO 8601 date or time -> ns since 1970. A
    plain number (seconds since 1970, the old ``serial import --start``) is still read, with a
    deprecation note."""
    import datetime as dt

    seconds = number(0, None if high_ns is None else high_ns / 1e9 - 1, unit="seconds since 1970")

    def parse(text: str) -> int:
        try:
            float(text)
        except ValueError:
            pass
        else:
            value = seconds(text)
            deprecated(f"--start {text} (seconds since 1970)", "--start TIME in ISO 8601, e.g. 2026-03-02T08:00:00Z")
            return int(round(value * 1e9))
        try:
            t = dt.datetime.fromisoformat(text[:-1] + "+00:00" if text.endswith("Z") else text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an ISO 8601 time (e.g. 2026-03-02T08:00:00Z)") from None
        if t.tzinfo is None:
            t = t.replace(tzinfo=dt.timezone.utc)
        ns = int(t.timestamp()) * NS + t.microsecond * 1000
        if ns < 0 or (high_ns is not None and ns > high_ns):
            raise argparse.ArgumentTypeError(f"{text} is out of range: give a time from 1970 on that the capture can hold")
        return ns

    parse.__name__ = "time"
    return parse


# -- commands that write a file (gen, serial) ----------------------------------------------------

FORCE_HELP = ("an output that is a symbolic link: replace the link itself by the new file (its target is never "
              "written; without --force such an output is refused)")


def add_force_option(p: argparse.ArgumentParser) -> None:
    """``--force``, honoured by a ``run`` wrapped in :func:`honours_force`."""
    p.add_argument("--force", action="store_true", help=FORCE_HELP)


def honours_force(run: Callable[..., int]) -> Callable[..., int]:
    """A command's ``run(args, ...)`` whose outputs replace a symbolic link under ``--force``
    (outputs never write through one: see :func:`sharedlink.capture.pcapio.check_link`)."""

    @functools.wraps(run)
    def wrapped(args: argparse.Namespace, *rest: Any) -> int:
        with replacing_links(bool(getattr(args, "force", False))):
            return run(args, *rest)

    return wrapped



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
        note(f"writing {records:,} frames to {out}, about {_size(size)}")


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


def warn_empty(path: Path | str, count: int, what: str = "SharedLink frames") -> None:
    """An empty input is reported (a warning on stderr; the exit code stays): nothing in it."""
    if count == 0:
        print(f"sharedlink: warning: {path}: no {what}", file=sys.stderr)


def plural(n: int, word: str, words: str | None = None) -> str:
    """``1 frame``, ``2 frames``, ``19,842 frames`` (the tables' thousands-separator rule:
    sharedlink.present.count)."""
    from sharedlink.present.formats import count

    return f"{count(n)} {word if n == 1 else (words or word + 's')}"


def report(summary: dict, as_json: bool, line: str) -> None:
    """The closing summary: JSON on stdout with ``--json``, else ``line`` on stderr (not with
    ``--quiet``)."""
    if as_json:
        json.dump(summary, sys.stdout)
        print()
    else:
        note(line)


def _problem_names(text: str) -> tuple[str, ...]:
    from sharedlink.problems import PROBLEMS

    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    unknown = [n for n in names if n not in PROBLEMS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"{','.join(unknown) or repr(text)}: give one or more of {','.join(PROBLEMS)}")
    return names


_problem_names.__name__ = "problem list"


def add_fail_on_option(p: argparse.ArgumentParser | Any) -> None:
    """``--fail-on PROBLEM,...`` (stats): the problems of :mod:`sharedlink.problems`."""
    from sharedlink.problems import PROBLEMS

    p.add_argument("--fail-on", type=_problem_names, default=(), metavar="PROBLEM,...",
                   help=f"exit 1 when any of these occur in the capture (for CI): {', '.join(PROBLEMS)} "
                   f"({'; '.join(f'{k}: {v.words}' for k, v in PROBLEMS.items())})")


def fail_on(names: tuple[str, ...], st: Any) -> int:
    """``--fail-on``: EXIT_FAIL, with a line on stderr, when a named problem occurred in the
    statistics ``st``; else EXIT_OK (the names and their counts: :mod:`.fail_on`)."""
    from sharedlink.problems import failures

    found = failures(names, st) if names else None
    if found:
        print(f"sharedlink: failed: {found} (--fail-on {','.join(names)})", file=sys.stderr)
        return EXIT_FAIL
    return EXIT_OK


# -- --quiet: one meaning in every command ------------------------------------------------------

QUIET_HELP = ("no progress bar, no per-file lines and no closing summary on standard error (warnings, errors "
              "and what goes to standard output are still printed)")
#: the running command's --quiet (set by cli.main from the parsed arguments: read by
#: :class:`Progress`, :func:`report` and :func:`note`, so that no command has to pass it on)
QUIET = False


def add_quiet_option(p: argparse.ArgumentParser | Any) -> None:
    """``--quiet``/``-q``: the same on every command that shows progress or a summary."""
    p.add_argument("--quiet", "-q", action="store_true", help=QUIET_HELP)


def set_quiet(args: argparse.Namespace) -> None:
    global QUIET
    QUIET = bool(getattr(args, "quiet", False))


def note(line: str) -> None:
    """An informational line on standard error (what was written, what is about to be): not
    with ``--quiet``."""
    if not QUIET:
        print(line, file=sys.stderr)


# -- compress and expand -----------------------------------------------------------------------


def add_transform_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments ``compress`` and ``expand`` share."""
    p.add_argument("input", type=Path, help="pcap or pcapng capture to read (-: standard input)")
    add_old_spelling(p, "OUT", "-o OUT", "output", type=Path)
    add_output_option(p, "capture to write, same format as the input (-: standard output)")
    add_variables_option(p)
    add_json_option(p)
    add_force_option(p)
    add_quiet_option(p)


@honours_force
def run_transform(args: argparse.Namespace, mode: str) -> int:
    """``compress`` / ``expand``: rewrite the capture, then the summary."""
    require_output(args)
    refuse_terminal(args.output)
    args.input = capture_input(args.input)
    if not (args.sync_interval > 0 and math.isfinite(args.sync_interval)):
        raise UsageError("--sync-interval must be a positive number of seconds")
    variables = variables_option(args.variables)
    if args.json and is_stdout(args.output):
        raise UsageError("--json needs an output file (the capture goes to standard output)")
    from sharedlink.analysis.transform import transform_capture  # (when the command runs: quick start-up)

    what = {"compress": "compressing", "expand": "expanding"}[mode]
    with Progress(args.input, quiet=args.json, what=what) as progress:
        st = transform_capture(args.input, args.output, mode, args.sync_interval, variables, progress)
    warn_empty(args.input, st.records, "records")
    if args.json:
        json.dump({"input": str(args.input), "output": str(args.output), "mode": mode, **st.to_dict()}, sys.stdout)
        print()
    else:
        saving = ""
        if st.saving is not None:
            saving = f" ({st.saving:.1%} smaller)" if st.saving >= 0 else f" ({-st.saving:.1%} larger)"
        note(
            f"wrote {args.output}: {st.records} records, {st.value_frames} value frames "
            f"({st.full} full, {st.delta} delta, {st.copied} copied unchanged), "
            f"SharedLink bytes {st.bytes_in} -> {st.bytes_out}{saving}"
        )
    if st.error:
        print(f"sharedlink: error: {st.error} (the records before it were written)", file=sys.stderr)
        return EXIT_USAGE
    return EXIT_OK


# -- tables: sharedlink.present (what people read: one format per kind of number, tables fitted
#    to the terminal, plain on a pipe) -------------------------------------------------------------


# -- progress, for commands that read a whole capture ------------------------------------------

#: seconds of work before a progress bar appears (shorter runs never show one)
PROGRESS_AFTER_S = 2.0


class Progress:
    """A progress bar on stderr (rich) for a command reading ``path``: records, bytes, rate and
    time left. It appears only after :data:`PROGRESS_AFTER_S` seconds, and only when stdout and
    stderr are both terminals and ``quiet`` is False (never on a pipe, with ``--json`` or
    ``--quiet``). Call it with (bytes read, records read); use it as a context manager."""

    def __init__(self, path: Path | str | Sequence[Path | str] | None, quiet: bool = False, what: str = "reading",
                 unit: str = "records") -> None:
        import time

        self._clock = time.monotonic
        self.enabled = not (quiet or QUIET) and sys.stdout.isatty() and sys.stderr.isatty()
        self.after = float(os.environ.get("SHAREDLINK_PROGRESS_AFTER", PROGRESS_AFTER_S))  # (tests: 0)
        self.start = self._clock()
        self.what, self.unit = what, unit
        self.total: int | None = None
        if self.enabled and path is not None:
            try:  # the total size of the files read (None when one is a pipe)
                files = [Path(p) for p in ([path] if isinstance(path, (str, Path)) else path)]
                self.total = sum(p.stat().st_size for p in files) if all(p.is_file() for p in files) else None
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
