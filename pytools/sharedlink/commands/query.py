"""``sharedlink query``: SQL (DuckDB) over a fleet dataset's views frames, values and captures."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sharedlink.commands import EXIT_OK, deprecated, number
from sharedlink.errors import UsageError
from sharedlink.extras import require

#: rows of a result a table on a terminal shows at most (the first and the last half)
MAX_ROWS = 40


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "query",
        help="SQL over a dataset made by ingest (DuckDB)",
        description="Run one SQL statement (DuckDB's dialect) over the dataset's views frames, values and captures "
        "(columns in docs/fleet.md) and print the result: on a terminal a table fitted to its width (as DuckDB's "
        "shell: columns left out or cut are named under it; timestamps UTC with nanoseconds), on a pipe CSV, or "
        "what --format says.",
    )
    p.add_argument("dataset", type=Path, help="dataset directory made by sharedlink ingest")
    p.add_argument("sql", help='e.g. "SELECT pair, count(*) FROM frames GROUP BY pair"')
    p.add_argument("--format", dest="fmt", choices=("table", "csv", "json"), default=None,
                   help="output format (default: table on a terminal, csv on a pipe; table on a pipe: every column, "
                   "aligned plain text)")
    p.add_argument("--json", dest="fmt", action="store_const", const="json",
                   help="print the result as JSON on standard output (--format json)")
    p.add_argument("--max-rows", type=number(0, 1e12, integer=True), default=MAX_ROWS, metavar="N",
                   help=f"the table on a terminal shows the first and last N/2 rows of a longer result, as DuckDB's "
                   f"shell (default {MAX_ROWS}; 0: every row)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not args.dataset.exists():  # the one wording of a missing input
        raise UsageError(f"{args.dataset}: no such file")
    require("fleet", "sharedlink query")
    from sharedlink.fleet.query import (  # pyarrow loads for this command only
        run_query,
        write_csv,
        write_json,
    )

    result = run_query(args.dataset, args.sql, ns_times=True)
    for old, new in result.renamed:  # (link = 'B-A': the partition's spelling before issue 41)
        deprecated(f"link = '{old}'", f"link = '{new}' or pair = '{old[0]}>{old[-1]}'")
    if args.fmt == "csv":
        write_csv(result, sys.stdout)
    elif args.fmt == "json":
        write_json(result, sys.stdout)
    elif args.fmt is None and not sys.stdout.isatty():
        write_csv(result, sys.stdout)
    elif result.columns:
        terminal = sys.stdout.isatty()
        _table(result, terminal, args.max_rows if terminal else 0)
    return EXIT_OK


#: DuckDB's types shown as numbers (right-aligned, never cut)
_INTEGERS = ("TINYINT", "SMALLINT", "INTEGER", "BIGINT", "HUGEINT", "UTINYINT", "USMALLINT", "UINTEGER", "UBIGINT",
             "UHUGEINT")


def _column(name: str, type_: str, i: int, n: int, ns_time: bool):
    from sharedlink.present import INTEGER, TEXT, TIME, VALUE, Column

    drop = None if i == 0 else n - i  # (the first column stays; the last goes first)
    if ns_time or type_.startswith("TIMESTAMP"):
        return Column(name, TIME, drop=drop)
    if type_ in _INTEGERS:
        return Column(name, INTEGER, drop=drop)
    if type_ in ("FLOAT", "DOUBLE") or type_.startswith("DECIMAL"):
        return Column(name, VALUE, drop=drop)
    return Column(name, TEXT, drop=drop, cut=type_ in ("VARCHAR", "BLOB") or type_.startswith(("STRUCT", "MAP")) or
                  type_.endswith("]"))


def _table(result, terminal: bool, max_rows: int = 0) -> None:
    """The result as a table: fitted to the terminal, or every column as plain text; with
    ``max_rows``, a longer result's first and last ``max_rows // 2`` rows around a row of
    ``…`` (the rows between are read and counted, not kept)."""
    from collections import deque

    from sharedlink.fleet.query import text
    from sharedlink.present import INTEGER, TIME, Table, count, show

    n = len(result.columns)
    types = result.types or [""] * n
    cols = [_column(c, t, i, n, i in result.ns_times) for i, (c, t) in enumerate(zip(result.columns, types))]
    t = Table("", cols, more="--format csv has every column and every character", empty="")
    first: list = []
    last: deque = deque(maxlen=max_rows // 2 if max_rows else 0)
    room = max_rows - max_rows // 2 if max_rows else -1  # rows kept from the start (-1: all)
    rows = 0
    for row in result.rows():
        rows += 1
        if room < 0 or len(first) < room:
            first.append(row)
        else:
            last.append(row)
    shown = len(first) + len(last)
    for row in first:
        t.add(*(x if c.kind in (TIME, INTEGER) and x is not None else text(x) for x, c in zip(row, cols)))
    if rows > shown:
        t.add(*("…" for _ in cols))
    for row in last:
        t.add(*(x if c.kind in (TIME, INTEGER) and x is not None else text(x) for x, c in zip(row, cols)))
    show([t], terminal=terminal)
    more = f", {count(shown)} shown" if rows > shown else ""
    print(f"({count(rows)} row{'s' if rows != 1 else ''}{more})")
