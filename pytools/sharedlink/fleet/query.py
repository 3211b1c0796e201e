"""``sharedlink query``: SQL over a fleet dataset with embedded DuckDB.

:func:`connect` gives a DuckDB connection with three views:

* ``frames``, ``values``, ``packets``, ``links`` and ``outages``: the dataset's tables over exactly the files the manifest
  lists (a consistent snapshot even while an ingest runs), with the Hive partition columns ``day``
  (DATE) and ``link`` and a ``time`` column (TIMESTAMP_NS, UTC) computed from ``time_ns``. The
  frames' and values' ``link`` is ``B_to_A`` (:func:`~sharedlink.fleet.dataset.link_name`), in
  a dataset with partitions of the old spelling (``link=B-A``) too: there it is made from
  ``src`` and ``dst``; ``outages`` has an ``end_time`` too (from ``end_ns``);
* ``captures``: the manifest, one row per capture (path, vehicle, size, hash, frames, values,
  records, first_ns, last_ns, error).

:func:`run_query` runs one statement and streams its rows; :func:`write_csv` and :func:`write_json`
write them (``QueryResult.plain_rows``: the values as JSON has them, times UTC with nanoseconds).

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
import re
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from sharedlink.errors import UsageError
from sharedlink.fleet.dataset import (
    COLUMNS,
    DUCKDB_TYPES,
    MANIFEST,
    TABLES,
    Manifest,
    link_name,
    old_links,
    require_dataset,
)

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
    """An in-memory DuckDB connection with the views of the tables and ``captures``."""
    root = Path(root)
    return _database(root, require_dataset(root))


def _database(root: Path, manifest: Manifest, cache_metadata: bool = False) -> Any:
    import duckdb

    con = duckdb.connect(":memory:")
    try:
        files = {table: [str(root / f) for f in manifest.files(table)] for table in TABLES}
        if cache_metadata and sum(map(len, files.values())) <= METADATA_CACHE_FILES:
            con.execute("SET parquet_metadata_cache = true")
        old = old_links(manifest)
        for table in TABLES:
            if files[table]:
                listed = ", ".join(_quote(f) for f in files[table])
                source = f"read_parquet([{listed}], hive_partitioning = true)"
            else:  # no rows yet: the same columns, empty
                source = f"({_empty(table)})"
            columns = "*"
            if old and table != "packets":  # (link=B-A partitions: the link made from the rows, one spelling;
                # a dataset of new partitions only keeps the partition's, which DuckDB prunes files by)
                columns = f"* REPLACE ({_sql_link('src', 'dst')} AS link)"
            extra = ", make_timestamp_ns(end_ns) AS end_time" if table == "outages" else ""
            con.execute(f'CREATE VIEW "{table}" AS SELECT {columns}, make_timestamp_ns(time_ns) AS time{extra} '
                        f'FROM {source}')
        # (the manifest's entries as JSON, typed and unnested by DuckDB: no row made in Python)
        rows = json.dumps([{c: getattr(e, c) for c in _CAPTURE_COLUMNS} for e in manifest.captures.values()])
        con.execute("CREATE TABLE _captures AS SELECT unnest(from_json(?::JSON, ?), recursive := true)",
                    [rows, json.dumps([_CAPTURE_COLUMNS])])
        con.execute("CREATE VIEW captures AS SELECT * FROM _captures")
    except BaseException:
        con.close()
        raise
    return con


def _sql_link(src: str, dst: str) -> str:
    """:func:`~sharedlink.fleet.dataset.link_name` in SQL (tests check they agree)."""
    return f"CAST({src} || '_to_' || {dst} AS VARCHAR)"


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


#: a node pair as the link partition spelled it before issue 41: a node, "-", a node (``B-A``)
_OLD_LINK = re.compile(r"(.)-(.)", re.S)


def renamed_links(sql: str) -> tuple[str, list[tuple[str, str]]]:
    """``sql`` with the old spelling of a link (``'B-A'``) respelled (``'B_to_A'``) where a
    ``link`` column is compared with it: ``link = 'B-A'`` (``<>``, ``!=`` too), ``link IN ('B-A',
    ...)`` (``NOT IN`` too), the column qualified or quoted or not; and the (old, new) spellings
    respelled, once each. Nothing else is touched (``'B-A' = link``, LIKE patterns): the old
    spelling works where scripts wrote it, until the next release (docs/fleet.md "Renamed")."""
    import duckdb

    try:
        tokens = duckdb.tokenize(sql)
    except duckdb.Error:
        return sql, []  # (run as it is: the error is the statement's)
    ends = [pos for pos, _ in tokens[1:]] + [len(sql)]
    toks = [(pos, sql[pos:end].rstrip(), kind) for (pos, kind), end in zip(tokens, ends)
            if kind != duckdb.token_type.comment]
    string, edits, renamed = duckdb.token_type.string_const, [], []
    for i, (pos, lit, kind) in enumerate(toks):
        m = _OLD_LINK.fullmatch(lit[1:-1]) if kind == string and len(lit) > 2 and lit[0] == lit[-1] == "'" else None
        if m is None or not _compared_with_link(toks, i):
            continue
        new = link_name(m[1], m[2])
        edits.append((pos, pos + len(lit), _quote(new)))
        if (m[0], new) not in renamed:
            renamed.append((m[0], new))
    for start, end, text in reversed(edits):
        sql = sql[:start] + text + sql[end:]
    return sql, renamed


def _compared_with_link(toks: list[tuple[int, str, Any]], i: int) -> bool:
    """Whether the string token ``i`` is the right side of ``link =`` (``<>``, ``!=``) or in
    the list of ``link IN (...)``."""
    import duckdb

    j = i - 1
    while j >= 1 and toks[j][1] == "," and toks[j - 1][2] == duckdb.token_type.string_const:
        j -= 2
    if j >= 1 and toks[j][1] == "(" and toks[j - 1][1].upper() == "IN":
        j -= 2
        if j >= 0 and toks[j][1].upper() == "NOT":
            j -= 1
    elif j >= 0 and toks[j][1] in ("=", "==", "<>", "!=") and j == i - 1:
        j -= 1
    else:
        return False
    return j >= 0 and toks[j][2] == duckdb.token_type.identifier and toks[j][1].strip('"').lower() == "link"


@dataclass
class QueryResult:
    columns: list[str]
    batches: Iterator[list[tuple]]  # rows, FETCH_ROWS at a time
    types: list[str] = field(default_factory=list)  # DuckDB's type of each column
    ns_times: frozenset[int] = frozenset()  # columns whose values are ns since 1970 (TIMESTAMP_NS, UTC)
    renamed: list[tuple[str, str]] = field(default_factory=list)  # old link spellings respelled (renamed_links)

    def rows(self) -> Iterator[tuple]:
        """The rows, the ``ns_times`` columns as ns since 1970 (ints)."""
        for batch in self.batches:
            yield from batch

    def plain_rows(self) -> Iterator[list[Any]]:
        """The rows as JSON has them (:func:`plain`; times as UTC text with nanoseconds)."""
        from sharedlink.present import timestamp

        times = self.ns_times
        for row in self.rows():
            yield [timestamp(x) if i in times and x is not None else plain(x) for i, x in enumerate(row)]


def run_query(root: str | Path, sql: str, ns_times: bool = False) -> QueryResult:
    """Run ``sql`` over the dataset at ``root``; UsageError for a bad dataset or statement.
    ``ns_times``: a single SELECT's TIMESTAMP_NS columns come as ns since 1970 (ints, their
    indices in ``QueryResult.ns_times``), not as datetimes to the microsecond (what the command
    prints: every digit). A link compared with its old spelling (``link = 'B-A'``) is compared
    with its new one (:func:`renamed_links`; the pairs in ``QueryResult.renamed``)."""
    import duckdb

    root = Path(root)
    sql, renamed = renamed_links(sql)
    kept = _snapshot(root)
    single = _single_select(kept, sql)
    con = kept.cursor() if single else _database(root, require_dataset(root))
    described: list[tuple[str, str]] | None = None
    try:
        if single and ns_times:
            sql, described = _with_ns_times(con, sql)
        cur = con.execute(sql)
    except duckdb.Error as exc:
        con.close()
        raise UsageError(f"query: {exc}") from None
    if cur.description is None:  # a statement without a result
        con.close()
        return QueryResult([], iter(()), renamed=renamed)

    def batches() -> Iterator[list[tuple]]:
        try:
            while rows := cur.fetchmany(FETCH_ROWS):
                yield rows
        except duckdb.Error as exc:
            raise UsageError(f"query: {exc}") from None
        finally:
            con.close()

    if described is None:
        return QueryResult([d[0] for d in cur.description], batches(), [str(d[1]) for d in cur.description],
                           renamed=renamed)
    # (the wrapped query's names are its expressions': the statement's own, as described)
    return QueryResult([c for c, _ in described], batches(), [t for _, t in described],
                       frozenset(i for i, (_, t) in enumerate(described) if t == "TIMESTAMP_NS"), renamed)


def _with_ns_times(con: Any, sql: str) -> tuple[str, list[tuple[str, str]] | None]:
    """A SELECT with a TIMESTAMP_NS column, which DuckDB gives Python as a datetime (to the
    microsecond), wrapped so that those columns come as ns since 1970 (``epoch_ns``), the
    others as they are: (the statement to run, the names and types of the statement's columns);
    (``sql``, None) when it has no such column."""
    import duckdb

    described = [(str(r[0]), str(r[1])) for r in con.execute("DESCRIBE " + sql).fetchall()]
    if not any(t == "TIMESTAMP_NS" for _, t in described):
        return sql, None
    body = sql
    tokens = duckdb.tokenize(sql)
    real = [(pos, kind) for pos, kind in tokens if kind != duckdb.token_type.comment]
    if real and sql[real[-1][0]] == ";":  # (the statement's own end: the subquery has none)
        body = sql[: real[-1][0]]
    cols = ", ".join(f"epoch_ns(#{i + 1})" if t == "TIMESTAMP_NS" else f"#{i + 1}" for i, (_, t) in enumerate(described))
    return f"SELECT {cols} FROM ({body}\n) AS _sharedlink_q", described


def plain(x: Any) -> Any:
    """A DuckDB value as JSON has it: numbers, strings, booleans, null; times in ISO 8601
    (timestamps UTC with nanoseconds, sharedlink.present.timestamp)."""
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    if isinstance(x, _dt.datetime):
        from sharedlink.present import timestamp

        return timestamp(x)
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
    for row in result.plain_rows():
        w.writerow(text(x) for x in row)
        n += 1
    return n


def write_json(result: QueryResult, out: TextIO) -> int:
    """A JSON array of objects, one per row (written as rows come); the number of rows."""
    n = 0
    out.write("[")
    for row in result.plain_rows():
        out.write(",\n " if n else "\n ")
        out.write(json.dumps(dict(zip(result.columns, row))))
        n += 1
    out.write("\n]\n" if n else "]\n")
    return n
