"""`ingest`'s rows, row by row, against their definition: every frame of the plain reference
decoder (:class:`~sharedlink.analysis.decode.ReferenceDecoder`, frame by frame through
``iter_frames``) gives one frames row, and each value it leaves (carried ones too, not those
of a frame with a bad checksum) a values row, typed by the direction's declared type. On
generated streams built to vary (both forms, declarations, replies, bad checksums, two frames
in a datagram, noise, two directions) and on compressed drives, with a tiny batch so that rows
cross row groups and partitions."""

from __future__ import annotations

import math
from pathlib import Path

import pyarrow as pa
import pyarrow.dataset as pads
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from sl_captures import captures, examples, write_capture

from sharedlink.analysis.decode import ReferenceDecoder
from sharedlink.capture.stream import iter_frames
from sharedlink.fleet.dataset import FRAMES_SCHEMA, VALUES_SCHEMA
from sharedlink.fleet.ingest import ingest
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import guess_value, typed_value

#: 2026-01-02T00:00:00Z
MIDNIGHT_NS = 1_767_312_000 * 10**9


def _typed(tc: int | None, text: str) -> tuple:
    x = guess_value(text) if tc is None else typed_value(tc, text)
    if isinstance(x, str):
        return None, None, x
    if isinstance(x, int):
        return (x, float(x), None) if -(1 << 63) <= x < (1 << 63) else (None, float(x), None)
    return None, x, None


def reference_rows(path: Path) -> tuple[list[tuple], list[tuple]]:
    """(frames rows, values rows) by the definition, without capture and vehicle."""
    dec = ReferenceDecoder()
    frames, values = [], []
    seq = 0
    for sf in iter_frames(path):
        if sf.frame is None:
            continue
        d = dec.decode(sf)
        seq += 1
        proto = str(d.conv[0])
        conv = f"{proto} {d.conv[1]}:{d.conv[2]} > {d.conv[3]}:{d.conv[4]}"
        pair = f"{d.src}>{d.dst}"
        frames.append((seq, d.number, d.ts_ns, proto, conv, d.src, d.dst, pair, d.kind, d.checksum_ok, d.late,
                       len(d.raw), d.raw))
        for u in d.updates:
            if u.text is None:
                continue
            tc = u.type_code  # a named value's own T (none: untyped), a slot's its list's type
            values.append((seq, d.number, d.ts_ns, d.src, d.dst, pair, u.name, tc, u.text, *_typed(tc, u.text),
                           u.carried, u.changed))
    return frames, values


def dataset_rows(ds: Path, table: str) -> list[tuple]:
    schema = FRAMES_SCHEMA if table == "frames" else VALUES_SCHEMA
    names = [n for n in schema.names if n not in ("capture", "vehicle")]
    if not (ds / table).exists():  # (no row of this table)
        return []
    t = pads.dataset(ds / table, format="parquet", partitioning="hive").to_table(columns=names)
    rows = list(zip(*(t.column(n).to_pylist() for n in names)))
    if table == "values":  # NaN != NaN: compare its text instead
        rows = [r[:10] + ("nan",) + r[11:] if isinstance(r[10], float) and math.isnan(r[10]) else r for r in rows]
    key = (lambda r: (r[0],)) if table == "frames" else (lambda r: (r[0], r[6]))
    return sorted(rows, key=key)


def _same(path: Path, ds: Path, batch_rows: int) -> int:
    report = ingest([path], ds, batch_rows=batch_rows)
    assert report.ok, report
    frames, values = reference_rows(path)
    assert dataset_rows(ds, "frames") == frames
    fix = [r[:10] + ("nan",) + r[11:] if isinstance(r[10], float) and math.isnan(r[10]) else r for r in values]
    assert dataset_rows(ds, "values") == sorted(fix, key=lambda r: (r[0], r[6]))
    return len(frames)


@settings(max_examples=30, deadline=None, suppress_health_check=list(HealthCheck))
@given(captures(max_frames=30))
# a named value of a listed name without its own T: untyped (issue 31's rule), not its list's type
@example([(1_767_268_800_200_000_000, b"[:AB|N0|QAutoGpsLat|D1.5|X1|C80]\r\n")])
def test_rows_equal_the_reference_on_generated_streams(tmp_path_factory, datagrams):
    d = tmp_path_factory.mktemp("ing")
    _same(write_capture(d / "c.pcap", datagrams), d / "ds", batch_rows=7)


@pytest.mark.parametrize("variant", [dict(compress=True, bad_checksum=0.05, drop=0.3, seed=2),
                                     dict(form="positional", compress=True, seed=3), dict(jitter_ms=300.0, seed=4),
                                     dict(compress=True, jitter_ms=300.0, seed=5, start_ns=MIDNIGHT_NS - 20 * 10**9)])
def test_rows_equal_the_reference_on_drives(tmp_path, variant):
    """(the last one crosses midnight inside the decoder's batches: two day partitions)"""
    path = tmp_path / "d.pcap"
    generate_file(GenOptions(duration=40, **variant), path)
    assert _same(path, tmp_path / "ds", batch_rows=333) > 100
    if "start_ns" in variant:
        assert len(list((tmp_path / "ds" / "values").iterdir())) == 2


@pytest.mark.parametrize("type_code", [None, 0, 2, 4, 7])
def test_typed_columns_of_odd_texts(type_code):
    """ingest's typing (int()/float() straight) gives the reference typing's columns for texts
    of every kind: signs, leading zeros, exponents past the double's range, integers past
    int64 and past Python's digit limit, nan/inf spelt out, spaces, underscores, other digits."""
    from sharedlink.fleet.ingest import _typed as fast

    texts = ["7", "-0", "0", "12345678901234567890", "-9223372036854775808", "9223372036854775808", "1.5", "-0.25",
             "1e5", "1E-3", "1e999", "-1e999", ".5e999", "007", "1.", ".5", "+3", "abc", "", "0x10", "1_000", "NaN",
             "nan", "inf", "-Infinity", " 1", "1 ", "2.50", "1" * 5000, "-" + "1" * 5000, "\u0663", "+", "-", ".",
             "e5", "1e", "+-3", "1.5e+3", "\u00e9"]
    for t in texts:
        want, got = _typed(type_code, t), fast(type_code, t)
        assert [type(x) for x in got] == [type(x) for x in want] and got == want, t


@settings(max_examples=examples(200), deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=20),
       st.sampled_from(["%r", "%.17g", "%.3e", "%+.10f", "%.0f", "%.1f", "%E"]))
def test_arrow_reads_doubles_as_float_does(xs, form):
    """Doubles that fit their type are cast by Arrow (all of a batch at once): the same floats
    as Python's float() of the text, in the forms a sender writes them."""
    from sharedlink.fleet.ingest import _Rows

    texts = [form % x for x in xs]
    rows = _Rows(Path("."), "c", "v", "s", 10)
    vlong, vdouble, vstring = rows._typed_columns([2] * len(texts), texts, pa.array([2] * len(texts), pa.int8()),
                                                  pa.array(texts))
    assert vdouble.to_pylist() == [float(t) for t in texts]
    assert vlong.null_count == vstring.null_count == len(texts)


@settings(max_examples=examples(300), deadline=None)
@given(st.lists(st.one_of(st.text(alphabet="0123456789+-.eE \n_x\u0663", max_size=8), st.text(max_size=6)), min_size=1,
                max_size=20))
def test_arrow_takes_as_doubles_the_texts_that_fit_the_double_type(texts):
    """The doubles Arrow converts are the texts parse_typed says fit the double type (Arrow's
    regular expression against codec's): the others are typed one by one, as text."""
    from sharedlink.fleet.ingest import _Rows
    from sharedlink.protocols.codec import parse_typed

    rows = _Rows(Path("."), "c", "v", "s", 10)
    vlong, vdouble, vstring = rows._typed_columns([2] * len(texts), texts, pa.array([2] * len(texts), pa.int8()),
                                                  pa.array(texts, pa.string()))
    for t, x, s in zip(texts, vdouble.to_pylist(), vstring.to_pylist()):
        fits = parse_typed(2, t)[1]
        assert (x, s) == ((float(t), None) if fits else (None, t)), t
