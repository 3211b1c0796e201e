"""How `ingest` lays out the values table so that a query for one variable reads little of it:
each flush's rows sorted by name (one name's rows in frame order), cut into row groups of whole
names, so a row group's name statistics span only its own names and a reader skips the row groups
of the other names; rising integers (seq, frame, time_ns) delta-encoded. A dataset written before
(rows in frame order, a row group per flush, plain integers) reads the same."""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sharedlink.fleet.dataset import SCHEMAS
from sharedlink.fleet.ingest import NAME_GROUP_ROWS, by_name, ingest, name_groups
from sharedlink.fleet.query import run_query
from sharedlink.generators.beacon import GenOptions, generate_file

#: the query of `make bench` (bench/bench_ingest.py TOP_SPEED)
TOP_SPEED = "SELECT vehicle, max(value_double) FROM values WHERE name = 'AutoGpsVel' AND NOT carried GROUP BY vehicle"
QUERIES = [
    TOP_SPEED,
    "SELECT name, count(*), round(sum(value_double), 3), count(*) FILTER (WHERE carried), min(time), max(seq) FROM values "
    "GROUP BY ALL ORDER BY ALL",
    "SELECT seq, name, text, changed FROM values WHERE name IN ('AutoGpsLat', 'AutoGpsHead') AND seq % 97 = 0 "
    "ORDER BY seq, name",
    "SELECT day, link, count(*), min(time_ns), max(frame) FROM frames GROUP BY ALL ORDER BY ALL",
]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """20,000 compressed beacon frames (4 names, 80,000 values rows: two flushes of the default
    batch, the first with more than NAME_GROUP_ROWS rows of each name)."""
    d = tmp_path_factory.mktemp("layout")
    (d / "v1").mkdir()
    generate_file(GenOptions(frames=20_000, compress=True, seed=3, bad_checksum=0.01), d / "v1" / "c.pcap")
    report = ingest([d / "v1"], d / "ds")
    assert report.ok and report.values > 4 * NAME_GROUP_ROWS, report
    return d / "ds"


def values_files(ds: Path) -> list[Path]:
    files = sorted((ds / "values").rglob("*.parquet"))
    assert files
    return files


def test_row_groups_hold_whole_names_in_frame_order(dataset):
    for f in values_files(dataset):
        pf = pq.ParquetFile(f)
        seen: list[str] = []  # names of the row groups of the flush so far
        for i in range(pf.num_row_groups):
            t = pf.read_row_group(i, columns=["name", "seq"])
            names = t["name"].to_pylist()
            assert names == sorted(names), f"{f} row group {i}: rows not sorted by name"
            for name in set(names):  # one name's rows in frame order
                seqs = t.filter(pc.equal(t["name"], name))["seq"].to_pylist()
                assert seqs == sorted(seqs)
            if seen and names[0] > seen[-1]:  # the same flush: its names come after the group before's
                assert not set(names) & set(seen)
            else:  # a new flush
                seen = []
            seen += names
            assert t.num_rows >= NAME_GROUP_ROWS or pf.num_row_groups == 1 or i == pf.num_row_groups - 1


def test_a_query_for_one_name_needs_few_row_groups(dataset):
    """By the statistics a reader sees (min and max of `name` per row group), `name =
    'AutoGpsVel'` needs at most half the row groups (all of them when rows came in frame order)."""
    needed = total = 0
    for f in values_files(dataset):
        md = pq.ParquetFile(f).metadata
        col = SCHEMAS["values"].get_field_index("name")
        for i in range(md.num_row_groups):
            stats = md.row_group(i).column(col).statistics
            assert stats is not None and stats.has_min_max
            total += 1
            needed += stats.min <= "AutoGpsVel" <= stats.max
    assert total >= 4 and 2 * needed <= total, (needed, total)


def test_rising_integers_are_delta_encoded(dataset):
    for table in ("frames", "values"):
        for f in sorted((dataset / table).rglob("*.parquet")):
            md = pq.ParquetFile(f).metadata
            for name in ("seq", "frame", "time_ns"):
                col = md.row_group(0).column(SCHEMAS[table].get_field_index(name))
                assert "DELTA_BINARY_PACKED" in col.encodings, (f, name, col.encodings)


def test_readers_see_the_tables_types(dataset):
    """(the fixed columns and names are written from dictionary arrays; the files do not carry
    an Arrow schema, so every reader takes the Parquet types: strings)"""
    for table in ("frames", "values"):
        for f in sorted((dataset / table).rglob("*.parquet")):
            assert pq.read_schema(f).equals(SCHEMAS[table]), f
            assert pq.read_table(f).schema.equals(SCHEMAS[table])


def test_the_layout_before_reads_the_same(dataset, tmp_path):
    """The same rows as ingest wrote them before (frame order, one row group, plain encodings;
    the manifest unchanged): every query answers the same."""
    old = tmp_path / "old"
    shutil.copytree(dataset, old)
    for f in values_files(old):
        t = pq.read_table(f, schema=SCHEMAS["values"])
        t = t.take(pc.sort_indices(t, [("seq", "ascending")]))  # (stable: names in frame order)
        assert t["name"].to_pylist() != sorted(t["name"].to_pylist())
        f.unlink()
        pq.write_table(t, f, compression="zstd", use_dictionary=["capture", "vehicle", "name"])
        assert pq.ParquetFile(f).num_row_groups == 1
    for sql in QUERIES:
        assert list(run_query(old, sql).rows()) == list(run_query(dataset, sql).rows()), sql


@given(st.lists(st.sampled_from(["b", "a", "AutoGpsVel", "", "é", "Z", "a\x00"]), max_size=60))
def test_by_name_is_a_stable_sort_by_the_bytes(names):
    """(Parquet's statistics order strings by their UTF-8 bytes)"""
    order, sorted_names = by_name(pa.array(names, pa.string()))
    assert order.to_pylist() == sorted(range(len(names)), key=lambda i: names[i].encode())
    assert sorted_names.to_pylist() == [names[i] for i in order.to_pylist()]
    if names:
        assert name_groups(sorted_names, 1) == name_groups(pa.array(sorted_names.to_pylist(), pa.string()), 1)


@given(st.lists(st.integers(1, 40), max_size=12), st.integers(1, 50))
def test_name_groups_are_whole_names_of_at_least_the_least(runs, least):
    names = pa.array([f"n{i:02d}" for i, r in enumerate(runs) for _ in range(r)], pa.string())
    groups = name_groups(names, least)
    assert sum(groups) == len(names)
    ends = {sum(runs[: i + 1]) for i in range(len(runs))}
    at = 0
    for g in groups:
        at += g
        assert at in ends  # a cut only between names
        assert g >= least or len(groups) == 1
    assert len(groups) <= max(1, len(names) // least)
