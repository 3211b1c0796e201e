"""``sharedlink query``: SQL (DuckDB) over a fleet dataset's views frames, values and captures."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sharedlink.commands import EXIT_OK
from sharedlink.errors import UsageError
from sharedlink.extras import require


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "query",
        help="SQL over a dataset made by ingest (DuckDB)",
        description="Run one SQL statement (DuckDB's dialect) over the dataset's views frames, values and captures "
        "(columns in docs/fleet.md) and print the result as a table, CSV or JSON.",
    )
    p.add_argument("dataset", type=Path, help="dataset directory made by sharedlink ingest")
    p.add_argument("sql", help='e.g. "SELECT pair, count(*) FROM frames GROUP BY pair"')
    p.add_argument("--format", dest="fmt", choices=("table", "csv", "json"), default="table",
                   help="output format (default table)")
    p.add_argument("--json", dest="fmt", action="store_const", const="json",
                   help="print the result as JSON on standard output (--format json)")
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

    result = run_query(args.dataset, args.sql)
    if args.fmt == "csv":
        write_csv(result, sys.stdout)
    elif args.fmt == "json":
        write_json(result, sys.stdout)
    elif result.columns:
        _table(result)
    return EXIT_OK


def _table(result) -> None:
    from rich.console import Console
    from rich.table import Table

    from sharedlink.fleet.query import text

    t = Table(show_header=True, header_style="bold")
    for c in result.columns:
        t.add_column(c, overflow="fold")
    n = 0
    for row in result.rows():
        t.add_row(*(text(x) for x in row))
        n += 1
    console = Console(width=None if sys.stdout.isatty() else 200)
    console.print(t)
    console.print(f"{n} row{'s' if n != 1 else ''}", style="dim")
