"""Issue 44's memory patterns: input that repeats itself (the same declaration before every data
frame, new layouts each sent twice, good frames one byte a record, many queriers each waiting on
many names, many serial interfaces, many small captures) must cost memory for what it says, once.

Each ``make_*(n, tmp)`` writes its input of size n into ``tmp`` and returns the command line (the
shape ``scaling.measure`` and ``check_scaling`` take). :func:`check_memory` runs a pattern at N
and 4N, each in a fresh process (peak RSS and CPU time from ``getrusage(RUSAGE_CHILDREN)``), and
fails when the 4N run's peak memory is more than twice the N run's plus ``slack_kb`` (50 MB in
``make fuzz``), or its CPU time beyond start-up more than 8 times the N run's. No wall clock.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

FUZZ = Path(__file__).resolve().parent
TESTS = FUZZ.parent
for _p in (FUZZ, TESTS):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from scaling import TIME_LIMIT, Run, ScalingError, measure  # noqa: E402
from scaling_python import T0, write, write_serial  # noqa: E402, F401 (write_serial: scaling_memory.py)

import tshark_util as tu  # noqa: E402
from sharedlink.capture.pcapio import LINKTYPE_USER0, PcapngWriter  # noqa: E402
from sharedlink.capture.serial_format import DIR_OUT  # noqa: E402

REPO = TESTS.parent
CLI = [sys.executable, "-m", "sharedlink"]
STEP = 10_000_000
#: the slack of the memory rule in ``make fuzz``: 4N may take twice N's peak plus this
SLACK_KB = 50 * 1024


def frame(body: str) -> bytes:
    """``[:<body>|C<xx>]`` CR LF with the right checksum (the bytes from ':' through 'C')."""
    head = f"[:{body}|C".encode("latin-1")
    return head + b"%02X]\r\n" % (sum(head[1:]) % 256)


def write_udp(path: Path, payloads: Sequence[bytes | tuple[int, bytes]]) -> Path:
    """Each payload a UDP datagram 10 ms after the previous (``scaling_python.write``);
    ``(sport, payload)`` picks the sender's port (a querier or conversation each)."""
    return write(path, payloads, step=STEP, src="10.0.0.2")


def write_interfaces(path: Path, chunks: Sequence[tuple[int, bytes]], interfaces: int) -> Path:
    """A serial pcapng with ``interfaces`` USER0 interfaces, records ``(interface, bytes)``
    interleaved in the given order, all outbound."""
    with open(path, "wb") as fh:
        w = PcapngWriter(fh, LINKTYPE_USER0)
        for _ in range(interfaces - 1):
            fh.write(w.interface(LINKTYPE_USER0))
        for i, (iface, data) in enumerate(chunks):
            fh.write(w.record(T0 + i * 1_000_000, data, DIR_OUT, iface))
    return path


# --- the patterns (payloads of size n) ------------------------------------------------------------


def repeated_declaration(n: int) -> list[bytes]:
    """The same short declaration of 1,001 slots before every data frame (25 bytes): issue 44
    measured about 30 KB kept per declaration in tshark (a copy of the list per switch)."""
    decl = frame("AB|N1000|T0|Qx")
    return [p for i in range(n) for p in (decl, frame(f"AB|N0|D{i}"))]


SUBSET_NAMES = [f"v{k}" for k in range(24)]


def new_layouts(n: int) -> list[bytes]:
    """One frame with 24 names, then n named layouts of 4 of them (each new, all known), each sent
    twice: a direction's subset cache kept every layout alive after the layout cache dropped it."""
    from itertools import combinations

    out = [frame("AB|N0|" + "|".join(f"T4|Q{nm}|D0" for nm in SUBSET_NAMES))]
    for i, combo in zip(range(n), combinations(SUBSET_NAMES, 4)):
        f = frame("AB|N0|" + "|".join(f"T4|Q{nm}|D{i % 10}" for nm in combo))
        out += [f, f]
    return out


def bytewise_frames(n: int) -> list[bytes]:
    """n good SharedLink frames sent one byte a serial record (serial.lua's reassembly state)."""
    return [bytes([b]) for i in range(n) for b in frame(f"AB|N0|D{i % 1000}|D7")]


def interleaved_interfaces(n: int, interfaces: int = 2) -> list[tuple[int, bytes]]:
    """n good frames on each of ``interfaces`` serial interfaces, their records interleaved (each
    frame in three records, so that no record holds a whole frame)."""
    out: list[tuple[int, bytes]] = []
    for i in range(n):
        parts = {k: frame(f"AB|N0|D{i}|D{k}") for k in range(interfaces)}
        for cut in range(3):
            for k, f in parts.items():
                third = (len(f) + 2) // 3
                out.append((k, f[cut * third:(cut + 1) * third]))
    return out


def many_interfaces(n: int) -> list[tuple[int, bytes]]:
    """n serial interfaces, each sending 3 whole frames a record, round robin (nothing held: the
    splitter walked every interface's reader about every 64 records, quadratic in interfaces)."""
    return [(i, frame(f"AB|N0|D{i}|D{r}")) for r in range(3) for i in range(n)]


def many_queriers(n: int) -> list[bytes | tuple[int, bytes]]:
    """n queriers (a source port each), each asking for 256 names no one answers."""
    return [(1024 + i, frame("AB|" + "|".join(f"Qq{k}" for k in range(256)))) for i in range(n)]


# --- commands -------------------------------------------------------------------------------------


def tshark(cap: Path, *args: str, serial: bool = False) -> list[str]:
    scripts = [REPO / "dissector" / "sharedlink.lua"] + ([REPO / "dissector" / "serial.lua"] if serial else [])
    return [*tu.TSHARK_CMD, "-n", *[a for s in scripts for a in ("-X", f"lua_script:{s}")], "-r", str(cap), *args]


def make_tshark(pattern: Callable[[int], Sequence], *args: str,
                writer: Callable[[Path, Sequence], Path] = write_udp) -> Callable[[int, Path], list[str]]:
    def make(n: int, tmp: Path) -> list[str]:
        serial = writer is not write_udp
        cap = writer(tmp / f"{pattern.__name__}-{n}.{'pcapng' if serial else 'pcap'}", pattern(n))
        return tshark(cap, *args, serial=serial)

    return make


def make_cli(pattern: Callable[[int], Sequence], *command: str,
             writer: Callable[[Path, Sequence], Path] = write_udp) -> Callable[[int, Path], list[str]]:
    """``sharedlink COMMAND ARGS`` on the pattern written at size n (``{}``: the capture; a word
    starting ``{out}``: a file in ``tmp``, the rest its suffix)."""

    def make(n: int, tmp: Path) -> list[str]:
        suffix = "pcap" if writer is write_udp else "pcapng"
        cap = writer(tmp / f"{pattern.__name__}-{n}.{suffix}", pattern(n))
        out = tmp / f"{pattern.__name__}-{n}-out"
        return [*CLI, *(str(cap) if a == "{}" else f"{out}{a[5:]}" if a.startswith("{out}") else a
                        for a in command)]

    return make


def make_ingest(n: int, tmp: Path) -> list[str]:
    """``sharedlink ingest`` of n small captures (one frame each) into a fresh dataset."""
    src = tmp / f"ingest-src-{n}"
    src.mkdir(exist_ok=True)
    for i in range(n):
        p = src / f"c{i:06d}.pcap"
        if not p.exists():
            write_udp(p, [frame(f"AB|N0|T2|QLat|D{i}.5|T2|QLon|D1.5")])
    out = tmp / f"ingest-out-{n}"
    if out.exists():
        import shutil

        shutil.rmtree(out)
    return [*CLI, "ingest", str(src), "-o", str(out)]


def serial_interfaces(pattern: Callable[[int], Sequence[tuple[int, bytes]]]) -> Callable[[Path, Sequence], Path]:
    def writer(path: Path, chunks: Sequence[tuple[int, bytes]]) -> Path:
        return write_interfaces(path, chunks, max(k for k, _ in chunks) + 1)

    writer.__name__ = f"interfaces_{pattern.__name__}"
    return writer


# --- the rule -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MemoryReport:
    n: int
    base: Run
    small: Run
    big: Run

    def __str__(self) -> str:
        def run(r: Run) -> str:
            return f"{r.cpu_seconds:.2f} s CPU, {r.peak_kb / 1024:.1f} MB"

        return f"N={self.n}: {run(self.small)}; 4N: {run(self.big)}; baseline {run(self.base)}"


def check_memory(make: Callable[[int, Path], Sequence[str]], n: int, tmp: Path, *,
                 slack_kb: int = SLACK_KB, beyond_start: bool = False, time_limit: float = TIME_LIMIT,
                 min_seconds: float = 0.25, env: Mapping[str, str] | None = None, **_: object) -> MemoryReport:
    """Raise ScalingError when the pattern at 4N takes more than twice N's peak memory plus
    ``slack_kb``, or more than ``time_limit`` times N's CPU time beyond a size-1 baseline (a
    failure is measured once more: the machine may be busy). ``beyond_start``: the peaks are
    taken beyond the baseline's (the fast form in ``make test-long``, whose sizes are too small for a
    leak to show against tshark's 150 MB start-up)."""
    tmp.mkdir(parents=True, exist_ok=True)
    cmds = {size: list(make(size, tmp)) for size in (1, n, 4 * n)}
    report = None
    for _attempt in range(2):
        base, small, big = (measure(cmds[k], env=env) for k in (1, n, 4 * n))
        report = MemoryReport(n, base, small, big)
        m0 = base.peak_kb if beyond_start else 0
        dt = max(small.cpu_seconds - base.cpu_seconds, min_seconds)
        if (big.peak_kb - m0 <= 2 * (small.peak_kb - m0) + slack_kb
                and big.cpu_seconds - base.cpu_seconds <= time_limit * dt):
            return report
    raise ScalingError(f"memory or time not bounded (4N at most 2x N + {slack_kb // 1024} MB"
                       f"{' beyond start-up' if beyond_start else ''}, {time_limit:.0f}x CPU): {report}\n"
                       f"command: {' '.join(cmds[4 * n])}")


def many_directions(n: int) -> list[bytes | tuple[int, bytes]]:
    """n directions (a source port each), one named frame of 2 values each."""
    return [(1024 + i % 60000, frame(f"{'ABCDEFGHIJ'[i // 60000]}B|N0|T2|QLat|D1.5|T2|QLon|D{i}")) for i in range(n)]


def many_names(n: int) -> list[bytes]:
    """One direction, each frame two names never sent before (past max_names, 4,096: dropped)."""
    return [frame(f"AB|N0|T4|Qa{i}|Dx|T4|Qb{i}|Dy") for i in range(n)]
