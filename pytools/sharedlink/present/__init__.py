"""What people read: one format per kind of number (:mod:`~sharedlink.present.formats`) and
tables fitted to a terminal, plain on a pipe (:mod:`~sharedlink.present.tables`), for every
command's human output. Layer 4 (beside ``analysis``): it imports nothing heavier than rich,
and that only when a table is drawn."""

from sharedlink.present.formats import (
    COUNT,
    DURATION,
    INTEGER,
    NUMERIC,
    PROSE,
    REAL,
    TEXT,
    TIME,
    VALUE,
    cell,
    count,
    duration,
    integer,
    real,
    timestamp,
    value,
)
from sharedlink.present.tables import (
    Column,
    Fitted,
    Table,
    fit,
    plain,
    print_fitted,
    show,
    text_table,
    write_csv,
)

__all__ = [
    "COUNT", "DURATION", "INTEGER", "NUMERIC", "PROSE", "REAL", "TEXT", "TIME", "VALUE", "Column", "Fitted", "Table",
    "cell", "count", "duration", "fit", "integer", "plain", "print_fitted", "real", "show", "text_table", "timestamp",
    "value", "write_csv",
]
