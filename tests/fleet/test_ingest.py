"""`sharedlink ingest` and `sharedlink query`: a small fleet (sample captures and `sharedlink gen`
captures of several vehicles, days and faults, UDP and serial) into one Parquet dataset.

Frame counts per capture are checked against the real tshark with the dissectors, the query
results against `sharedlink stats` (capture_stats) on the same captures; re-ingesting changes
nothing, a changed capture has its rows replaced, a damaged one keeps what came before the damage.
"""

from __future__ import annotations

import datetime as dt
import functools
import json
import re
import shutil
import subprocess
import sys
import tracemalloc
from decimal import Decimal
from pathlib import Path

import pyarrow.dataset as pads
import pytest
from sl_cli import run_cli

from sharedlink.analysis.stats import capture_stats
from sharedlink.cli import main as cli_main
from sharedlink.fleet.dataset import link_name, load_manifest, old_links, save_manifest
from sharedlink.fleet.ingest import ingest
from sharedlink.fleet.query import renamed_links, run_query
from tshark_util import REPO, fields

CLI = [sys.executable, "-m", "sharedlink"]
SERIAL_LUA = REPO / "dissector" / "serial.lua"

#: vehicle/file -> sharedlink gen options: vehicles on nodes B, C and D, three days, faults
FLEET = {
    "v1/day1.pcap": "--duration 30 --src B --start 2026-03-02T08:00:00Z --seed 1 --bad-checksum 0.005",
    "v1/day2.pcap": "--duration 30 --src B --start 2026-03-03T08:00:00Z --seed 2 --compress --drop 0.05",
    "v2/day1.pcap": "--duration 20 --src C --start 2026-03-02T09:00:00Z --seed 3 --bad-checksum 0.2",
    "v2/day1-later.pcap": "--duration 10 --src C --start 2026-03-02T09:05:00Z --seed 7",  # C silent 280 s
    "v2/day2.pcapng": "--duration 20 --src C --start 2026-03-03T09:00:00Z --seed 4 --form positional --compress",
    "v3/midnight.pcap": "--duration 20 --src D --start 2026-03-02T23:59:50Z --seed 5 --jitter 20 --bad-checksum 0.05",
    "v3/serial.pcapng": "--duration 15 --transport serial --seed 6",
}


def q(dataset: Path, sql: str) -> list[tuple]:
    return list(run_query(dataset, sql).rows())


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("fleet") / "captures"
    for name, opts in FLEET.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        assert cli_main(["gen", str(root / name), *opts.split()]) == 0
    (root / "samples").mkdir()
    for p in sorted((REPO / "captures").glob("*.pcap")):
        shutil.copy(p, root / "samples" / p.name)
    return root


@pytest.fixture(scope="module")
def dataset(fleet, tmp_path_factory) -> Path:
    ds = tmp_path_factory.mktemp("ds") / "fleet"
    report = ingest([fleet], ds)
    assert report.ok and report.count("ingested") == len(FLEET) + 2, report
    return ds


def captures(fleet: Path) -> list[Path]:
    return sorted(p.resolve() for p in fleet.rglob("*.pcap*"))


def snapshot(ds: Path) -> dict[str, tuple[int, int]]:
    return {p.relative_to(ds).as_posix(): (p.stat().st_size, p.stat().st_mtime_ns) for p in ds.rglob("*") if p.is_file()}


# -- against tshark and stats -------------------------------------------------------------------------


@functools.cache
def tshark_frames(path: Path) -> list[tuple[int, str, str, str]]:
    """(time ns, src, dst, checksum status: 0 bad, 1 good, 2 none) of every SharedLink frame, by
    the real tshark with the dissectors."""
    extra = ["-X", f"lua_script:{SERIAL_LUA}"] if path.name.startswith("serial") else []
    names = ["frame.time_epoch", "sharedlink.src", "sharedlink.dst", "sharedlink.checksum.status"]
    out = []
    for r in fields(path, names, extra=extra):
        ts = int(Decimal(r["frame.time_epoch"][0]) * 10**9)
        assert len(r["sharedlink.src"]) == len(r["sharedlink.dst"]) == len(r["sharedlink.checksum.status"])
        out += [(ts, *f) for f in zip(r["sharedlink.src"], r["sharedlink.dst"], r["sharedlink.checksum.status"])]
    return out


def test_frames_per_capture_equal_tsharks(fleet, dataset):
    got = dict(q(dataset, "SELECT capture, count(*) FROM frames GROUP BY capture"))
    assert set(got) == {str(p) for p in captures(fleet)}
    for p in captures(fleet):
        assert got[str(p)] == len(tshark_frames(p)) > 0, p
        bad = q(dataset, f"SELECT count(*) FROM frames WHERE capture = '{p}' AND checksum_ok = false")
        assert bad == [(sum(f[3] == "0" for f in tshark_frames(p)),)]


def test_queries_agree_with_stats(fleet, dataset):
    for p in captures(fleet):
        st = capture_stats(p)
        cap = str(p).replace("'", "''")
        pairs = q(dataset, f"""SELECT pair, count(*), sum(size), count(*) FILTER (WHERE checksum_ok = false),
                                      count(*) FILTER (WHERE late), min(time_ns), max(time_ns)
                               FROM frames WHERE capture = '{cap}' GROUP BY pair""")
        assert {r[0]: r[1:] for r in pairs} == {
            k: (v.frames, v.bytes, v.checksum_failures, v.sync_late, v.first_ns, v.last_ns) for k, v in st.pairs.items()
        }, p
        kinds = dict(q(dataset, f"SELECT kind, count(*) FROM frames WHERE capture = '{cap}' GROUP BY kind"))
        assert kinds == st.kinds
        variables = q(dataset, f"""SELECT pair, name, count(*), count(*) FILTER (WHERE changed),
                                          min(value_double), max(value_double), arg_max(text, seq)
                                   FROM values WHERE capture = '{cap}' AND NOT carried GROUP BY pair, name""")
        assert {(r[0], r[1]): r[2:] for r in variables} == {
            k: (v.count, v.changes, v.min, v.max, v.last) for k, v in st.variables.items()
        }, p


def test_partitions_and_typed_values(fleet, dataset):
    parts = q(dataset, "SELECT DISTINCT vehicle, CAST(day AS VARCHAR), link FROM frames WHERE vehicle LIKE 'v%' ORDER BY ALL")
    assert ("v3", "2026-03-02", "D_to_A") in parts and ("v3", "2026-03-03", "D_to_A") in parts  # across midnight
    assert {r[0] for r in parts} == {"v1", "v2", "v3"}
    assert q(dataset, "SELECT count(*) FROM frames WHERE day <> CAST(time AS DATE) OR link <> src || '_to_' || dst") == [(0,)]
    assert q(dataset, "SELECT count(*) FROM values WHERE link <> src || '_to_' || dst") == [(0,)]
    assert all(link_name(s, d) == f"{s}_to_{d}" for s, d in q(dataset, "SELECT DISTINCT src, dst FROM frames"))
    assert {p.name for p in (dataset / "frames").glob("day=*/link=*")} >= {"link=B_to_A", "link=D_to_A"}
    assert not list(dataset.glob("*/day=*/link=?-?"))  # (the spelling before issue 41)
    # every value of a good frame; none of a bad one; typed columns agree with the text
    assert q(dataset, """SELECT count(*) FROM values v JOIN frames f USING (capture, seq)
                         WHERE f.checksum_ok = false""") == [(0,)]
    bad = q(dataset, """SELECT count(*) FROM values WHERE value_double IS NOT NULL
                        AND abs(value_double - CAST(text AS DOUBLE)) > 1e-9""")
    assert bad == [(0,)]
    # the other engines' road: pyarrow reads the same directory with its Hive partitions
    table = pads.dataset(dataset / "frames", format="parquet", partitioning="hive").to_table()
    assert table.num_rows == q(dataset, "SELECT count(*) FROM frames")[0][0]
    assert {"day", "link", "pair", "checksum_ok", "raw"} <= set(table.column_names)


# -- incremental, idempotent, damage ------------------------------------------------------------------


def test_reingest_changes_nothing(fleet, dataset):
    before = snapshot(dataset)
    counts = q(dataset, "SELECT (SELECT count(*) FROM frames), (SELECT count(*) FROM values)")
    report = ingest([fleet], dataset)
    assert report.ok and report.count("unchanged") == len(FLEET) + 2 and report.count("ingested") == 0
    assert snapshot(dataset) == before
    assert q(dataset, "SELECT (SELECT count(*) FROM frames), (SELECT count(*) FROM values)") == counts


def test_changed_capture_replaces_its_rows(fleet, tmp_path):
    ds = tmp_path / "ds"
    work = tmp_path / "caps"
    shutil.copytree(fleet / "v1", work / "v1")
    assert ingest([work], ds).ok
    day1 = (work / "v1" / "day1.pcap").resolve()
    assert cli_main(["gen", str(day1), "--duration", "12", "--seed", "9", "--start", "2026-03-02T08:00:00Z"]) == 0
    files_before = set(load_manifest(ds).captures[str(day1)].files)
    report = ingest([work], ds)
    assert report.count("ingested") == 1 and report.count("unchanged") == 1
    rows = dict(q(ds, "SELECT capture, count(*) FROM frames GROUP BY capture"))
    assert rows[str(day1)] == capture_stats(day1).frames == 60
    assert not any((ds / f).exists() for f in files_before)
    # --force rewrites, never duplicates; a new vehicle name is a change too
    assert ingest([work], ds, force=True).count("ingested") == 2
    assert ingest([work], ds, vehicle="truck-7").count("ingested") == 2
    assert dict(q(ds, "SELECT capture, count(*) FROM frames GROUP BY capture")) == rows
    assert q(ds, "SELECT DISTINCT vehicle FROM values") == [("truck-7",)]
    assert len(list(ds.rglob("*.parquet"))) == len({f for e in load_manifest(ds).captures.values() for f in e.files})


def test_damaged_capture_is_kept_up_to_the_damage_and_reported(fleet, tmp_path):
    caps = tmp_path / "caps"
    caps.mkdir()
    good = caps / "good.pcap"
    shutil.copy(fleet / "v1" / "day1.pcap", good)
    data = (fleet / "v2" / "day1.pcap").read_bytes()
    cut = caps / "cut.pcap"
    cut.write_bytes(data[: len(data) // 2 + 7])
    (caps / "junk.pcap").write_bytes(b"not a capture at all")
    ds = tmp_path / "ds"
    r = run_cli("ingest", str(caps), "--to", str(ds), timeout=300)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and f"{cut.resolve()}: record" in r.stderr and "junk.pcap" in r.stderr
    st = capture_stats(cut)
    assert st.error and st.frames > 10
    got = dict(q(ds, "SELECT capture, count(*) FROM frames GROUP BY capture"))
    assert got == {str(cut.resolve()): st.frames, str(good.resolve()): capture_stats(good).frames}
    errors = dict(q(ds, "SELECT path, error FROM captures WHERE error IS NOT NULL"))
    assert set(errors) == {str(cut.resolve()), str((caps / "junk.pcap").resolve())}
    # again: nothing to do, still reported
    r = run_cli("ingest", str(caps), "--to", str(ds), timeout=300)
    assert r.returncode == 2 and "3 unchanged" not in r.stderr and "1 unchanged" in r.stderr
    assert dict(q(ds, "SELECT capture, count(*) FROM frames GROUP BY capture")) == got


def test_stray_files_of_an_interrupted_ingest_are_swept(fleet, tmp_path):
    ds = tmp_path / "ds"
    assert ingest([fleet / "v1"], ds).ok
    stray = ds / "frames" / "day=2026-03-02" / "link=B_to_A" / ".deadbeef-00000000.parquet"
    stray.write_bytes(b"half")
    report = ingest([fleet / "v1"], ds)
    assert report.swept == 1 and not stray.exists()


# -- the pair's spelling before issue 41: link=B-A ------------------------------------------------------------


def old_style(dataset: Path, to: Path) -> Path:
    """A copy of ``dataset`` as ingest wrote it before issue 41: the frames' and values'
    partitions ``link=B-A`` (the folders renamed, the manifest's file lists with them); the
    packets' ``link=<protocol>`` as they are; no links and outages tables (issue 43, later)."""
    shutil.copytree(dataset, to)
    for table in ("links", "outages"):
        shutil.rmtree(to / table, ignore_errors=True)
    for d in sorted(to.glob("*/day=*/link=*_to_*")):
        assert d.parent.parent.name in ("frames", "values")
        d.rename(d.with_name(d.name.replace("_to_", "-")))
    manifest = load_manifest(to)
    for e in manifest.captures.values():
        e.files = [f.replace("_to_", "-") if f.startswith(("frames/", "values/")) else f for f in e.files
                   if not f.startswith(("links/", "outages/"))]
    save_manifest(to, manifest)
    assert old_links(manifest) and not old_links(load_manifest(dataset))
    assert all((to / f).is_file() for e in manifest.captures.values() for f in e.files)
    return to


OLD_LINK_QUERIES = [
    SUMMARY := """SELECT capture, vehicle, pair, CAST(day AS VARCHAR), count(*), sum(size), sum(hash(raw))
                  FROM frames GROUP BY ALL ORDER BY ALL""",
    VALUES_SUMMARY := """SELECT capture, name, count(*), round(sum(value_double), 6), sum(hash(text))
                         FROM values GROUP BY ALL ORDER BY ALL""",
    "SELECT link, pair, src, dst, count(*) FROM frames GROUP BY ALL ORDER BY ALL",
    "SELECT link, count(*), sum(hash(text)) FROM values GROUP BY ALL ORDER BY ALL",
    "SELECT vehicle, count(*) FROM frames WHERE link = 'C_to_A' GROUP BY ALL ORDER BY ALL",
    "SELECT link, protocol, count(*) FROM packets GROUP BY ALL ORDER BY ALL",
    "SELECT * FROM captures ORDER BY path",
]


def test_a_dataset_of_the_old_spelling_reads_the_same(dataset, tmp_path):
    old = old_style(dataset, tmp_path / "old")
    assert sorted(p.name for p in old.glob("frames/day=*/link=*")) == sorted(
        p.name.replace("_to_", "-") for p in dataset.glob("frames/day=*/link=*"))
    assert sorted(old.glob("packets/**/*.parquet")) == [old / p.relative_to(dataset)
                                                         for p in sorted(dataset.glob("packets/**/*.parquet"))]
    for sql in OLD_LINK_QUERIES:
        assert q(old, sql) == q(dataset, sql), sql
    assert q(old, "SELECT count(*) FROM frames WHERE link LIKE '%-%'") == [(0,)]
    # the packets' link is the protocol, in either dataset
    assert {r[0] for r in q(old, "SELECT DISTINCT link FROM packets")} <= {"p2os", "blackboard"}


def test_ingest_into_a_dataset_of_the_old_spelling(fleet, dataset, tmp_path):
    """Incremental: the captures there stay (their files, link=B-A, as they were); a new one
    goes to link=B_to_A partitions; one ingested again moves to them; every query the same."""
    old = old_style(dataset, tmp_path / "old")
    before = load_manifest(old)
    extra = tmp_path / "more" / "v4" / "extra.pcap"
    extra.parent.mkdir(parents=True)
    assert cli_main(["gen", str(extra), "--duration", "5", "--src", "E", "--seed", "11",
                     "--start", "2026-03-04T08:00:00Z"]) == 0
    assert ingest([fleet, extra.parent.parent], old).count("ingested") == 1
    after = load_manifest(old)
    assert {k: e.files for k, e in after.captures.items() if k in before.captures} == {
        k: e.files for k, e in before.captures.items()}
    assert after.captures[str(extra.resolve())].files and all(
        "/link=E_to_A/" in f for f in after.captures[str(extra.resolve())].files)
    new = tmp_path / "new"
    assert ingest([extra.parent.parent], new).ok and ingest([fleet], new).ok
    for sql in OLD_LINK_QUERIES:
        assert q(old, sql) == q(new, sql), sql
    # captures of the old spelling ingested again: their files move, the old ones go
    v1 = [str(p.resolve()) for p in sorted((fleet / "v1").glob("*.pcap"))]
    assert ingest([fleet / "v1"], old, force=True).count("ingested") == len(v1)
    assert all("_to_" in f for k in v1 for f in load_manifest(old).captures[k].files if not f.startswith("packets/"))
    assert not any((old / f).exists() for k in v1 for f in after.captures[k].files)
    assert old_links(load_manifest(old))  # (the other captures' files)
    for sql in OLD_LINK_QUERIES:
        assert q(old, sql) == q(new, sql), sql


def test_a_query_with_the_old_spelling_of_a_link(dataset, tmp_path):
    """``WHERE link = 'B-A'`` (scripts written before issue 41) answers as ``link = 'B_to_A'``
    until the next release, with the one deprecation line; nothing else is respelled."""
    assert renamed_links("SELECT 'B-A' AS x FROM frames f WHERE f.\"link\" NOT IN ('C-A', 'D-A') -- 'B-A'") == (
        "SELECT 'B-A' AS x FROM frames f WHERE f.\"link\" NOT IN ('C_to_A', 'D_to_A') -- 'B-A'",
        [("C-A", "C_to_A"), ("D-A", "D_to_A")])
    for sql in ("SELECT day FROM frames WHERE day = '2026-03-02'", "SELECT 1 WHERE link LIKE 'B-%'",
                "SELECT 'B-A' = link", "SELECT pair FROM frames WHERE pair = 'B-A'"):
        assert renamed_links(sql) == (sql, []), sql
    sql = "SELECT vehicle, count(*) AS n FROM frames WHERE link = '{}' GROUP BY ALL ORDER BY ALL"
    old = old_style(dataset, tmp_path / "old")
    for ds in (dataset, old):
        want = q(ds, sql.format("B_to_A"))
        assert want and q(ds, sql.format("B-A")) == want
        assert run_query(ds, sql.format("B-A")).renamed == [("B-A", "B_to_A")]
        r = run_cli("query", str(ds), sql.format("B-A"), "--format", "json", timeout=120)
        assert r.returncode == 0 and [(d["vehicle"], d["n"]) for d in json.loads(r.stdout)] == want
        assert r.stderr == ("sharedlink: warning: link = 'B-A' is deprecated, use link = 'B_to_A' or pair = 'B>A' "
                            "(the old spelling goes in the next release)\n")
        r = run_cli("query", str(ds), sql.format("B_to_A"), timeout=120)
        assert r.returncode == 0 and r.stderr == ""


# -- parallel: processes and Dask -----------------------------------------------------------------------



def test_two_workers_give_the_same_dataset(fleet, dataset, tmp_path):
    ds = tmp_path / "ds2"
    report = ingest([fleet], ds, workers=2)
    assert report.ok and report.count("ingested") == len(FLEET) + 2
    assert q(ds, SUMMARY) == q(dataset, SUMMARY)
    assert q(ds, VALUES_SUMMARY) == q(dataset, VALUES_SUMMARY)


def test_dask_local_cluster_gives_the_same_dataset(fleet, dataset, tmp_path):
    distributed = pytest.importorskip("distributed")
    ds = tmp_path / "ds-dask"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        report = ingest([fleet], ds, scheduler=cluster.scheduler_address, batch_rows=100)
    assert report.ok and report.count("ingested") == len(FLEET) + 2
    assert q(ds, SUMMARY) == q(dataset, SUMMARY)
    assert q(ds, VALUES_SUMMARY) == q(dataset, VALUES_SUMMARY)


def test_a_worker_started_with_a_small_trim_threshold_gives_the_same_dataset(fleet, dataset, tmp_path):
    """Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536; a task then keeps freed
    heap while it decodes (ingest._heap_kept, glibc's mallopt) and sets it back after: the same
    rows, in a process started as Dask starts its workers (2 of them: a pool)."""
    import os
    import platform

    from sharedlink.fleet.ingest import _glibc

    ds = tmp_path / "ds-trim"
    code = f"from sharedlink.fleet.ingest import ingest; assert ingest([{str(fleet)!r}], {str(ds)!r}, workers=2).ok"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300,
                   env=dict(os.environ, MALLOC_TRIM_THRESHOLD_="65536"))
    assert q(ds, SUMMARY) == q(dataset, SUMMARY)
    assert q(ds, VALUES_SUMMARY) == q(dataset, VALUES_SUMMARY)
    if sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc":
        assert _glibc() is not None  # (else the heap is not kept: slower, not wrong)


@pytest.mark.parametrize("timeout", [pytest.param(None, marks=pytest.mark.long), "0.5"])
def test_unreachable_scheduler_is_a_usage_error(fleet, tmp_path, timeout):
    """Given up after --scheduler-timeout (default 10 s: make test-long waits it out)."""
    wait = [] if timeout is None else ["--scheduler-timeout", timeout]
    r = run_cli("ingest", str(fleet / "v1"), "--to", str(tmp_path / "d"), "--scheduler", "tcp://127.0.0.1:9", *wait, timeout=120)
    assert r.returncode == 2 and "Dask scheduler" in r.stderr and "Traceback" not in r.stderr
    assert f"after {timeout or 10} s" in r.stderr, r.stderr  # (Dask's words: the timeout it was given)


@pytest.mark.parametrize("timeout", ["0", "-1", "nan"])
def test_scheduler_timeout_must_be_a_positive_number(fleet, tmp_path, timeout):
    r = run_cli("ingest", str(fleet / "v1"), "-o", str(tmp_path / "d"), "--scheduler", "tcp://127.0.0.1:9", "--scheduler-timeout", timeout, timeout=120)
    assert r.returncode == 2 and "argument --scheduler-timeout" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("shape", ["dangling-link", "file"])
def test_a_dataset_path_that_cannot_be_a_directory_is_one_line(fleet, tmp_path, shape):
    """--to a link to nothing, or a file: one line and exit 2, nothing made behind the link,
    the file left as it was (issue 31)."""
    to = tmp_path / "d"
    if shape == "dangling-link":
        to.symlink_to(tmp_path / "nowhere")
    else:
        to.write_bytes(b"keep me")
    r = run_cli("ingest", str(fleet / "v1"), "-o", str(to), timeout=120)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert str(to) in r.stderr
    if shape == "dangling-link":
        assert to.is_symlink() and not (tmp_path / "nowhere").exists()
    else:
        assert to.read_bytes() == b"keep me"


def test_memory_does_not_grow_with_the_capture(tmp_path):
    peaks = []
    for n in (1000, 8000):
        cap = tmp_path / f"c{n}.pcap"
        assert cli_main(["gen", str(cap), "--frames", str(n), "--compress"]) == 0
        tracemalloc.start()
        report = ingest([cap], tmp_path / f"ds{n}", batch_rows=500)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert report.ok and q(tmp_path / f"ds{n}", "SELECT count(*) FROM frames") == [(n,)]
    # the larger capture may fill the 1 MiB read buffers (hash, capture reader) the smaller one
    # does not; rows held are bounded by batch_rows (8000 frames' rows would be ~10 MB)
    assert peaks[1] < peaks[0] + 2 * (1 << 20) + 300_000, peaks


# -- the query command ------------------------------------------------------------------------------------


def test_query_cli_formats(dataset):
    sql = "SELECT pair, count(*) AS frames FROM frames WHERE vehicle = 'v2' GROUP BY pair ORDER BY pair"
    want = q(dataset, sql)
    r = run_cli("query", str(dataset), sql, "--format", "json", timeout=120)
    assert r.returncode == 0, r.stderr
    assert [(d["pair"], d["frames"]) for d in json.loads(r.stdout)] == want
    r = run_cli("query", str(dataset), sql, "--format", "csv", timeout=120)
    assert r.stdout.splitlines() == ["pair,frames"] + [f"{a},{b}" for a, b in want]
    csv_text = r.stdout
    r = run_cli("query", str(dataset), sql, timeout=120)
    assert r.returncode == 0 and r.stdout == csv_text  # on a pipe: CSV
    r = run_cli("query", str(dataset), sql, "--format", "table", timeout=120)
    assert r.returncode == 0 and "C>A" in r.stdout and f"({len(want)} row" in r.stdout


def test_query_bad_input(dataset, tmp_path):
    r = run_cli("query", str(dataset), "SELECT nope FROM frames", timeout=120)
    assert r.returncode == 2 and r.stderr.startswith("sharedlink: error: query:") and "Traceback" not in r.stderr
    r = run_cli("query", str(tmp_path), "SELECT 1", timeout=120)
    assert r.returncode == 2 and "not a fleet dataset" in r.stderr
    r = run_cli("ingest", str(tmp_path / "none.pcap"), "--to", str(tmp_path / "d"), timeout=120)
    assert r.returncode == 2 and "no such file" in r.stderr


def test_empty_dataset_has_the_columns(tmp_path):
    ds = tmp_path / "ds"
    (tmp_path / "empty").mkdir()
    assert ingest([tmp_path / "empty"], ds).ok
    assert q(ds, "SELECT count(*), max(time), max(value_double) FROM values") == [(0, None, None)]
    assert q(ds, "SELECT count(*), max(day) FROM frames") == [(0, None)]


# -- the questions of docs/fleet.md -----------------------------------------------------------------------


def docs_queries() -> list[str]:
    return re.findall(r"```sql\n(.*?)```", (REPO / "docs" / "fleet.md").read_text(), re.S)


def day_of(ts_ns: int) -> dt.date:
    return dt.datetime.fromtimestamp(ts_ns // 10**9, dt.timezone.utc).date()


def as_time(ts_ns: int) -> dt.datetime:
    return dt.datetime(1970, 1, 1) + dt.timedelta(microseconds=ts_ns // 1000)


def test_docs_questions(fleet, dataset):
    lossy, top_speed, c_last, c_silences = docs_queries()
    vehicle = {str(p): p.parent.name for p in captures(fleet)}
    # 1. links losing more than 1 % of frames to bad checksums, per vehicle per day (tshark's counts)
    per: dict[tuple, list[int]] = {}
    for p in captures(fleet):
        for ts, src, dst, status in tshark_frames(p):
            n = per.setdefault((vehicle[str(p)], day_of(ts), f"{src}>{dst}"), [0, 0])
            n[0] += 1
            n[1] += status == "0"
    want = sorted((*k, n, bad) for k, (n, bad) in per.items() if bad > 0.01 * n)
    got = [r[:5] for r in q(dataset, lossy)]
    assert got == want and ("v2", dt.date(2026, 3, 2), "C>A") in {r[:3] for r in got}
    # 2. top speed per vehicle (sharedlink stats' max of AutoGpsVel)
    best: dict[str, float] = {}
    for p in captures(fleet):
        for (_pair, name), v in capture_stats(p).variables.items():
            if name == "AutoGpsVel" and v.max is not None:
                best[vehicle[str(p)]] = max(best.get(vehicle[str(p)], v.max), v.max)
    assert {r[0]: r[1] for r in q(dataset, top_speed)} == best
    # 3. when did node C stop answering (good frames by tshark's verdict)
    heard: dict[dt.date, list[int]] = {}
    for p in captures(fleet):
        for ts, src, _dst, status in tshark_frames(p):
            if status != "0":
                h = heard.setdefault(day_of(ts), [0, 0])
                h[1] = max(h[1], ts)
                if src == "C":
                    h[0] = max(h[0], ts)
    want3 = [(d, as_time(c), as_time(a)) for d, (c, a) in sorted(heard.items()) if c]
    assert [r[:3] for r in q(dataset, c_last)] == want3 and len(want3) == 2
    # ... and its silences: the 280 s between the two captures of v2 on 2026-03-02
    rows = q(dataset, c_silences)
    assert len(rows) == 1 and rows[0][0] == "v2" and 270 < rows[0][3].total_seconds() < 290


def test_reingest_whose_manifest_save_fails_keeps_the_old_rows(fleet, tmp_path, monkeypatch):
    """A crash leaves at worst unlisted files: a re-ingest of a changed capture whose manifest
    save fails (a full disk, a kill) leaves every file the manifest lists in place, and the
    capture's old rows still answer; the next ingest sweeps what the failed one left."""
    import sharedlink.fleet.ingest as ingest_mod

    ds = tmp_path / "ds"
    work = tmp_path / "caps"
    shutil.copytree(fleet / "v1", work / "v1")
    assert ingest([work], ds).ok
    day1 = (work / "v1" / "day1.pcap").resolve()
    old_rows = q(ds, f"SELECT count(*), sum(hash(raw)) FROM frames WHERE capture = '{day1}'")
    assert old_rows[0][0] > 0
    assert cli_main(["gen", str(day1), "--duration", "12", "--seed", "9", "--start", "2026-03-02T08:00:00Z"]) == 0

    def failing_save(root, manifest):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(ingest_mod, "save_manifest", failing_save)
    with pytest.raises(OSError):
        ingest([work], ds)
    monkeypatch.undo()
    listed = {f for e in load_manifest(ds).captures.values() for f in e.files}
    assert listed and all((ds / f).exists() for f in listed), sorted(f for f in listed if not (ds / f).exists())
    assert q(ds, f"SELECT count(*), sum(hash(raw)) FROM frames WHERE capture = '{day1}'") == old_rows
    # the next ingest takes the change and sweeps the unlisted files the failed one wrote
    report = ingest([work], ds)
    assert report.swept > 0 and report.count("ingested") == 1
    assert len(list(ds.rglob("*.parquet"))) == len({f for e in load_manifest(ds).captures.values() for f in e.files})
