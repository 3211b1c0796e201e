"""Fleet scale: many captures into one Parquet dataset (:mod:`.ingest`), SQL over it with DuckDB
(:mod:`.query`); the dataset's layout, tables and manifest are in :mod:`.dataset`."""
