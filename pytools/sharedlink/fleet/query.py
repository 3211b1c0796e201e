"""``sharedlink query``: SQL over a fleet dataset with embedded DuckDB.

:func:`connect` gives a DuckDB connection with three views:

* ``frames`` and ``values``: the dataset's tables over exactly the files the manifest lists (a
  consistent snapshot even while an ingest runs), with the Hive partition columns ``day`` (DATE)
  and ``link`` and a ``time`` column (TIMESTAMP_NS, UTC) computed from ``time_ns``;
* ``captures``: the manifest, one row per capture (path, vehicle, size, hash, frames, values,
  records, first_ns, last_ns, error).

:func:`run_query` runs one statement and streams its rows; :func:`write_csv`, :func:`write_json`
and :func:`table_rows` format them.
"""

from __future__ import annotations

import csv
import datetime as _dt
import decimal
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import pyarrow as pa

from sharedlink.errors import UsageError
from sharedlink.fleet.dataset import SCHEMAS, TABLES, CaptureEntry, require_dataset

#: rows fetched from DuckDB at a time
FETCH_ROWS = 10_000
_CAPTURE_COLUMNS = ("path", "vehicle", "size", "hash", "frames", "values", "records", "first_ns", "last_ns", "error")
_CAPTURE_TYPES = {"size": pa.int64(), "frames": pa.int64(), "values": pa.int64(), "records": pa.int64(),
                  "first_ns": pa.int64(), "last_ns": pa.int64()}


def connect(root: str | Path) -> Any:
    """An in-memory DuckDB connection with the views ``frames``, ``values`` and ``captures``."""
    import duckdb

    root = Path(root)
    manifest = require_dataset(root)
    con = duckdb.connect(":memory:")
    for table in TABLES:
        files = [str(root / f) for f in manifest.files(table)]
        if files:
            listed = ", ".join(_quote(f) for f in files)
            source = f"read_parquet([{listed}], hive_partitioning = true)"
        else:  # no rows yet: the same columns, empty
            con.register(f"_{table}_empty", _empty(table))
            source = f"_{table}_empty"
        con.execute(f'CREATE VIEW "{table}" AS SELECT *, make_timestamp_ns(time_ns) AS time FROM {source}')
    con.register("_captures", _captures(list(manifest.captures.values())))
    con.execute("CREATE VIEW captures AS SELECT * FROM _captures")
    return con


def _quote(text: str) -> str:
    return "'" + text.replace("'", "''") + "'"


def _empty(table: str) -> pa.Table:
    schema = SCHEMAS[table].append(pa.field("day", pa.date32())).append(pa.field("link", pa.string()))
    return schema.empty_table()


def _captures(entries: list[CaptureEntry]) -> pa.Table:
    """The manifest's entries as a table (read field by field: ``asdict`` would copy every
    entry's file list, a millisecond per 6 captures)."""
    return pa.table({c: pa.array([getattr(e, c) for e in entries], type=_CAPTURE_TYPES.get(c, pa.string()))
                     for c in _CAPTURE_COLUMNS})


@dataclass
class QueryResult:
    columns: list[str]
    batches: Iterator[list[tuple]]  # rows, FETCH_ROWS at a time

    def rows(self) -> Iterator[tuple]:
        for batch in self.batches:
            yield from batch


def run_query(root: str | Path, sql: str) -> QueryResult:
    """Run ``sql`` over the dataset at ``root``; UsageError for a bad dataset or statement."""
    import duckdb

    con = connect(root)
    try:
        cur = con.execute(sql)
    except duckdb.Error as exc:
        con.close()
        raise UsageError(f"query: {exc}") from None
    if cur.description is None:  # a statement without a result
        con.close()
        return QueryResult([], iter(()))

    def batches() -> Iterator[list[tuple]]:
        try:
            while rows := cur.fetchmany(FETCH_ROWS):
                yield rows
        except duckdb.Error as exc:
            raise UsageError(f"query: {exc}") from None
        finally:
            con.close()

    return QueryResult([d[0] for d in cur.description], batches())


def plain(x: Any) -> Any:
    """A DuckDB value as JSON has it: numbers, strings, booleans, null; times in ISO 8601."""
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    if isinstance(x, (bytes, bytearray, memoryview)):
        return bytes(x).decode("latin-1")
    if isinstance(x, (_dt.datetime, _dt.date, _dt.time)):
        return x.isoformat()
    if isinstance(x, decimal.Decimal):
        return float(x)
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    return str(x)


def text(x: Any) -> str:
    """A value as a table or CSV cell (null: empty)."""
    x = plain(x)
    if x is None:
        return ""
    if isinstance(x, (list, dict)):
        return json.dumps(x)
    return str(x)


def write_csv(result: QueryResult, out: TextIO) -> int:
    """CSV with a header line; the number of rows."""
    w = csv.writer(out, lineterminator="\n")
    w.writerow(result.columns)
    n = 0
    for batch in result.batches:
        w.writerows([text(x) for x in row] for row in batch)
        n += len(batch)
    return n


def write_json(result: QueryResult, out: TextIO) -> int:
    """A JSON array of objects, one per row (written as rows come); the number of rows."""
    n = 0
    out.write("[")
    for row in result.rows():
        out.write(",\n " if n else "\n ")
        out.write(json.dumps(dict(zip(result.columns, (plain(x) for x in row)))))
        n += 1
    out.write("\n]\n" if n else "]\n")
    return n
