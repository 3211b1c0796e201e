"""Builders shared by the decoding-core tests (test_core, test_core_columns, test_core_changes):
hypothesis streams of datagrams built to catch a wrong reuse of what the fast path learnt, the
pcap writer for them, and the shared vectors as captures with their variable lists."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest
from hypothesis import strategies as st
from sl_vectors import write_stream

from sharedlink.analysis.decode import Decoded, ReferenceDecoder
from sharedlink.analysis.stats import CaptureStats
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.capture.stream import StreamFrame, iter_frames
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named, encode_positional
from sharedlink.protocols.state import BEACON_VARIABLES, parse_variables

NAMES = ("Lat", "Lon", "Head", "Vel")
VALUES = ("1", "2", "2.5", "-3", "10")  # few values: unchanged and carried values are the rule
# what a datagram's frame is: mostly a named frame the fast path takes, then what can change a
# value, a type or the names behind its back ("odd": a value the fast pattern does not take)
KINDS = ("named", "named", "named", "named", "bad", "reply", "declaration", "positional", "odd", "query")


def bad_checksum(raw: bytes) -> bytes:
    """The same frame with a wrong checksum."""
    return raw[:-5] + (b"00" if raw[-5:-3] != b"00" else b"01") + raw[-3:]


@st.composite
def reply(draw, src: str, dst: str, names: Sequence[str], values: Sequence[str]) -> bytes:
    """A reply (``R`` and a ``D``) of one of ``names``."""
    return build_frame(Frame(dst, src, (Field("R", draw(st.sampled_from(names))), Field("D", draw(st.sampled_from(values))))))


@st.composite
def declaration(draw, src: str, dst: str, names: Sequence[str]) -> bytes:
    """A declaration of one to four of ``names`` (doubles)."""
    fields = [Field("N", "0")]
    for n in draw(st.lists(st.sampled_from(names), unique=True, min_size=1, max_size=4)):
        fields += [Field("T", "2"), Field("Q", n)]
    return build_frame(Frame(dst, src, tuple(fields)))


@st.composite
def positional(draw, src: str, dst: str, values: Sequence[str]) -> bytes:
    """A positional frame of one to four slots (a slot left empty: carried)."""
    return encode_positional(dst, src, draw(st.lists(st.one_of(st.none(), st.sampled_from(values)), min_size=1,
                                                     max_size=4)))


@st.composite
def frames(draw, src: str, dst: str, values: tuple[str, ...] = VALUES, kinds: tuple[str, ...] = KINDS) -> bytes:
    """One frame of a kind drawn from ``kinds`` ("long": a named frame of type-0 values)."""
    kind = draw(st.sampled_from(kinds))
    if kind in ("named", "bad", "long"):
        names = draw(st.lists(st.sampled_from(NAMES), unique=True, max_size=4))
        raw = encode_named(dst, src, [(n, 0 if kind == "long" else 2, draw(st.sampled_from(values))) for n in names])
        return bad_checksum(raw) if kind == "bad" else raw
    if kind == "reply":
        return draw(reply(src, dst, NAMES, values))
    if kind == "query":
        return build_frame(Frame(dst, src, (Field("Q", draw(st.sampled_from(NAMES))),)))
    if kind == "declaration":
        return draw(declaration(src, dst, NAMES))
    if kind == "positional":
        return draw(positional(src, dst, values))
    assert kind == "odd", kind
    return encode_named(dst, src, [(draw(st.sampled_from(NAMES)), 4, draw(st.sampled_from(values)) + " x")])


@st.composite
def streams(draw, max_datagrams: int = 40, values: tuple[str, ...] = VALUES, kinds: tuple[str, ...] = KINDS,
            two_in: int = 5) -> list[tuple[int, int, bytes]]:
    """(sender, ts_ns, payload): mostly one frame a datagram, two frames in one of ``two_in``."""
    out = []
    ts = 1_700_000_000 * 10**9
    for _ in range(draw(st.integers(1, max_datagrams))):
        sender = draw(st.integers(0, 2))  # two conversations of B>A, and one of C>A
        src = "C" if sender == 2 else "B"
        ts += draw(st.sampled_from((200_000_000, 200_000_000, 1_700_000_000)))
        payload = draw(frames(src, "A", values, kinds))
        if draw(st.integers(0, two_in - 1)) == 0:
            payload += draw(frames(src, "A", values, kinds))  # two frames in one datagram
        out.append((sender, ts, payload))
    return out


@st.composite
def positional_streams(draw) -> list[tuple[int, int, bytes]]:
    """Mostly positional frames of a few slot counts (the fast path takes a count its direction's
    last reference-path frame had), with what can move the slots' names or values between them:
    declarations, named frames, two frames in a datagram, bad checksums."""
    out = []
    ts = 1_700_000_000 * 10**9
    sizes = draw(st.lists(st.integers(1, 5), min_size=1, max_size=2))
    for _ in range(draw(st.integers(1, 40))):
        sender = draw(st.integers(0, 1))
        ts += draw(st.sampled_from((200_000_000, 200_000_000, 1_700_000_000)))
        n = draw(st.sampled_from(sizes))
        texts = [draw(st.one_of(st.none(), st.sampled_from(VALUES))) for _ in range(n)]
        payload = encode_positional("A", "B", texts)
        what = draw(st.integers(0, 9))
        if what == 0:
            payload += draw(frames("B", "A"))  # a second frame: the reference path
        elif what == 1:
            payload = draw(frames("B", "A"))  # a declaration, a named frame, a reply...
        elif what == 2:
            payload = bad_checksum(payload)
        out.append((sender, ts, payload))
    return out


def write_udp(path: Path, stream: list[tuple[int, int, bytes]]) -> Path:
    """A pcap of the stream's datagrams, sender i from 10.0.0.(i+1) to 10.0.0.9, port 7013."""
    senders = [UdpBuilder(f"10.0.0.{i + 1}", "10.0.0.9", 7013, 7013) for i in range(3)]
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for i, (sender, ts, payload) in enumerate(stream):
            w.write(ts, senders[sender].frame(payload, i + 1))
    return path


def one_sender(*payloads: bytes, sender: int = 0) -> list[tuple[int, int, bytes]]:
    """The payloads as datagrams of one sender, 200 ms apart."""
    return [(sender, 10**18 + i * 200_000_000, p) for i, p in enumerate(payloads)]


def vector_capture(stream: dict, tmp_path: Path) -> tuple[Path, Sequence[tuple[str, int | None]]]:
    """A shared vector's stream as a capture (pcapng for serial), with its variable list; skips
    a per-pair list (B>A: ...), which only issue 29's parser reads."""
    ext = "pcapng" if stream.get("transport") == "serial" else "pcap"
    path = write_stream(stream, tmp_path / f"s.{ext}")
    try:
        variables = parse_variables(stream["variables"]) if stream.get("variables") else BEACON_VARIABLES
    except ValueError:
        pytest.skip("a variable list the decoders do not take yet")
    return path, variables


def reference_items(dec: ReferenceDecoder, path: Path) -> Iterator[Decoded | StreamFrame | tuple[int, int]]:
    """:func:`iter_frames`' items through the plain decoder ``dec``: each frame decoded, the bytes
    that hold none cut into malformed frames and noise (:meth:`ReferenceDecoder.unframed`, as the
    core cuts them), other records as they come."""
    for item in iter_frames(path):
        if isinstance(item, StreamFrame):
            if item.frame is not None:
                yield dec.decode(item)
            else:
                yield from dec.unframed(item)
        else:
            yield item


def stats_by_reference(path: Path, variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES) -> CaptureStats:
    """``stats`` the plain way: every frame through ReferenceDecoder and CaptureStats.add."""
    st_ = CaptureStats(path=str(path))
    dec = ReferenceDecoder(variables, carried=False)
    for item in iter_frames(path):
        if isinstance(item, StreamFrame) and item.frame is not None:
            st_.add(dec.decode(item))
        elif isinstance(item, tuple):
            st_.other_records += 1
        else:
            st_.add_unframed(item)
    return st_


def spy_runs(dec: object, method: str) -> list[int]:
    """Wraps ``dec``'s run taker ``method`` (``column_run``, ``count_run``): the list it returns
    gets the number of frames of each run taken."""
    run = getattr(dec, method)
    took: list[int] = []

    def spy(*args):
        r = run(*args)
        if r is not None:
            took.append(r[2])
        return r

    setattr(dec, method, spy)
    return took
