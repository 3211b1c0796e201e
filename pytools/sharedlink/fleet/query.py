"""``sharedlink query``: SQL over a fleet dataset with embedded DuckDB.

:func:`connect` gives a DuckDB connection with three views:

* ``frames`` and ``values``: the dataset's tables over exactly the files the manifest lists (a
  consistent snapshot even while an ingest runs), with the Hive partition columns ``day`` (DATE)
  and ``link`` and a ``time`` column (TIMESTAMP_NS, UTC) computed from ``time_ns``;
* ``captures``: the manifest, one row per capture (path, vehicle, size, hash, frames, values,
  records, first_ns, last_ns, error).

:func:`run_query` runs one statement and streams its rows; :func:`write_csv`, :func:`write_json`
and :func:`table_rows` format them.

A single SELECT runs on a connection of its own to an in-memory database this process keeps for
the dataset's manifest as it is (:func:`_snapshot`): a second query over the same snapshot sets
up nothing (about 20 ms of DuckDB start and views) and finds the files' Parquet footers read. A
new manifest (an ingest since) gets a new database; any other statement (CREATE, SET, COPY,
several statements) a database of its own, as :func:`connect` gives, so that nothing one query
does is seen by the next. Nothing here imports pyarrow (a tenth of a second and more).
"""

from __future__ import annotations

import csv
import datetime as _dt
import decimal
import json
import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from sharedlink.errors import UsageError
from sharedlink.fleet.dataset import COLUMNS, DUCKDB_TYPES, MANIFEST, TABLES, Manifest, require_dataset

#: rows fetched from DuckDB at a time
FETCH_ROWS = 10_000
#: the captures view's columns and DuckDB types
_CAPTURE_COLUMNS = {"path": "VARCHAR", "vehicle": "VARCHAR", "size": "BIGINT", "hash": "VARCHAR", "frames": "BIGINT",
                    "values": "BIGINT", "records": "BIGINT", "packets": "BIGINT", "first_ns": "BIGINT", "last_ns": "BIGINT",
                    "error": "VARCHAR"}
#: a kept database caches its files' Parquet footers (about 30 kB a file, read once instead of
#: once a query) up to this many files
METADATA_CACHE_FILES = 2048


def connect(root: str | Path) -> Any:
    """An in-memory DuckDB connection with the views ``frames``, ``values`` and ``captures``."""
    root = Path(root)
    return _database(root, require_dataset(root))


def _database(root: Path, manifest: Manifest, cache_metadata: bool = False) -> Any:
    import duckdb

    con = duckdb.connect(":memory:")
    try:
        files = {table: [str(root / f) for f in manifest.files(table)] for table in TABLES}
        if cache_metadata and sum(map(len, files.values())) <= METADATA_CACHE_FILES:
            con.execute("SET parquet_metadata_cache = true")
        for table in TABLES:
            if files[table]:
                listed = ", ".join(_quote(f) for f in files[table])
                source = f"read_parquet([{listed}], hive_partitioning = true)"
            else:  # no rows yet: the same columns, empty
                source = f"({_empty(table)})"
            con.execute(f'CREATE VIEW "{table}" AS SELECT *, make_timestamp_ns(time_ns) AS time FROM {source}')
        # (the manifest's entries as JSON, typed and unnested by DuckDB: no row made in Python)
        rows = json.dumps([{c: getattr(e, c) for c in _CAPTURE_COLUMNS} for e in manifest.captures.values()])
        con.execute("CREATE TABLE _captures AS SELECT unnest(from_json(?::JSON, ?), recursive := true)",
                    [rows, json.dumps([_CAPTURE_COLUMNS])])
        con.execute("CREATE VIEW captures AS SELECT * FROM _captures")
    except BaseException:
        con.close()
        raise
    return con


def _quote(text: str) -> str:
    return "'" + text.replace("'", "''") + "'"


def _empty(table: str) -> str:
    """A SELECT of no row with the table's columns (and the partition columns)."""
    cols = [*((c, DUCKDB_TYPES[kind]) for c, kind in COLUMNS[table]), ("day", "DATE"), ("link", "VARCHAR")]
    return "SELECT " + ", ".join(f'CAST(NULL AS {t}) AS "{c}"' for c, t in cols) + " WHERE false"


# -- the kept database ----------------------------------------------------------------------------

_lock = threading.Lock()
_kept: tuple[tuple, Any] | None = None  # (snapshot key, connection): the last one only


def _snapshot(root: Path) -> Any:
    """The kept database of ``root``'s manifest as it is now (made if need be). The manifest is
    replaced, never rewritten in place, by every ingest that changes it: its identity (device,
    inode, time, size), taken before it is read, is the snapshot's."""
    global _kept
    try:
        st = (root / MANIFEST).stat()
    except OSError:
        st = None
    key = None if st is None else (str(root.resolve()), st.st_dev, st.st_ino, st.st_mtime_ns, st.st_ctime_ns,
                                   st.st_size)
    with _lock:
        if key is not None and _kept is not None and _kept[0] == key:
            return _kept[1]
    con = _database(root, require_dataset(root), cache_metadata=True)
    with _lock:
        _kept = (key, con) if key is not None else _kept
    return con


def forget() -> None:
    """Drop the kept database (the next query sets one up again), e.g. to time a first query.
    Queries still reading keep theirs until they end."""
    global _kept
    with _lock:
        _kept = None


_forked: list = []  # kept databases a forked child inherited: never closed there (no threads of theirs)


def _after_fork() -> None:
    global _kept, _lock
    _lock = threading.Lock()
    if _kept is not None:
        _forked.append(_kept)
        _kept = None


if hasattr(os, "register_at_fork"):  # (POSIX)
    os.register_at_fork(after_in_child=_after_fork)


def _single_select(con: Any, sql: str) -> bool:
    """Whether ``sql`` is one SELECT (or FROM, VALUES, DESCRIBE, SUMMARIZE: what changes
    neither the catalog nor a setting)."""
    import duckdb

    try:
        statements = con.extract_statements(sql)
    except duckdb.Error:
        return False  # (run as before: the error is the statement's)
    return len(statements) == 1 and statements[0].type == duckdb.StatementType.SELECT


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

    root = Path(root)
    kept = _snapshot(root)
    con = kept.cursor() if _single_select(kept, sql) else _database(root, require_dataset(root))
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
