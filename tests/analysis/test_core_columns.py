"""The decoding core's columns mode (``Decoder.capture(columns=True)``, what ``ingest`` reads)
against the plain reference decoder, row by row.

In columns mode the frames the fast path takes come as per-column lists (frame rows and value
rows, no Update, no Decoded), the tables brought up to date when a batch is handed over. Every
frame must give the rows the reference decoder's frame gives (its Updates with a text: name,
text, type, carried, changed; its number, time, conversation, letters, kind, checksum verdict,
late, bytes), in capture order, and the table as the reference leaves it after each direction's
last frame of a batch and after every frame decoded the other way (whose Updates, carried_from
included, show any table a batch left wrong). The streams mix fast frames with what changes a
value, a type or the names behind the fast path's back: two frames in a datagram, replies,
declarations, positional frames, bad checksums, values the fast pattern does not take, several
directions and conversations; then the fault captures and the shared vectors.
"""

from __future__ import annotations

from pathlib import Path

import core_streams
import pytest
from core_streams import reference_items, spy_runs, vector_capture, write_udp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sl_captures import captures, examples, write_capture
from sl_vectors import load_streams

from sharedlink.analysis.decode import Columns, Decoded, Decoder, ReferenceDecoder
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named
from sharedlink.protocols.state import BEACON_VARIABLES, VariableTable

VALUES = core_streams.VALUES + ("1e", "+.5")  # few values: unchanged and carried ones are the rule
KINDS = ("named", "named", "named", "named", "named", "bad", "reply", "declaration", "positional", "odd", "long")


def streams():
    """(sender, ts_ns, payload): mostly one named frame a datagram, sometimes two."""
    return core_streams.streams(values=VALUES, kinds=KINDS, two_in=6)


def _table(t: VariableTable) -> tuple:
    return ({n: (v.text, v.type_code, v.set_in, v.set_at) for n, v in t.vars.items()},
            (t.last_full_at, t.last_full_in, t.named, dict(t.sent_names), tuple(t.names), sorted(t.filled)))


def _decoded(d: Decoded) -> tuple:
    """(frame row, value rows, what else a Decoded says, the table after it)."""
    rows = [(u.name, u.text, u.type_code, u.carried, u.changed) for u in d.updates if u.text is not None]
    return ((d.number, d.ts_ns, d.conv, d.raw, d.src, d.dst, d.kind, d.checksum_ok, d.late), rows,
            (d.updates, d.shown, d.sync_gap_ns, d.response_to), _table(d.table))


def reference(path: Path, carried: bool = True, variables=BEACON_VARIABLES) -> list[tuple]:
    dec = ReferenceDecoder(variables, carried=carried)
    return [_decoded(d) for d in reference_items(dec, path) if isinstance(d, Decoded)]


def columns(path: Path, carried: bool = True, variables=BEACON_VARIABLES) -> tuple[list[tuple], int]:
    """The same tuples from the columns mode (None where a batch has no such thing: the rest of
    a Decoded, the table after a frame not its direction's last of the batch); frames batched."""
    dec = Decoder(variables, carried=carried)
    out: list[tuple] = []
    batched = 0
    for item in dec.capture(path, columns=True):
        if isinstance(item, Decoded):
            out.append(_decoded(item))
        elif isinstance(item, Columns):
            frames: list = [None] * item.frames
            for (conv, src, dst), c in item.dirs.items():
                n = len(c.number)
                assert (conv, src, dst) == (c.conv, c.src, c.dst) and n > 0
                assert [len(x) for x in (c.ordinal, c.ts_ns, c.raw, c.kind, c.late, c.nvalues)] == [n] * 6
                m = sum(c.nvalues)
                assert [len(x) for x in (c.name, c.text, c.type_code, c.carried, c.changed)] == [m] * 5
                at = 0
                for i, o in enumerate(c.ordinal):
                    k = c.nvalues[i]
                    rows = list(zip(c.name[at:at + k], c.text[at:at + k], c.type_code[at:at + k], c.carried[at:at + k],
                                    c.changed[at:at + k]))
                    at += k
                    assert frames[o] is None
                    frames[o] = ((c.number[i], c.ts_ns[i], conv, c.raw[i], src, dst, c.kind[i], True, c.late[i]), rows,
                                 None, _table(c.table) if i == n - 1 else None)
            assert None not in frames
            out += frames
            batched += item.frames
    return out, batched


def compare(path: Path, carried: bool = True, variables=BEACON_VARIABLES) -> int:
    """Columns and reference give the same rows and tables; returns the frames batched."""
    got, batched = columns(path, carried, variables)
    want = reference(path, carried, variables)
    assert len(got) == len(want)
    for i, (g, w) in enumerate(zip(got, want)):
        assert g[0] == w[0], i
        assert g[1] == w[1], (i, g[0])
        assert g[2] is None or g[2] == w[2], (i, g[0])
        assert g[3] is None or g[3] == w[3], (i, g[0])
    return batched


@settings(max_examples=examples(150), deadline=None, suppress_health_check=list(HealthCheck))
@given(streams(), st.booleans())
def test_columns_equal_the_reference_on_generated_streams(tmp_path_factory, stream, carried):
    compare(write_udp(tmp_path_factory.mktemp("col") / "s.pcap", stream), carried)


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(captures())
def test_columns_equal_the_reference_on_varied_captures(tmp_path_factory, dgs):
    compare(write_capture(tmp_path_factory.mktemp("var") / "x.pcap", dgs))


def test_a_reference_frame_between_batched_frames_changes_their_values(tmp_path):
    """A datagram of two frames (reference path) changes Lat between fast frames that carry
    it; a declaration renames; a bad checksum changes nothing: rows as the reference's."""
    b = lambda *kv: encode_named("A", "B", [(k, 2, v) for k, v in kv])  # noqa: E731
    stream = [b(("Lat", "1"), ("Lon", "2")), b(("Lat", "1"), ("Lon", "2")), b(("Lon", "3")), b(("Lon", "3")),
              b(("Lat", "5")) + b(("Lon", "4")), b(("Lon", "4")), b(("Lon", "5")), b(("Lat", "1"), ("Lon", "2")),
              b(("Lon", "9"))[:-5] + b"00]\r\n", b(("Lon", "6")),
              build_frame(Frame("A", "B", (Field("N", "0"), Field("T", "0"), Field("Q", "Lon")))), b(("Lon", "6"))]
    path = write_udp(tmp_path / "s.pcap", [(0, (i + 1) * 10**9, p) for i, p in enumerate(stream)])
    assert compare(path) >= 4


def test_a_reference_frame_changes_the_type_of_a_value_batched_frames_carry(tmp_path):
    """Lat becomes a long (a reference-path frame, a layout of its own) while fast frames of
    the Lon layout carry it: their Lat rows have the new type."""
    def b(*kv, t=2):
        return encode_named("A", "B", [(k, t, v) for k, v in kv])
    stream = [b(("Lat", "1"), ("Lon", "2")), b(("Lon", "3")), b(("Lon", "4")), b(("Lat", "7"), t=0), b(("Lon", "5")),
              b(("Lat", "8"), t=0), b(("Lon", "6")), b(("Lat", "2.5")), b(("Lon", "7"))]
    path = write_udp(tmp_path / "s.pcap", [(0, (i + 1) * 10**8, p) for i, p in enumerate(stream)])
    assert compare(path) >= 3


def test_runs_from_the_block_and_single_frames_in_one_batch(tmp_path):
    """Frames in table order go as runs straight from the pcap block (column_run), a layout in
    another order frame by frame (column), both in one batch of one direction: which frame last
    set each value (shown by the carried_from of the reference-path frames after) and the rows
    are the reference's."""
    b = lambda *kv: encode_named("A", "B", [(k, 2, v) for k, v in kv])  # noqa: E731
    stream = [b(("Lat", "1"), ("Lon", "2")), b(("Lat", "1"), ("Lon", "3")), b(("Lon", "4"), ("Lat", "2")),
              b(("Lon", "5"), ("Lat", "2")), b(("Lat", "7")), b(("Lon", "6")), b(("Lon", "7"), ("Lat", "3")),
              b(("Lat", "8")), b(("Lon", "9"))[:-5] + b"00]\r\n", b(("Lon", "9")) + b(("Lat", "9")),
              b(("Lat", "1"), ("Lon", "2")), b(("Lat", "2")),
              # a first value for a variable of the list (typed, no value yet), in table order
              b(("AutoGpsVel", "4"), ("Lat", "3")), b(("Lat", "4"), ("Lon", "3")), b(("Lat", "5"))]
    path = write_udp(tmp_path / "s.pcap", [(0, (i + 1) * 10**8, p) for i, p in enumerate(stream)])
    assert compare(path) >= 5
    dec = Decoder()
    took = spy_runs(dec, "column_run")
    for _item in dec.capture(path, columns=True):
        pass
    assert sum(took) >= 3 and dec.fast > sum(took)  # runs, and frames column() took


@pytest.mark.parametrize("stream", load_streams(), ids=lambda s: s["name"])
def test_columns_equal_the_reference_on_the_shared_vectors(tmp_path, stream):
    path, variables = vector_capture(stream, tmp_path)
    compare(path, variables=variables)


@pytest.mark.parametrize("variant", [dict(compress=True, bad_checksum=0.1, drop=0.3, jitter_ms=300.0, seed=2),
                                     dict(seed=3), dict(form="positional", compress=True, bad_checksum=0.05, seed=4)])
def test_columns_equal_the_reference_on_fault_captures(tmp_path, variant):
    path = tmp_path / "d.pcap"
    generate_file(GenOptions(duration=40, **variant), path)
    n = compare(path)
    assert n > 100 or variant.get("form") == "positional"


def test_one_mode_a_decoder(tmp_path: Path) -> None:
    """The changes-only mode's compiled layouts hold texts the columns mode moves: a Decoder
    refuses a second mode (capture in another mode, or compiled after a capture)."""
    path = tmp_path / "beacon.pcap"
    generate_file(GenOptions(frames=50, compress=True, seed=1), path)
    dec = Decoder()
    for _item in dec.capture(path, columns=True):
        pass
    for _item in dec.capture(path, columns=True):  # the same mode again: fine
        pass
    with pytest.raises(ValueError, match="columns mode"):
        dec.capture(path)
    with pytest.raises(ValueError, match="columns mode"):
        dec.compiled(("udp", "192.168.1.12", 7013, "255.255.255.255", 7013), "B", "A")
