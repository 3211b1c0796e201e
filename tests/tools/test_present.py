"""What people read (issue 41, items 1 and 2): one format per kind of number, tables fitted to a
terminal (a real pseudo-terminal, COLUMNS 80 and 200) and plain or CSV on a pipe, for stats,
diff and query; and plots of a long faulty capture: markers thinned (counted from the figure's
artists), clock time, units, one legend."""

from __future__ import annotations

import csv
import datetime as dt
import io
import os
import re
from functools import partial
from pathlib import Path

import pytest
from sl_captures import write_capture
from sl_cli import CLI, run_cli
from sl_pipes import on_pty

from sharedlink.present import COUNT, DURATION, PROSE, TEXT, TIME, Column, Table, fit, plain
from sharedlink.present.formats import count, duration, timestamp, value
from sharedlink.present.tables import MIN_WIDTH
from sharedlink.protocols.codec import encode_named

T0 = 1_767_268_799_990_493_941  # 2026-01-01T11:59:59.990493941Z
ESC = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


#: `sharedlink ARGS` (some of these runs are long)
run = partial(run_cli, timeout=300)


def on_terminal(columns: int, *args) -> str:
    env = dict(os.environ, COLUMNS=str(columns), LINES="60", TERM="xterm")
    code, out = on_pty([*CLI, *map(str, args)], env, timeout=300)
    assert code == 0, out
    return ESC.sub("", out).replace("\r\n", "\n")


# -- formats --------------------------------------------------------------------------------------


def test_one_format_per_kind():
    assert count(1234567) == "1,234,567" and count(0) == "0"
    # a long's min and max are integers, never 1.0; a double keeps its digits
    assert value(1.0, True) == "1" and value(1234567.0, None) == "1234567" and value(-3.0, True) == "-3"
    assert value(1.0, False) == "1.0" and value(38.34698779, False) == "38.34698779"
    assert value(2.5, None) == "2.5" and value(1e300, None) == "1e+300"
    assert duration(199999.8) == "2d 07h 33m 19.800s"
    assert duration(3723.4) == "1h 02m 03.400s" and duration(123.4) == "2m 03.400s" and duration(0.25) == "0.250s"
    assert timestamp(T0) == "2026-01-01T11:59:59.990493941Z"
    plus_two = dt.datetime(2026, 1, 1, 14, 0, 0, 123456, tzinfo=dt.timezone(dt.timedelta(hours=2)))
    assert timestamp(plus_two) == "2026-01-01T12:00:00.123456000Z"  # UTC, nine digits


def _table() -> Table:
    t = Table("t", [Column("name"), Column("frames", COUNT), Column("note", TEXT, cut=True, drop=2),
                    Column("when", TIME, drop=1), Column("took", DURATION), Column("words", PROSE, drop=3)],
              more="--json has every column")
    t.add("B>A", 1234567, "x" * 60, T0, 3723.4, "one two three four")
    t.add("A>B", 3, "short", T0 + 1, 0.5, "five")
    return t


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.split("│")]


def test_fit_cuts_text_then_leaves_out_columns_and_never_cuts_numbers():
    t = _table()
    whole = fit(t, 500)
    assert whole is not None and whole.note is None and len(whole.columns) == 6
    narrow = fit(t, 90)
    assert narrow is not None and "cut to fit: note" in narrow.note and "--json has every column" in narrow.note
    assert narrow.widths[1] >= len("1,234,567") and narrow.widths[3] == len(timestamp(T0))
    assert sum(narrow.widths[i] for i in narrow.columns) + 3 * (len(narrow.columns) - 1) <= 90
    tight = fit(t, 45)
    assert tight is not None and tight.columns == [0, 1, 4, 5]  # left out by rank: when (1), then note (2)
    assert "left out to fit the terminal: note, when" in tight.note
    assert all(w >= MIN_WIDTH for w in tight.widths.values())
    assert fit(t, 20) is None  # the numbers alone are wider: the caller prints plain lines


def test_plain_text_right_aligns_numbers():
    lines = plain(_table()).splitlines()
    assert lines[0] == "t"
    head, first, second = lines[1:]
    end = head.index("frames") + len("frames")
    assert first[:end].endswith("1,234,567") and second[:end].endswith(" 3")  # right-aligned under the header
    assert "2026-01-01T11:59:59.990493941Z" in first and "1h 02m 03.400s" in first and "0.500s" in second


# -- stats, diff, query on a terminal and a pipe -----------------------------------------------------


@pytest.fixture(scope="module")
def longs(tmp_path_factory) -> Path:
    """A capture with a long variable whose values are whole numbers, and a double."""
    datagrams = []
    for i, n in enumerate([1, 5, 1234567, 7, 1] * 8):
        datagrams.append((T0 + i * 200_000_000, encode_named("A", "B", [("Count", 0, str(n)), ("Speed", 2, "%.2f" % (i / 4))])))
    return write_capture(tmp_path_factory.mktemp("longs") / "longs.pcap", datagrams)


@pytest.mark.parametrize("columns", [80, 200])
def test_stats_on_a_terminal(longs, columns):
    text = on_terminal(columns, "stats", longs)
    assert max(len(line) for line in text.splitlines()) <= columns, text
    assert "│" in text and "┃" not in text and "━" not in text  # light borders
    count_row = next(line for line in text.splitlines() if "Count" in line and "│" in line)
    cells = _cells(count_row)
    assert "1" in cells and "1234567" in cells and "1.0" not in count_row and "1234567.0" not in count_row, count_row
    assert "2026-01-01T11:59:59.990493941Z" in text  # the first frame: UTC with nanoseconds
    assert re.search(r"duration\s+│\s+7\.800s", text), text
    if columns == 200:
        assert "left out" not in text and "cut to fit" not in text
        for header in ("kinds", "longest full-set interval", "last", "changes"):
            assert header in text


def test_stats_on_a_pipe_is_plain_text(longs):
    r = run("stats", longs)
    assert r.returncode == 0 and "│" not in r.stdout and "─" not in r.stdout
    lines = r.stdout.splitlines()
    head = next(line for line in lines if line.split()[:3] == ["pair", "name", "count"])
    row = next(line for line in lines if " Count " in line)
    assert row[: head.index("count") + len("count")].endswith(" 40")  # right-aligned under its header
    assert re.search(r"\s1\s+1234567\s+1$", row), row  # min, max, last: integers


def test_diff_on_a_terminal(longs, tmp_path):
    assert run("compress", longs, "-o", tmp_path / "c.pcap").returncode == 0
    for columns in (80, 200):
        text = on_terminal(columns, "diff", longs, tmp_path / "c.pcap")
        assert max(len(line) for line in text.splitlines()) <= columns, text
        assert "Count" in text and "Speed" in text and "AGREE" in text
    r = run("diff", longs, tmp_path / "c.pcap")
    assert "│" not in r.stdout and re.search(r"SharedLink frames\s+40\s+40", r.stdout), r.stdout


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("ds")
    (d / "caps").mkdir()
    assert run("gen", "-o", d / "caps" / "drive.pcap", "--frames", "50").returncode == 0
    r = run("ingest", d / "caps", "-o", d / "ds")
    assert r.returncode == 0, r.stderr
    return d / "ds"


def test_query_on_an_80_column_terminal(dataset):
    text = on_terminal(80, "query", dataset, "select * from frames order by seq limit 2")
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80, text
    rule = next(line for line in lines if "┼" in line)
    assert all(len(seg) >= MIN_WIDTH for seg in rule.split("┼")), rule  # no column one character wide
    header = lines[lines.index(rule) - 1]
    shown = _cells(header)
    assert shown[0] == "capture" and "time_ns" in shown, header
    assert "left out to fit the terminal:" in text and "(2 rows)" in text
    first = lines[lines.index(rule) + 1]
    assert re.search(r"│\s+\d{19}\s+│", first), first  # time_ns whole, right-aligned
    # (every value of a left-out column is one a CSV has)


def test_query_on_a_terminal_shows_the_first_and_last_rows(dataset):
    sql = "select seq from frames order by seq"
    lines = on_terminal(80, "query", dataset, sql).splitlines()
    cells = [line.strip() for line in lines if re.fullmatch(r"\s*(\d+|…)", line)]
    assert cells == [str(i) for i in range(1, 21)] + ["…"] + [str(i) for i in range(31, 51)]
    assert "(50 rows, 40 shown)" in lines
    lines = on_terminal(80, "query", dataset, sql, "--max-rows", "0").splitlines()
    assert [line.strip() for line in lines if re.fullmatch(r"\s*\d+", line)] == [str(i) for i in range(1, 51)]
    assert "(50 rows)" in lines


def test_query_times_keep_their_nanoseconds(dataset):
    sql = "select time_ns, time, day from frames order by seq limit 3"
    text = on_terminal(200, "query", dataset, sql)
    rows = [_cells(line) for line in text.splitlines() if re.match(r"\s*\d{19}", line)]
    assert len(rows) == 3
    for ns, time_text, _day in (r[:3] for r in rows):
        assert time_text == timestamp(int(ns)), (ns, time_text)
    r = run("query", dataset, sql)  # a pipe: CSV
    got = list(csv.reader(io.StringIO(r.stdout)))
    assert got[0] == ["time_ns", "time", "day"] and len(got) == 4
    assert all(row[1] == timestamp(int(row[0])) for row in got[1:]), got
    r = run("query", dataset, sql, "--json")
    assert [d["time"] for d in __import__("json").loads(r.stdout)] == [row[1] for row in got[1:]]


def test_query_table_on_a_pipe_is_plain(dataset):
    r = run("query", dataset, "select seq, pair, size from frames order by seq limit 2", "--format", "table")
    assert r.returncode == 0 and "│" not in r.stdout and "(2 rows)" in r.stdout
    assert re.search(r"^\s+seq\s+pair\s+size$", r.stdout, re.M), r.stdout
    r = run("query", dataset, "select seq, pair from frames where false", "--format", "table")
    assert r.stdout.split() == ["seq", "pair", "(0", "rows)"]  # no rows: the headers still


# -- plots ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def faulty(tmp_path_factory) -> Path:
    """A long faulty capture: 11 hours (an axis in hours) at 1.25 Hz, 50,000 frames, 1 % bad
    checksums, 1 % dropped (some 500 of each: more than the 300 markers a kind the plot keeps;
    1M frames are make bench's)."""
    path = tmp_path_factory.mktemp("faulty") / "faulty.pcap"
    r = run("gen", "-o", path, "--duration", "40000", "--rate", "1.25", "--compress", "--bad-checksum", "0.01",
            "--drop", "0.01")
    assert r.returncode == 0, r.stderr
    return path


def test_plot_of_a_long_faulty_capture(faulty, tmp_path):
    """The command on a long faulty capture (its speed, 1M frames under 10 s of CPU, is
    `make bench`'s plot line: bench/bench_plot.py)."""
    r = run("plot", faulty, "-o", tmp_path / "f.png", "--json")
    assert r.returncode == 0, r.stderr
    summary = __import__("json").loads(r.stdout)
    assert summary["frames"] > 47_000 and summary["checksum_failures"] > 300 and summary["dropped_frames"] > 300


@pytest.fixture(scope="module")
def figure(faulty):
    import matplotlib

    matplotlib.use("Agg")
    from sharedlink.analysis.plot import build_figure, collect

    data = collect(faulty)
    fig = build_figure(data)
    fig.canvas.draw()
    return data, fig


def test_plot_markers_are_thinned_and_panels_not_painted_red(figure):
    from sharedlink.analysis.plot import BAD_COLOUR, DROPPED_COLOUR, MAX_MARKERS

    data, fig = figure
    assert data.checksum_failures > MAX_MARKERS and data.gaps > MAX_MARKERS
    track, *panels, events = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    marks = {line.get_label(): len(line.get_xdata()) for line in track.get_lines() if line.get_linestyle() == "None"}
    bad = next(k for k in marks if k.startswith("bad checksums ("))
    dropped = next(k for k in marks if k.startswith("frames dropped ("))
    assert marks[bad] == MAX_MARKERS and f"{data.checksum_failures:,}" in bad and f"{MAX_MARKERS} drawn" in bad
    assert marks[dropped] == MAX_MARKERS and f"{data.gaps:,} places" in dropped
    for ax in panels:  # the series line only: no line per bad checksum, no stretch per dropped frame
        assert len(ax.get_lines()) == 1 and not ax.patches, ax.get_ylabel()
    import matplotlib.colors as mcolors

    steps = {mcolors.to_hex(p.get_edgecolor()): p.get_data().values.sum() for p in events.patches}
    assert steps == {mcolors.to_hex(BAD_COLOUR): data.checksum_failures, mcolors.to_hex(DROPPED_COLOUR): data.gaps}


def test_plot_reads_in_clock_time_with_units_and_one_legend(figure, faulty):
    from sharedlink.analysis.plot import build_figure

    data, fig = figure
    track, *panels, events = [ax for ax in fig.axes if ax.get_label() not in ("<colorbar>", "<link quality>")]
    assert track.get_xlabel() == "longitude (°)" and track.get_ylabel() == "latitude (°)"
    assert [ax.get_ylabel() for ax in panels] == ["AutoGpsLat\n(°)", "AutoGpsLon\n(°)", "AutoGpsHead\n(°)",
                                                  "AutoGpsVel\n(mph)"]
    assert events.get_xlabel() == "time (UTC)"
    ticks = [t.get_text() for t in events.get_xticklabels()]
    assert any(re.fullmatch(r"\d\d:\d\d", t) for t in ticks), ticks  # clock times
    assert len(fig.legends) == 1 and all(ax.get_legend() is None for ax in fig.axes)
    title = fig._suptitle.get_text()
    assert "dropped frames" in title and "bad checksums" in title and "gap" not in title
    assert f"{data.frames:,} frames" in title and "11h 06m" in title  # 40,000 s
    elapsed = build_figure(data, ["AutoGpsVel"], elapsed=True)
    ax = [a for a in elapsed.axes if a.get_label() == "events"][0]
    assert ax.get_xlabel() == "time since the first frame (h)"
    assert max(ax.get_xlim()) < 40000 / 3600 * 1.1


def test_plot_of_times_matplotlib_cannot_date(longs):
    """A capture stamped past the year 9999 (pcapng holds it): time since its first frame,
    the first frame's time in the axis label, never a traceback."""
    import matplotlib

    matplotlib.use("Agg")
    from sharedlink.analysis.plot import build_figure, collect

    data = collect(longs)
    data.t0_ns = 300_000_000_000 * 10**9  # +11476-08-15T05:20:00Z
    fig = build_figure(data)
    fig.canvas.draw()
    events = [a for a in fig.axes if a.get_label() == "events"][0]
    assert events.get_xlabel() == "time since the first frame, +11476-08-15T05:20:00.000000000Z (s)"
