"""Issue 31's patterns for the Python commands, for ``make fuzz`` (scripts/fuzz.py's scaling
stage): each pattern (defined here, and checked by test_python_scaling.py) written at its make-fuzz size N and 4N and run as
the ``sharedlink`` command a user runs (a fresh process; CPU time and peak RSS beyond a one-frame
baseline, ``scaling.check_scaling``). test_python_scaling.py checks the same patterns in-process
at the smaller sizes in ``make test-long`` (the ``n in make test-long`` column is those sizes, for the record)."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from sl_robots import write_serial as write_records  # (tests/ is on sys.path: conftest.py, scripts/fuzz.py)

from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.capture.serial_format import DIR_OUT
from sharedlink.protocols.codec import Field, Frame, build_frame, encode_named, encode_positional
from sharedlink.protocols.limits import MAX_HELD_BYTES, MAX_SLOTS

T0 = 1_700_000_000 * 10**9
STEP = 200_000_000


def write(path: Path, payloads: Sequence[bytes | tuple[int, bytes]], step: int = STEP,
          src: str = "10.0.0.1") -> Path:
    """Each payload a UDP datagram from ``src`` to 10.0.0.9 port 7013, ``step`` ns (200 ms)
    after the previous; ``(sport, payload)`` picks the sender's port (a conversation each). The
    one UDP capture builder of the scaling patterns (memory_patterns.py writes with it too)."""
    builders: dict[int, UdpBuilder] = {}
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for i, item in enumerate(payloads):
            sport, payload = item if isinstance(item, tuple) else (7013, item)
            b = builders.get(sport)
            if b is None:
                b = builders[sport] = UdpBuilder(src, "10.0.0.9", sport, 7013)
            w.write(T0 + i * step, b.frame(payload, i + 1))
    return path


#: the directions new_names takes turns in: at make fuzz's 4N = 48000 frames each holds 16001 names
#: (past MAX_NAMES: dropped and counted), at make test's 4N = 4000 frames 1335 (every name stored)
PAIRS = (("A", "B"), ("C", "D"), ("E", "F"))


def new_names(n: int) -> list[bytes]:
    """Every frame sends one name never sent before (and the first name again), the directions
    of :data:`PAIRS` in turn."""
    return [encode_named(*PAIRS[i % len(PAIRS)], [("First", 2, "1"), (f"Name{i}", 2, str(i))]) for i in range(n)]


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


def write_serial(path: Path, chunks: Sequence[bytes]) -> Path:
    """A serial capture (pcapng, USER0), one outbound record per chunk, 1 ms apart from T0 (the
    tests' one writer, sl_robots.write_serial)."""
    return write_records(path, [(c, DIR_OUT) for c in chunks], step_ns=1_000_000)


def sl_unterminated(n: int) -> list[bytes]:
    """A SharedLink frame that never ends, sent one byte a record (serial.lua and the Python
    deframer rescanned the held bytes each record: 4k to 16k records 0.2 s to 3.2 s here)."""
    return [b"[:AB|N0|D"] + [b"7"] * n


def bb_unterminated(n: int) -> list[bytes]:
    """The same for a blackboard message (no CR ever)."""
    return [b":031F00"] + [b"0"] * n


def past_the_limit(n: int) -> list[bytes]:
    """Unfinished frames of 1.5 MAX_HELD_BYTES each, 1 KB records, a good frame after each."""
    chunk = b"7" * 1024
    good = encode_positional("A", "B", ["1"])
    out: list[bytes] = []
    for _ in range(max(1, n // 100)):
        out += [b"[:AB|N0|D"] + [chunk] * (3 * MAX_HELD_BYTES // 2048) + [good]
    return out


CLI = [sys.executable, "-m", "sharedlink"]


def make(pattern: Callable[[int], Sequence], *command: str,
         writer: Callable[[Path, Sequence], Path] = write) -> Callable[[int, Path], list[str]]:
    """``sharedlink COMMAND CAPTURE ARGS`` on the pattern written at size n (``{}`` in the
    arguments is the capture)."""

    def run(n: int, tmp: Path) -> list[str]:
        suffix = ".pcapng" if writer is write_serial else ".pcap"
        path = writer(tmp / f"{pattern.__name__}-{n}{suffix}", pattern(n))
        return [*CLI, *(str(path) if a == "{}" else a for a in command)]

    return run


# name -> (make, n in make test-long, n in make fuzz, growth limit)
PATTERNS: dict[str, tuple[Callable[[int, Path], list[str]], int, int, float]] = {
    # 4N = 48000 frames: 16000 new names per direction, past MAX_NAMES (dropped and counted)
    "stats-new-names": (make(new_names, "stats", "{}"), 1000, 12000, 5.0),
    "export-new-names": (make(new_names, "export", "{}", "--format", "jsonl", "--changes", "-o", "-"), 1000, 12000, 5.0),
    "diff-new-names": (make(new_names, "diff", "{}", "{}"), 1000, 12000, 5.0),
    "stats-bad-checksums": (make(bad_checksums, "stats", "{}"), 300, 1200, 5.0),
    "stats-replies-big-list": (make(replies_in_a_big_list, "stats", "{}"), 8000, 32000, 5.0),
    "stats-conversations": (make(conversations, "stats", "{}"), 1000, 10000, 5.0),
    # three MCAP channels a conversation: 4N = 20000 stays under MCAP's 65535 channels (past them
    # every message is an error line: test_mcap_of_more_conversations..., an xfail)
    "mcap-conversations": (make(conversations, "export", "{}", "--format", "mcap", "-o", "/dev/null"), 2000, 5000, 5.0),
    "diff-conversations": (make(conversations, "diff", "{}", "{}"), 1000, 10000, 5.0),
    "stats-serial-unterminated": (make(sl_unterminated, "stats", "{}", writer=write_serial), 4000, 15000, 5.0),
    "stats-serial-past-the-limit": (make(past_the_limit, "stats", "{}", writer=write_serial), 200, 4000, 5.0),
}
