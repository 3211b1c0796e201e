"""`run_query` keeps one in-memory DuckDB database per dataset snapshot (its manifest as it is)
for single SELECTs: a later query over the same snapshot sets nothing up again, a query after an
ingest sees the new rows, what another statement does (CREATE, SET) is not seen by the next one,
a query still streaming ends on its own snapshot, threads and a forked child query alike. And
`sharedlink query` never imports pyarrow."""

from __future__ import annotations

import multiprocessing
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from sharedlink.errors import UsageError
from sharedlink.fleet import query
from sharedlink.fleet.ingest import ingest
from sharedlink.fleet.query import run_query
from sharedlink.generators.beacon import GenOptions, generate_file

COUNT = "SELECT count(*) FROM values"


def q(ds: Path, sql: str) -> list[tuple]:
    return list(run_query(ds, sql).rows())


@pytest.fixture
def dataset(tmp_path) -> Path:
    caps = tmp_path / "caps" / "v1"
    caps.mkdir(parents=True)
    generate_file(GenOptions(frames=3000, compress=True, seed=1), caps / "a.pcap")
    assert ingest([caps], tmp_path / "ds").ok
    return tmp_path / "ds"


def add_capture(ds: Path, name: str, frames: int, seed: int) -> None:
    cap = ds.parent / "caps" / "v2" / name
    cap.parent.mkdir(parents=True, exist_ok=True)
    generate_file(GenOptions(frames=frames, seed=seed), cap)
    assert ingest([cap], ds).ok


def test_a_second_select_reuses_the_snapshot_and_an_ingest_makes_a_new_one(dataset):
    query.forget()
    (n,) = q(dataset, COUNT)
    kept = query._kept
    assert kept is not None and q(dataset, "SELECT count(*) FROM frames") and query._kept is kept
    add_capture(dataset, "b.pcap", 500, 2)
    (m,) = q(dataset, COUNT)
    assert m[0] > n[0] and query._kept is not kept
    assert q(dataset, "SELECT count(*) FROM captures") == [(2,)]


def test_other_statements_run_on_a_database_of_their_own(dataset):
    q(dataset, COUNT)
    assert run_query(dataset, "CREATE TABLE mine AS SELECT 1 AS x").columns in ([], ["Count"])
    with pytest.raises(UsageError, match="mine"):
        q(dataset, "SELECT * FROM mine")
    q(dataset, "SET threads = 1")
    assert q(dataset, "SELECT current_setting('threads')")[0][0] != 1 or multiprocessing.cpu_count() == 1
    with pytest.raises(UsageError, match="query:"):
        q(dataset, "SELEC 1")
    assert q(dataset, "SELECT 1; SELECT 2") == [(2,)]  # (several statements: the last one's rows)


def test_a_query_still_streaming_ends_on_its_snapshot(dataset, monkeypatch):
    monkeypatch.setattr(query, "FETCH_ROWS", 1000)
    ((n,),) = q(dataset, COUNT)
    result = run_query(dataset, "SELECT seq FROM values")
    first = next(result.batches)
    add_capture(dataset, "c.pcap", 500, 3)
    assert q(dataset, COUNT)[0][0] > n  # (a new kept database; the old one lives on for result)
    assert len(first) + sum(len(b) for b in result.batches) == n


def test_threads_query_one_snapshot_at_once(dataset):
    want = q(dataset, "SELECT name, count(*), max(value_double) FROM values GROUP BY ALL ORDER BY ALL")
    got: list = []

    def one() -> None:
        for _ in range(5):
            got.append(q(dataset, "SELECT name, count(*), max(value_double) FROM values GROUP BY ALL ORDER BY ALL"))

    threads = [threading.Thread(target=one) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert len(got) == 15 and all(g == want for g in got)


def _child_count(ds: str) -> list[tuple]:
    return q(Path(ds), COUNT)


@pytest.mark.skipif(sys.platform != "linux", reason="fork")
def test_a_forked_child_queries_on_its_own(dataset):
    want = q(dataset, COUNT)  # (the parent holds a kept database when it forks)
    with multiprocessing.get_context("fork").Pool(1) as pool:
        assert pool.apply_async(_child_count, (str(dataset),)).get(timeout=120) == want
    assert q(dataset, COUNT) == want


def test_the_query_command_does_not_import_pyarrow(dataset):
    code = ("import sys; from sharedlink.cli import main; rc = main(['query', sys.argv[1], sys.argv[2], '--json']); "
            "assert 'pyarrow' not in sys.modules, 'pyarrow imported'; sys.exit(rc)")
    for sql in (COUNT, "SELECT count(*) FROM captures"):
        r = subprocess.run([sys.executable, "-c", code, str(dataset), sql], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert '"count_star()": ' in r.stdout


def test_an_empty_dataset_needs_no_pyarrow_either(tmp_path):
    (tmp_path / "none").mkdir()
    assert ingest([tmp_path / "none"], tmp_path / "ds").ok
    code = ("import sys; from sharedlink.fleet.query import run_query; "
            "print(list(run_query(sys.argv[1], 'SELECT count(*), max(time), max(raw), max(day) FROM frames').rows())); "
            "assert 'pyarrow' not in sys.modules")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "ds")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "[(0, None, None, None)]", r.stderr
