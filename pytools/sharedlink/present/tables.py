"""Tables for people: fitted to a terminal, plain aligned text on a pipe, CSV for programs.

A :class:`Table` is a title, :class:`Column` s (a header and the kind of its cells, from
:mod:`sharedlink.present.formats`) and rows of raw values (numbers, ns times, strings), each
written by its column's kind. :func:`show` prints tables to standard output: on a terminal
fitted to its width (:func:`fit`), else as :func:`plain` text. A command adds a table so::

    from sharedlink.present import COUNT, DURATION, Column, Table, show

    t = Table("Link health", [Column("pair"), Column("outages", COUNT),
                              Column("longest", DURATION, drop=1)])
    t.add("B>A", 3, 12.5)               # raw values: 3 -> "3", 12.5 -> "12.500s"
    t.add("A>B", 1200, None, style="red")
    show([t])

Fitting to a terminal ``width`` columns wide (light borders, no outer frame: ``│`` between
columns, ``─┼─`` under the headers): when the table is too wide, headers of several words go on
several lines, text columns marked ``cut=True`` are cut (``…``) down to :data:`CUT_MIN`
characters and prose columns wrap at spaces; if it is still too wide, columns with a ``drop``
rank are left out, lowest rank first. Numbers, durations and times are never cut nor split and
are right-aligned. What was cut or left out is said in a note under the table (with
``Table.more``: where the whole is, e.g. ``--json has every column``). No column is narrower
than :data:`MIN_WIDTH`. When even that does not fit, :func:`show` prints the plain text, which
the terminal wraps.
"""

from __future__ import annotations

import csv
import sys
import textwrap
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, TextIO

from sharedlink.present.formats import COUNT, NUMERIC, PROSE, REAL, TEXT, cell, datetime_ns, one_line

#: no column narrower than this (headers and cells of one character read as noise)
MIN_WIDTH = 3
#: a cut text column keeps at least this many characters (with the "…")
CUT_MIN = 8
#: characters between two columns: " │ "
GAP = 3


@dataclass
class Column:
    header: str
    kind: str = TEXT
    drop: int | None = None  # left out to fit a narrow terminal, lowest rank first; None: always kept
    cut: bool = False  # a text column that may be cut ("…") to fit

    @property
    def right(self) -> bool:
        return self.kind in NUMERIC


@dataclass
class Table:
    title: str
    columns: list[Column]
    rows: list[list[Any]] = field(default_factory=list)
    styles: list[str | None] = field(default_factory=list)  # a rich style per row (terminal only)
    more: str = ""  # where every column is, said when some are left out or cut
    header: bool = True  # False: a two-column list of names and values without headers
    empty: str = "(none)"  # said for a table without rows ("": its headers alone, as DuckDB's shell)

    def add(self, *cells: Any, style: str | None = None) -> None:
        self.rows.append(list(cells))
        self.styles.append(style)

    def texts(self) -> list[list[str]]:
        """Every cell as text on one line (its column's format; control characters escaped)."""
        kinds = [c.kind for c in self.columns]
        return [[one_line(cell(x, k)) for x, k in zip(row, kinds)] for row in self.rows]


@dataclass
class Fitted:
    """How a table fits: the columns kept (indices), their widths and header lines, the note."""

    columns: list[int]
    widths: dict[int, int]
    headers: dict[int, str]
    note: str | None


def _len(text: str) -> int:
    """Terminal cells ``text`` takes (wide characters two)."""
    if text.isascii():
        return len(text)
    from rich.cells import cell_len

    return cell_len(text)


def _longest_word(text: str) -> int:
    return max((_len(w) for w in text.split()), default=0)


def fit(table: Table, width: int, texts: list[list[str]] | None = None) -> Fitted | None:
    """The columns and widths of ``table`` on a terminal ``width`` wide; None when it cannot fit."""
    texts = table.texts() if texts is None else texts
    cols = table.columns
    natural: dict[int, int] = {}
    floor: dict[int, int] = {}
    for i, c in enumerate(cols):
        longest = max((_len(r[i]) for r in texts), default=0)
        head = _len(c.header) if table.header else 0
        natural[i] = max(longest, head, MIN_WIDTH)
        if c.kind == PROSE:
            least = max((_longest_word(r[i]) for r in texts), default=0)
        elif c.cut and c.kind == TEXT:
            least = min(longest, CUT_MIN)
        else:
            least = longest
        floor[i] = max(least, _longest_word(c.header) if table.header else 0, MIN_WIDTH)

    def need(keep: list[int], w: dict[int, int]) -> int:
        return sum(w[i] for i in keep) + GAP * (len(keep) - 1)

    keep = list(range(len(cols)))
    if need(keep, natural) <= width:
        widths = dict(natural)
    else:
        ranked = sorted((i for i, c in enumerate(cols) if c.drop is not None), key=lambda i: cols[i].drop)
        while need(keep, floor) > width and ranked:
            keep.remove(ranked.pop(0))
        if need(keep, floor) > width:
            return None
        widths = {i: floor[i] for i in keep}
        spare = width - need(keep, floor)
        needy = [i for i in keep if widths[i] < natural[i]]
        while spare and needy:  # back towards the natural widths, a fair share each
            share = max(1, spare // len(needy))
            for i in needy:
                more = min(share, natural[i] - widths[i], spare)
                widths[i] += more
                spare -= more
            needy = [i for i in needy if widths[i] < natural[i]]
    headers = {i: "\n".join(textwrap.wrap(cols[i].header, widths[i], break_long_words=False)) or cols[i].header
               for i in keep}
    left_out = [cols[i].header or f"column {i + 1}" for i in range(len(cols)) if i not in keep]
    cut = [cols[i].header for i in keep if cols[i].kind != PROSE
           and any(_len(r[i]) > widths[i] for r in texts)]
    notes = []
    if left_out:
        notes.append(f"left out to fit the terminal: {', '.join(left_out)}")
    if cut:
        notes.append(f"cut to fit: {', '.join(cut)}")
    note = None
    if notes:
        note = "; ".join(notes) + (f" ({table.more})" if table.more else "")
    return Fitted(keep, widths, headers, note)


def rich_table(table: Table, fitted: Fitted, texts: list[list[str]]) -> Any:
    """The rich Table of a fitted table (no title: :func:`show` prints it above)."""
    from rich import box
    from rich.table import Table as RichTable

    t = RichTable(box=box.SQUARE, show_edge=False, pad_edge=False, show_header=table.header,
                  header_style="bold", expand=False)
    for i in fitted.columns:
        c = table.columns[i]
        w = fitted.widths[i]
        t.add_column(fitted.headers[i], justify="right" if c.right else "left", width=w, min_width=w, max_width=w,
                     no_wrap=c.kind != PROSE, overflow="fold" if c.kind == PROSE else "ellipsis")
    styles = table.styles if len(table.styles) == len(texts) else [None] * len(texts)
    for row, style in zip(texts, styles):
        t.add_row(*(row[i] for i in fitted.columns), style=style)
    return t


def plain(table: Table, texts: list[list[str]] | None = None) -> str:
    """The table as aligned plain text: its title, then its rows indented two spaces (numbers
    right-aligned), ``(none)`` when it has none."""
    texts = table.texts() if texts is None else texts
    grid = ([[c.header for c in table.columns]] if table.header else []) + texts
    out = [table.title] if table.title else []
    if not texts and table.empty:
        out.append(f"  {table.empty}")
        return "\n".join(out) + "\n"
    widths = [max(_len(r[i]) for r in grid) for i in range(len(table.columns))]
    for r in grid:
        cells = [(" " * (w - _len(x)) + x) if c.right else (x + " " * (w - _len(x)))
                 for x, w, c in zip(r, widths, table.columns)]
        out.append(("  " + "  ".join(cells)).rstrip())
    return "\n".join(out) + "\n"


def _machine(x: Any, kind: str) -> str:
    """A cell for programs (CSV): numbers without separators, times in ISO 8601."""
    if x is None:
        return ""
    if kind in ("time",):
        return cell(x, kind)
    if isinstance(x, float) and x.is_integer() and kind in ("count", "integer"):
        return str(int(x))
    if hasattr(x, "tzinfo"):  # a datetime given for any kind
        return cell(datetime_ns(x), "time")
    return str(x)


def write_csv(table: Table, out: TextIO) -> None:
    """The table as CSV with a header line (raw values: no separators)."""
    w = csv.writer(out, lineterminator="\n")
    w.writerow([c.header for c in table.columns])
    kinds = [c.kind for c in table.columns]
    w.writerows([_machine(x, k) for x, k in zip(row, kinds)] for row in table.rows)


def text_table(title: str, headers: list[str], rows: list[list[str]], more: str = "") -> Table:
    """A table of cells already written as text: a column whose every cell is a whole number
    is a count (right-aligned, the one thousands-separator rule), one of decimal numbers
    right-aligned as written, the rest text; headers all empty: a names-and-values list."""
    def every(i: int, test) -> bool:
        return bool(rows) and all(test(r[i]) for r in rows if r[i] != "")

    def decimal(x: str) -> bool:
        return x.replace(".", "", 1).lstrip("-").isdigit()

    kinds = [TEXT if i == 0 else COUNT if every(i, str.isdigit) else REAL if every(i, decimal) else PROSE
             for i in range(len(headers))]
    n = len(headers)
    # to fit a narrow terminal, nothing cut: the columns after the second left out from the last,
    # then (a table of four columns and more) the first
    drops = [n - 2 if n >= 4 else None, None] + [n - 1 - i for i in range(2, n)]
    columns = [Column(h, k, drop=r) for h, k, r in zip(headers, kinds, drops)]
    t = Table(title, columns, more=more or "--json has every column", header=any(headers))
    for r in rows:
        t.add(*(int(x) if k == COUNT and x else x for x, k in zip(r, kinds)))
    return t


def show(tables: Iterable[Table], out: TextIO | None = None, *, terminal: bool | None = None,
         width: int | None = None) -> None:
    """Print ``tables``: fitted on a terminal (``terminal`` None: whether ``out`` is one), else
    plain text, a blank line between tables."""
    out = sys.stdout if out is None else out
    if terminal is None:
        terminal = out.isatty()
    tables = list(tables)
    if not terminal:
        out.write("\n".join(plain(t) for t in tables))
        return
    from rich.console import Console

    console = Console(file=out, width=width)
    for k, t in enumerate(tables):
        if k:
            console.print()
        print_fitted(console, t)


def print_fitted(console: Any, table: Table) -> None:
    """One table on a rich Console, fitted to its width (plain lines when it cannot fit)."""
    from rich.text import Text

    texts = table.texts()
    if table.title:
        console.print(Text(table.title, style="bold"))
    if not texts and table.empty:
        console.print(f"  {table.empty}", highlight=False)
        return
    fitted = fit(table, console.width, texts)
    if fitted is None:
        body = plain(Table("", table.columns, table.rows, header=table.header), texts)
        console.print(Text(body.rstrip("\n")), soft_wrap=True)
        return
    console.print(rich_table(table, fitted, texts))
    if fitted.note:
        console.print(Text(fitted.note, style="dim"))
