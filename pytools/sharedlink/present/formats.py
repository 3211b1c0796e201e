"""One text format per kind of number, for every table and summary people read.

The rules (docs/cli.md, "What the tables show"):

* counts and sizes (:func:`count`): integers with a comma every three digits, ``19,842``;
  the one thousands-separator rule. Values a capture carries are never separated (they are
  data: an id, a time in ns);
* a variable's value (:func:`value`): as its type says: a long (or an untyped value that is a
  whole number) as an integer, ``12``, never ``12.0``; a double by Python's shortest
  round-trip text, ``12.5``;
* measured quantities (:func:`real`): fixed decimals (3 unless said), ``10.000``;
* durations (:func:`duration`): ``2d 07h 33m 19.800s``, ``1h 02m 03.400s``, ``2m 03.400s``,
  ``3.400s``: milliseconds always, the larger units only when they are not zero;
* times (:func:`timestamp`): UTC, ISO 8601 with nanoseconds, ``2026-01-01T12:00:00.200000000Z``
  (the exports' format, :func:`sharedlink.analysis.decode.format_time`).

``None`` is an empty cell everywhere.
"""

from __future__ import annotations

import datetime as _dt
import math
import re

#: the kinds of cell a table column holds (tables.Column.kind)
TEXT = "text"  # left-aligned; may be cut ("…") when the column says so
PROSE = "prose"  # left-aligned, wraps at spaces
COUNT = "count"  # right-aligned, thousands separators
INTEGER = "integer"  # right-aligned, as is (an id, a time in ns)
VALUE = "value"  # a variable's value: right-aligned, :func:`value`
REAL = "real"  # right-aligned, fixed decimals
DURATION = "duration"  # seconds, right-aligned, :func:`duration`
TIME = "time"  # ns since 1970 (or a datetime), :func:`timestamp`
#: the kinds that are numbers: right-aligned and never cut nor wrapped
NUMERIC = frozenset({COUNT, INTEGER, VALUE, REAL, DURATION, TIME})

#: the largest float whose whole values are all exact integers (2**53)
_EXACT = float(2**53)


def count(n: int | None) -> str:
    """``19,842``."""
    return "" if n is None else f"{n:,}"


def integer(n: int | None) -> str:
    return "" if n is None else str(int(n))


def value(x: float | int | None, integral: bool | None = None) -> str:
    """A variable's number: ``integral`` True (a long) or None (untyped) and a whole number:
    the integer; otherwise the shortest text that reads back as ``x``."""
    if x is None:
        return ""
    if isinstance(x, bool):
        return str(int(x))
    if isinstance(x, int):
        return str(x)
    if integral is not False and math.isfinite(x) and x.is_integer() and abs(x) <= _EXACT:
        return str(int(x))
    return repr(float(x))


def real(x: float | None, decimals: int = 3) -> str:
    """``10.000``."""
    return "" if x is None else f"{x:.{decimals}f}"


def duration(seconds: float | None) -> str:
    """``1h 02m 03.400s``: hours, minutes (and days) only when not zero, milliseconds always."""
    if seconds is None:
        return ""
    if not math.isfinite(seconds):
        return str(seconds)
    sign = "-" if seconds < 0 else ""
    ms = round(abs(seconds) * 1000)
    s, ms = divmod(ms, 1000)
    m, s = divmod(s, 60)
    h, m = divmod(m, 60)
    d, h = divmod(h, 24)
    if d:
        return f"{sign}{d}d {h:02d}h {m:02d}m {s:02d}.{ms:03d}s"
    if h:
        return f"{sign}{h}h {m:02d}m {s:02d}.{ms:03d}s"
    if m:
        return f"{sign}{m}m {s:02d}.{ms:03d}s"
    return f"{sign}{s}.{ms:03d}s"


def timestamp(t: int | _dt.datetime | None) -> str:
    """UTC with nanoseconds, ``2026-01-01T12:00:00.200000000Z``, of ns since 1970 or of a
    datetime (a naive one is taken as UTC)."""
    if t is None:
        return ""
    if isinstance(t, _dt.datetime):
        t = datetime_ns(t)
    from sharedlink.analysis.decode import format_time  # (the one home of the format)

    return format_time(int(t))


def datetime_ns(t: _dt.datetime) -> int:
    """ns since 1970 of a datetime (naive: UTC)."""
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.timezone.utc)
    delta = t - _dt.datetime(1970, 1, 1, tzinfo=_dt.timezone.utc)
    return (delta.days * 86400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1000


#: how each kind of cell is written (text kinds: str)
FORMATS = {COUNT: count, INTEGER: integer, VALUE: value, REAL: real, DURATION: duration, TIME: timestamp}


def cell(x: object, kind: str = TEXT) -> str:
    """``x`` as a cell of ``kind`` (strings pass through whatever the kind: a cell already
    written, e.g. ``"3 (late)"``)."""
    if x is None:
        return ""
    if isinstance(x, str):
        return x
    fmt = FORMATS.get(kind)
    return fmt(x) if fmt is not None else str(x)  # type: ignore[operator]


_ESCAPES = {"\r": "\\r", "\n": "\\n", "\t": "\\t", "\\": "\\\\"}
_CONTROL = re.compile(r"[\x00-\x1f\x7f\\]")


def one_line(text: str) -> str:
    """A value on one table row, as the packet details and the tap's report show it: CR, LF, TAB
    and a backslash escaped (``\\r``, ``\\n``, ``\\t``, ``\\\\``), any other control
    character as ``\\xhh``."""
    return _CONTROL.sub(lambda m: _ESCAPES.get(m.group(), "\\x%02x" % ord(m.group())), text)
