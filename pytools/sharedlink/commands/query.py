"""``sharedlink query``: SQL (DuckDB) over a fleet dataset's views frames, values and captures."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sharedlink.commands import EXIT_OK
from sharedlink.errors import UsageError


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
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not args.dataset.exists():  # the one wording of a missing input
        raise UsageError(f"{args.dataset}: no such file")
    from sharedlink.fleet.query import (  # pyarrow loads for this command only
        run_query,
        write_csv,
        write_json,
    )

    result = run_query(args.dataset, args.sql, ns_times=True)
    if args.fmt == "csv":
        write_csv(result, sys.stdout)
    elif args.fmt == "json":
        write_json(result, sys.stdout)
    elif args.fmt is None and not sys.stdout.isatty():
        write_csv(result, sys.stdout)
    elif result.columns:
        _table(result, sys.stdout.isatty())
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


def _table(result, terminal: bool) -> None:
    """The result as a table: fitted to the terminal, or every column as plain text."""
    from sharedlink.fleet.query import text
    from sharedlink.present import INTEGER, TIME, Table, show

    n = len(result.columns)
    types = result.types or [""] * n
    cols = [_column(c, t, i, n, i in result.ns_times) for i, (c, t) in enumerate(zip(result.columns, types))]
    t = Table("", cols, more="--format csv has every column and every character", empty="")
    for row in result.rows():
        t.add(*(x if c.kind in (TIME, INTEGER) and x is not None else text(x) for x, c in zip(row, cols)))
    show([t], terminal=terminal)
    rows = len(t.rows)
    print(f"({rows} row{'s' if rows != 1 else ''})")
