"""The decoding core's counts mode (``Decoder.capture(counts=True)``, what ``stats`` reads)
against the full mode and the plain reference decoder.

In counts mode the frames the fast path takes come as :class:`~sharedlink.analysis.decode.Counted`
sums per direction: runs straight from the pcap block (``Decoder.count_run``: one match a frame,
the values summed per variable once a run) and single frames (``Decoder.count``). Every sum must
be what the reference decoder's frames give (``stats`` of the counts mode equal to every frame
through ``ReferenceDecoder`` and ``CaptureStats.add``), and the tables the sums leave must be the
reference's: each frame decoded the other way after a batch (its Updates, ``carried_from``
included, show which frame last set each value) is compared field by field with the reference's
and with the full mode's, and so is every table at the end. The streams put frames that runs
take (the beacon's variables, in table order) between what changes a value, a type or the names
behind their back: two frames in a datagram, replies, declarations, positional frames, bad
checksums, values the pattern does not take, late and gapped syncs, several directions.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import pytest
from core_streams import (
    bad_checksum,
    declaration,
    positional,
    reference_items,
    reply,
    spy_runs,
    stats_by_reference,
    write_udp,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sl_captures import captures, examples, write_capture
from sl_vectors import load_streams, write_stream

from sharedlink.analysis.decode import Counted, Decoded, Decoder, ReferenceDecoder
from sharedlink.analysis.stats import capture_stats
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named
from sharedlink.protocols.state import BEACON_VARIABLES, parse_variables

BEACON = tuple(n for n, _t in BEACON_VARIABLES)  # in the table's order: what runs take
VALUES = ("1", "2", "2.5", "-3", "10", "1e", "+.5", "38.123456")  # few: unchanged values are the rule


@st.composite
def _frame(draw, src: str, dst: str) -> bytes:
    kind = draw(st.sampled_from(("run", "run", "run", "run", "run", "run", "bare", "shuffled", "bad", "reply",
                                 "declaration", "positional", "odd", "long", "new")))
    if kind in ("run", "bad", "long"):
        names = [n for n in BEACON if draw(st.booleans())]  # a subset, in table order
        raw = encode_named(dst, src, [(n, 0 if kind == "long" else 2, draw(st.sampled_from(VALUES))) for n in names])
        return bad_checksum(raw) if kind == "bad" else raw
    if kind == "bare":
        return encode_named(dst, src, [])
    if kind == "shuffled":  # out of table order: the single-frame path
        names = draw(st.permutations(BEACON))[: draw(st.integers(1, 4))]
        return encode_named(dst, src, [(n, 2, draw(st.sampled_from(VALUES))) for n in names])
    if kind == "new":  # a name the table does not have yet (it grows; later frames may carry it)
        return encode_named(dst, src, [(BEACON[0], 2, draw(st.sampled_from(VALUES))),
                                       ("Extra", 2, draw(st.sampled_from(VALUES)))])
    if kind == "reply":
        return draw(reply(src, dst, BEACON, VALUES))
    if kind == "declaration":
        return draw(declaration(src, dst, BEACON))
    if kind == "positional":
        return draw(positional(src, dst, VALUES))
    # a value the pattern does not take (a space): the reference path changes it
    return encode_named(dst, src, [(draw(st.sampled_from(BEACON)), 2, draw(st.sampled_from(VALUES)) + " x")])


@st.composite
def streams(draw, max_datagrams: int = 60) -> list[tuple[int, int, bytes]]:
    """(sender, ts_ns, payload): runs of one sender's frames, sometimes two frames a datagram."""
    out = []
    ts = 1_700_000_000 * 10**9
    sender = 0
    for _ in range(draw(st.integers(1, max_datagrams))):
        if draw(st.integers(0, 7)) == 0:
            sender = draw(st.integers(0, 2))  # two conversations of B>A, and one of C>A
        src = "C" if sender == 2 else "B"
        # (1.5 s: a delta exactly at the sync interval plus the slack is not late)
        ts += draw(st.sampled_from((200_000_000, 200_000_000, 200_000_000, 1_700_000_000, 1_500_000_000)))
        payload = draw(_frame(src, "A"))
        if draw(st.integers(0, 9)) == 0:
            payload += draw(_frame(src, "A"))
        out.append((sender, ts, payload))
    return out


def _table(t) -> tuple:
    return ({n: (v.text, v.type_code, v.set_in, v.set_at) for n, v in t.vars.items()},
            (t.last_full_at, t.last_full_in, t.named, dict(t.sent_names), tuple(t.names), sorted(t.filled)))


def _key(d: Decoded) -> tuple:
    """Everything a Decoded says, the table after it included."""
    return (d.number, d.ts_ns, d.conv, d.raw, d.src, d.dst, d.kind, d.checksum_ok, d.updates, d.late,
            d.sync_gap_ns, d.shown, d.response_to, _table(d.table))


def compare(path: Path, variables=BEACON_VARIABLES) -> tuple[int, int]:
    """The counts mode against the reference and the full mode (see the module doc); returns
    (frames the runs took, frames counted in all)."""
    assert capture_stats(path, variables).to_dict() == stats_by_reference(path, variables).to_dict()
    dec = Decoder(variables)  # (carried values kept: the Decoded after a batch show its table)
    took = spy_runs(dec, "count_run")
    decoded, counted = [], 0
    for item in dec.capture(path, counts=True):
        if isinstance(item, Decoded):
            decoded.append(_key(item))  # (tables are live: read now)
        elif isinstance(item, Counted):
            for (conv, src, dst), c in item.dirs.items():
                assert (conv, src, dst) == (c.conv, c.src, c.dst) and c.frames > 0
                counted += c.frames
    ref = ReferenceDecoder(variables)
    want = [_key(d) for d in reference_items(ref, path) if isinstance(d, Decoded)]
    full = Decoder(variables)
    every = [_key(d) for d in full.capture(path) if isinstance(d, Decoded)]
    assert every == want
    assert len(decoded) + counted == len(want)
    by_number: dict[int, list[tuple]] = defaultdict(list)
    for k in want:
        by_number[k[0]].append(k)
    for k in decoded:  # each frame decoded the other way: the reference's, table and carried_from included
        assert k in by_number[k[0]], k[:8]
    # every table at the end (the last batch handed over): the reference's
    assert {k: _table(t) for k, t in dec.link.tables.items()} == {k: _table(t) for k, t in ref.link.tables.items()}
    return sum(took), counted


@settings(max_examples=examples(150), deadline=None, suppress_health_check=list(HealthCheck))
@given(streams())
def test_counts_equal_the_reference_on_generated_streams(tmp_path_factory, stream):
    compare(write_udp(tmp_path_factory.mktemp("cnt") / "s.pcap", stream))


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(captures())
def test_counts_equal_the_reference_on_varied_captures(tmp_path_factory, dgs):
    compare(write_capture(tmp_path_factory.mktemp("var") / "x.pcap", dgs))


def test_a_reference_frame_between_runs_changes_what_they_sum(tmp_path):
    """Runs (frames in table order) with, between them, a datagram of two frames (the reference
    path) that changes Lat, a bad checksum (changes nothing), a reply (shown, not stored), a
    late delta, a gap between full sets, a frame out of table order (the single-frame path) and
    a type change: the sums and tables are the reference's, and runs took most frames."""
    def b(*kv, t=2):
        return encode_named("A", "B", [(k, t, v) for k, v in kv])
    lat, lon, head, vel = BEACON
    full = lambda a, o: b((lat, a), (lon, o), (head, "1"), (vel, "0"))  # noqa: E731
    stream = [full("1", "2"), b((lat, "1")), b((lat, "2"), (lon, "2")), b((lon, "3")), b(),
              b((lat, "5")) + b((lon, "4")), b((lat, "5")), b((lon, "5")), full("1", "2"),
              b((lon, "9"))[:-5] + b"00]\r\n", b((lon, "6")), build_frame(Frame("A", "B", (Field("R", lat), Field("D", "2.5")))), b((lon, "7")),
              b((vel, "3"), (lat, "8")), b((lat, "9")), full("2", "2"), b((lat, "3")), b((lat, "3")),
              b((lat, "7"), t=0), b((lon, "8")), full("4", "4"), b((lat, "4")), b((lon, "1"), (lat, "1")),
              b((lat, "2")), b((lon, "2"), (lat, "2")), b((lon, "3"), (lat, "2")), b((lat, "4"))]
    times = [(i + 1) * 2 * 10**8 + (2 * 10**9 if i >= 12 else 0) + (3 * 10**9 if i >= 15 else 0)
             for i in range(len(stream))]
    path = write_udp(tmp_path / "s.pcap", [(0, ts, p) for ts, p in zip(times, stream)])
    runs, counted = compare(path)
    assert runs >= 8 and counted > runs  # runs, and frames count() took one at a time


@pytest.mark.parametrize("stream", load_streams(), ids=lambda s: s["name"])
def test_counts_equal_the_reference_on_the_shared_vectors(tmp_path, stream):
    ext = "pcapng" if stream.get("transport") == "serial" else "pcap"
    path = write_stream(stream, tmp_path / f"s.{ext}")
    try:
        variables = parse_variables(stream["variables"]) if stream.get("variables") else BEACON_VARIABLES
    except ValueError:  # a per-pair list, which only issue 29's parser reads
        pytest.skip("a variable list the decoders do not take yet")
    compare(path, variables)


@pytest.mark.parametrize("variant", [dict(compress=True, bad_checksum=0.1, drop=0.3, jitter_ms=300.0, seed=2),
                                     dict(compress=True, drop=0.3, bad_checksum=0.05, seed=2), dict(seed=3),
                                     dict(compress=True, jitter_ms=700.0, seed=6),
                                     dict(form="positional", compress=True, bad_checksum=0.05, seed=4)])
def test_counts_equal_the_reference_on_fault_captures(tmp_path, variant):
    path = tmp_path / "d.pcap"
    generate_file(GenOptions(duration=40, **variant), path)
    runs, counted = compare(path)
    if variant.get("form") != "positional":
        assert runs > 50 and counted > 100


def test_a_value_with_no_type_keeps_its_variables_type_in_the_full_set_size(tmp_path):
    """Found by the property above: full sets, a bare N0, a full set, then a frame giving
    AutoGpsLat with no T (and a field X): the full set it stands for still holds AutoGpsLat's
    ``|T2`` (the table keeps the variable's type), on the reference path as in the counts mode
    (the reference's running size dropped the three bytes)."""
    full = b"[:AB|N0|T2|QAutoGpsLat|D1.5|T2|QAutoGpsLon|D1.5|T4|QMode|Don|T0|QCount|D0|C45]\r\n"
    untyped = b"[:AB|N0|QAutoGpsLat|D1.5|X1|C80]\r\n"
    frames = [full, full, b"[:AB|N0|C76]\r\n", full, untyped]
    dgs = [(1_767_268_800_200_000_000 + i * 200_000_000, f) for i, f in enumerate(frames)]
    path = write_capture(tmp_path / "untyped.pcap", dgs)
    compare(path)
    want = sum(len(full) for _ in frames)  # every frame stands for the same full set
    assert capture_stats(path, BEACON_VARIABLES).to_dict()["compression"]["full_bytes"] == want
