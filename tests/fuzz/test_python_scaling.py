"""Hostile input against the Python decoders (issue 31): bounded memory, linear time, no traceback.

Each pattern is built at N and 4N (frames, names or conversations) and run in this process; the
test fails when the time or the peak memory (tracemalloc) of the 4N run is more than
:data:`GROWTH` (6) times the N run's (linear growth is 4x; quadratic 16x). Small absolute floors
keep timer noise on a busy machine out of the ratio. Past a bound of
``sharedlink.protocols.limits`` the input is dropped and counted, never allocated.
"""

from __future__ import annotations

import io
import subprocess
import sys
import time
import tracemalloc
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

from sharedlink.analysis.decode import Decoded, iter_decoded
from sharedlink.analysis.diff import DiffOptions, diff_captures
from sharedlink.analysis.export import ExportOptions, export
from sharedlink.analysis.stats import capture_stats
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named, encode_positional
from sharedlink.protocols.limits import MAX_NAMES, MAX_SLOTS

#: the most the 4N run may cost against the N run (time and peak memory): linear is 4x, quadratic
#: 16x; "about 5x" with room for a shared machine's noise (linear runs measured 4.0x-4.7x here)
GROWTH = 6.0
T0 = 1_700_000_000 * 10**9
STEP = 200_000_000


# -- helpers ------------------------------------------------------------------------------------


def write(path: Path, payloads: Sequence[bytes | tuple[int, bytes]]) -> Path:
    """Each payload a UDP datagram 200 ms after the previous; ``(sport, payload)`` picks the
    sender's port (a conversation each)."""
    builders: dict[int, UdpBuilder] = {}
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for i, item in enumerate(payloads):
            sport, payload = item if isinstance(item, tuple) else (7013, item)
            b = builders.get(sport)
            if b is None:
                b = builders[sport] = UdpBuilder("10.0.0.1", "10.0.0.9", sport, 7013)
            w.write(T0 + i * STEP, b.frame(payload, i + 1))
    return path


def measure(fn: Callable[[], object]) -> tuple[float, int]:
    """(CPU seconds of this process, peak traced bytes) of ``fn()``: CPU time, not wall time, so
    that other processes on a shared machine (pytest's other worker) do not enter the ratio."""
    tracemalloc.start()
    t = time.process_time()
    try:
        fn()
    finally:
        elapsed = time.process_time() - t
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return elapsed, peak


def assert_linear(run: Callable[[Path], object], small: Path, big: Path, floor_s: float = 0.2,
                  floor_bytes: int = 4 << 20) -> None:
    """``run`` on the 4N capture costs at most GROWTH times what it costs on the N one."""
    run(small)  # warm up (imports, caches)
    # best of three each: a shared machine's load comes and goes
    (t1, m1), (t4, m4) = (min(measure(lambda p=p: run(p)) for _ in range(3)) for p in (small, big))
    assert t4 <= GROWTH * max(t1, floor_s), f"time {t1:.3f} s -> {t4:.3f} s at 4N"
    assert m4 <= GROWTH * max(m1, floor_bytes), f"peak memory {m1} -> {m4} bytes at 4N"


def stats(path: Path) -> object:
    return capture_stats(path)


def export_changes(path: Path) -> object:
    return export(path, io.StringIO(), ExportOptions(fmt="jsonl", changes=True))


def watch_decode(path: Path) -> object:
    """What ``watch`` does with each datagram (its decoder, as commands/watch.py makes it)."""
    from sharedlink.capture.packets import decode_packet
    from sharedlink.capture.pcapio import read_records
    from sharedlink.watch import FastDecoder, RawDatagram

    dec = FastDecoder(carried=False)
    n = 0
    for rec in read_records(path):
        dg = decode_packet(rec.linktype, rec.data)
        conv = (dg.proto, dg.src, dg.sport, dg.dst, dg.dport)
        for d in dec.datagram(RawDatagram(rec.number, rec.ts_ns, conv, dg.payload)):
            n += isinstance(d, Decoded) and len(d.changes())
    return n


def diff_self(path: Path) -> object:
    return diff_captures(path, path, DiffOptions(parallel=False))


# -- patterns -----------------------------------------------------------------------------------


def new_names(n: int) -> list[bytes]:
    """Every frame sends one name never sent before (and the first name again)."""
    return [encode_named("A", "B", [("First", 2, "1"), (f"Name{i}", 2, str(i))]) for i in range(n)]


def bad_checksums(n: int) -> list[bytes]:
    """A table of 300 positional names, then frames with a bad checksum (once deep-copied each)."""
    decl = build_frame(Frame("A", "B", (Field("N", "0"), *[f for i in range(300) for f in (Field("T", "0"),
                                                                                         Field("Q", f"v{i}"))])))
    good = encode_positional("A", "B", [str(i) for i in range(300)])
    bad = good[:-5] + (b"00" if good[-5:-3] != b"00" else b"01") + good[-3:]
    return [decl, good] + [bad] * n


def replies_in_a_big_list(n: int) -> list[bytes]:
    """A declared list of MAX_SLOTS names, then replies naming its last slot (``names.index``)."""
    decl = build_frame(Frame("A", "B", (Field("N", "0"), *[f for i in range(MAX_SLOTS) for f in (
        Field("T", "0"), Field("Q", f"v{i}"))])))
    return [decl] + [build_frame(Frame("A", "B", (Field("R", f"v{MAX_SLOTS - 1}"), Field("D", str(i)))))
                     for i in range(n)]


def conversations(n: int) -> list[tuple[int, bytes]]:
    """``n`` conversations (source ports), a full frame each, then one delta each."""
    full = encode_named("A", "B", [("AutoGpsLat", 2, "1.5"), ("AutoGpsLon", 2, "2.5")])
    delta = encode_named("A", "B", [("AutoGpsLat", 2, "1.6")])
    return [(10000 + i, full) for i in range(n)] + [(10000 + i, delta) for i in range(n)]


@pytest.mark.parametrize("run", [stats, export_changes, diff_self, watch_decode], ids=["stats", "export", "diff", "watch"])
def test_new_names_every_frame_cost_linear_time(tmp_path, run):
    small = write(tmp_path / "s.pcap", new_names(400))
    big = write(tmp_path / "b.pcap", new_names(1600))
    assert_linear(run, small, big)


@pytest.mark.parametrize("run", [stats, export_changes], ids=["stats", "export"])
def test_bad_checksum_frames_cost_what_they_hold(tmp_path, run):
    small = write(tmp_path / "s.pcap", bad_checksums(100))
    big = write(tmp_path / "b.pcap", bad_checksums(400))
    assert_linear(run, small, big)


def test_replies_in_a_big_list_cost_linear_time(tmp_path):
    small = write(tmp_path / "s.pcap", replies_in_a_big_list(1000))
    big = write(tmp_path / "b.pcap", replies_in_a_big_list(4000))
    assert_linear(stats, small, big)


@pytest.mark.parametrize("run", [stats, export_changes, diff_self], ids=["stats", "export", "diff"])
def test_many_conversations_cost_linear_time_and_memory(tmp_path, run):
    small = write(tmp_path / "s.pcap", conversations(1000))
    big = write(tmp_path / "b.pcap", conversations(4000))
    assert_linear(run, small, big)


# -- bounds ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [4_000_000, 2_000_000_000, 10**12])
def test_a_huge_declared_ordinal_is_dropped_not_allocated(tmp_path, n):
    """``[:AB|N<n>|T0|Qx|C..]``: once a list of n placeholder names (4e6: 17 s and 1.3 GB)."""
    payloads = [build_frame(Frame("A", "B", (Field("N", str(n)), Field("T", "0"), Field("Q", "x"))))] * 3
    payloads.append(encode_positional("A", "B", ["1", "2"], ordinal=n if n < 10**9 else 5))
    path = write(tmp_path / "o.pcap", payloads)
    t, peak = measure(lambda: capture_stats(path))
    st = capture_stats(path)
    assert st.frames == 4 and t < 2.0 and peak < 8 << 20, (t, peak)
    assert st.limits.slots + st.limits.numbers >= 3


def test_a_huge_positional_ordinal_is_dropped(tmp_path):
    """One ``N<n>|D1`` frame made every later frame of its direction build n names."""
    path = write(tmp_path / "p.pcap", [encode_positional("A", "B", ["1"], ordinal=2147483646 if i == 0 else 0)
                                       for i in range(50)])
    t, peak = measure(lambda: capture_stats(path))
    st = capture_stats(path)
    assert st.frames == 50 and st.limits.slots >= 1 and t < 2.0 and peak < 8 << 20, (t, peak)
    assert all(len(d.table.names) <= MAX_SLOTS for d in iter_decoded(path) if isinstance(d, Decoded))


def test_names_past_the_limit_are_counted_and_dropped(tmp_path):
    path = write(tmp_path / "n.pcap", [encode_named("A", "B", [(f"N{i}", 2, "1"), (f"M{i}", 2, "2")])
                                       for i in range(MAX_NAMES)])
    st = capture_stats(path)
    kept = {name for (_pair, name) in st.variables}
    # the direction's table holds at most MAX_NAMES (the a-priori list's names among them);
    # every name sent past that is counted, none is kept
    assert MAX_NAMES - 8 <= len(kept) < MAX_NAMES
    assert st.limits.names + len(kept) == 2 * MAX_NAMES


@pytest.mark.parametrize("command", [["stats"], ["stats", "--json"], ["export", "--format", "jsonl", "-o", "-"]])
def test_thousands_of_digits_are_a_count_not_a_traceback(tmp_path, command):
    digits = "7" * 5000
    path = write(tmp_path / "d.pcap", [
        build_frame(Frame("A", "B", (Field("N", digits), Field("D", "1")))),
        build_frame(Frame("A", "B", (Field("N", "0"), Field("T", digits), Field("Q", "x"), Field("D", "1")))),
        build_frame(Frame("A", "B", (Field("N", "0"), Field("T", "0"), Field("Q", "y"), Field("D", digits)))),
        encode_named("A", "B", [("z", 0, digits)]),
    ])
    cli = [sys.executable, "-m", "sharedlink", command[0], str(path), *command[1:]]
    r = subprocess.run(cli, capture_output=True, text=True, timeout=60)
    assert "Traceback" not in r.stderr and r.returncode == 0, r.stderr
    assert capture_stats(path).limits.numbers == 2
