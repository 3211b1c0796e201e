"""Times as the outputs write them: UTC ISO 8601 with nanoseconds."""

from __future__ import annotations

from sharedlink.capture.pcapio import NS


def format_time(ts_ns: int) -> str:
    """UTC ISO 8601 with nanoseconds: ``2026-01-01T12:00:00.200000000Z``. Any year (past 9999
    it has more digits, as ISO 8601's expanded years; before year 1 a sign)."""
    global _last_second
    sec, frac = divmod(ts_ns, NS)
    last = _last_second  # (one tuple, replaced whole: safe between threads)
    if sec != last[0]:  # frames come several a second: the date and time once a second
        last = _last_second = (sec, _format_second(sec))
    return "%s.%09dZ" % (last[1], frac)


_last_second: tuple[int | None, str] = (None, "")


def _format_second(sec: int) -> str:
    days, rest = divmod(sec, 86400)
    y, m, d = _civil_from_days(days)
    year = "%04d" % y if 0 <= y <= 9999 else "%+05d" % y
    return "%s-%02d-%02dT%02d:%02d:%02d" % (year, m, d, rest // 3600, rest // 60 % 60, rest % 60)


def _civil_from_days(z: int) -> tuple[int, int, int]:
    """(year, month, day) of day ``z`` counted from 1970-01-01, proleptic Gregorian, any year
    (Howard Hinnant's ``civil_from_days``)."""
    z += 719468
    era = z // 146097
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    d = doy - (153 * mp + 2) // 5 + 1
    m = mp + 3 if mp < 10 else mp - 9
    return yoe + era * 400 + (m <= 2), m, d
