"""Issue 40, item 2: a reply's values are kept in every export.

A reply's ``R``/``D`` values are shown on the reply and never stored in its direction's table
(docs/fields-sharedlink.md, "Replies" and disagreement 2). Exports used to write its row from the
table: ``"values": {}`` (or the data frames' values) while ``"changed"`` named the reply's names.
Now a reply's row holds the values the reply carries, typed as its direction's list types them,
and no row's ``changed`` names a value the row does not hold: csv and jsonl (the CLI, as people
run it), MCAP (the values and frames channels, read back with the `mcap` reader) and ``ingest``
(the values table, read back with pyarrow). The stream is the shared vector
``round3-reply-values-in-exports`` (tests/vectors/sharedlink-round3.json), which both decoders
follow frame by frame.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import pytest
from sl_cli import run_cli
from sl_vectors import load_streams, write_stream

CLI = [sys.executable, "-m", "sharedlink"]
STREAM = {s["name"]: s for s in load_streams()}["round3-reply-values-in-exports"]
#: the replies' packet numbers and the values they carry (typed: untyped names read as numbers)
REPLIES = {4: {"video_mux1": 1, "veh_start": 0}, 7: {"AutoGpsVel": 0.7}}
#: the vehicle's data frames after the replies: the reply's 0.7 is never stored
DATA = {5: {"AutoGpsHead": 268.6, "AutoGpsVel": 0.5}, 8: {"AutoGpsHead": 268.7, "AutoGpsVel": 0.5}}


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    return write_stream(STREAM, tmp_path / "replies.pcap")


def _export(cap: Path, out: Path, *args: str) -> str:
    r = run_cli("export", str(cap), "-o", str(out), *args, timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    return "" if out.suffix == ".mcap" else out.read_text(encoding="utf-8")


def test_jsonl_reply_rows_hold_their_own_values(capture: Path, tmp_path: Path) -> None:
    rows = {r["number"]: r for r in map(json.loads, _export(capture, tmp_path / "r.jsonl").splitlines())}
    for n, values in REPLIES.items():
        assert rows[n]["kind"] == "reply"
        assert rows[n]["values"] == values
        assert rows[n]["changed"] == list(values)
    for n, values in DATA.items():
        assert rows[n]["values"] == values
    assert rows[5]["changed"] == ["AutoGpsHead"]
    for r in rows.values():
        assert set(r["changed"]) <= set(r["values"]), r


def test_jsonl_changed_names_only_the_selected_values(capture: Path, tmp_path: Path) -> None:
    text = _export(capture, tmp_path / "s.jsonl", "--select", "AutoGpsVel,veh_start")
    rows = {r["number"]: r for r in map(json.loads, text.splitlines())}
    assert rows[4]["values"] == {"veh_start": 0} and rows[4]["changed"] == ["veh_start"]
    assert rows[2]["values"] == {"AutoGpsVel": 0.5} and rows[2]["changed"] == ["AutoGpsVel"]
    assert rows[5]["changed"] == []
    for r in rows.values():
        assert set(r["changed"]) <= set(r["values"]), r


def test_csv_reply_rows_hold_their_own_values(capture: Path, tmp_path: Path) -> None:
    rows = {int(r["number"]): r for r in csv.DictReader(_export(capture, tmp_path / "r.csv").splitlines())}
    assert {k: rows[4][k] for k in ("video_mux1", "veh_start", "AutoGpsHead", "AutoGpsVel")} == {
        "video_mux1": "1", "veh_start": "0", "AutoGpsHead": "", "AutoGpsVel": ""}
    assert (rows[7]["AutoGpsVel"], rows[7]["AutoGpsHead"], rows[7]["video_mux1"]) == ("0.7", "", "")
    assert (rows[8]["AutoGpsHead"], rows[8]["AutoGpsVel"], rows[8]["video_mux1"]) == ("268.7", "0.5", "")


def test_mcap_reply_messages_hold_their_own_values(capture: Path, tmp_path: Path) -> None:
    pytest.importorskip("mcap.reader")
    from sl_checks import Mcap  # (the file read back with the independent reader)

    _export(capture, tmp_path / "r.mcap")
    m = Mcap(tmp_path / "r.mcap")
    (values_topic,) = [t for t in m.msgs if t.startswith("/sharedlink/") and t.endswith("/values")
                       and any(msg.get("AutoGpsHead") for _, msg in m.msgs[t])]
    frames = m.msgs[values_topic[: -len("values")] + "frames"]
    values = m.msgs[values_topic]
    assert len(frames) == len(values) == 5   # the vehicle's direction: 3 data frames, 2 replies
    by_number = {f["number"]: (f, v) for (_, f), (_, v) in zip(frames, values)}
    for n, want in REPLIES.items():
        f, v = by_number[n]
        assert f["kind"] == "reply" and v == want and f["changed"] == list(want)
    for n, want in DATA.items():
        assert by_number[n][1] == want
    for f, v in by_number.values():
        assert set(f["changed"]) <= set(v), f


def test_ingest_keeps_a_replys_values(capture: Path, tmp_path: Path) -> None:
    pads = pytest.importorskip("pyarrow.dataset")
    from sharedlink.fleet.ingest import ingest

    report = ingest([capture], tmp_path / "ds")
    assert report.ok, report
    t = pads.dataset(tmp_path / "ds" / "values", format="parquet", partitioning="hive").to_table(
        columns=["frame", "name", "text", "value_long", "value_double", "changed"])
    rows = sorted(zip(*(t.column(c).to_pylist() for c in t.column_names)))
    got = {n: [(r[1], r[2], r[5]) for r in rows if r[0] == n] for n in (4, 7)}
    assert got == {4: [("veh_start", "0", True), ("video_mux1", "1", True)], 7: [("AutoGpsVel", "0.7", True)]}
    (vel,) = [r for r in rows if r[0] == 7]
    assert vel[4] == 0.7   # a double by its direction's list
