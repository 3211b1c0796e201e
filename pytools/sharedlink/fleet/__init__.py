"""Fleet scale: many captures into one Parquet dataset (:mod:`.ingest`), SQL over it with DuckDB
(:mod:`.query`); the dataset's layout, tables and manifest are in :mod:`.dataset`."""

#: rows buffered per table before a row group is written (bounds a worker's memory); here, not in
#: :mod:`.ingest`, so that the CLI can show it without importing pyarrow for every command
BATCH_ROWS = 65_536
#: seconds to reach a Dask scheduler (``ingest --scheduler-timeout``; Dask retries a refused
#: connection until then): a reachable one answers in milliseconds
SCHEDULER_TIMEOUT_S = 10.0
