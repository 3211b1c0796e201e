"""The sharedlink.lua scaling patterns of issue 31 for ``make fuzz`` (scripts/fuzz.py, stage 5
reads every ``tests/fuzz/scaling_*.py`` with a PATTERNS table): the patterns (defined here:
``LUA_PATTERNS``, which ``test_scaling_sharedlink.py`` runs at its N), here at 4 times that N.
Memory may grow 5x, time ``scaling.TIME_LIMIT`` (8x)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import tshark_util as tu
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter

T0_NS = 1_767_268_800 * 1_000_000_000


def frame(body: str) -> bytes:
    """``[:<body>|C<xx>]`` CR LF with the right checksum (the bytes from ':' through 'C')."""
    head = f"[:{body}|C".encode("latin-1")
    return head + b"%02X]\r\n" % (sum(head[1:]) % 256)


def write(path: Path, payloads: Sequence[bytes]) -> Path:
    b = UdpBuilder("10.0.0.2", "10.0.0.255", 7013, 7013)
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for i, p in enumerate(payloads):
            w.write(T0_NS + i * 10_000_000, b.frame(p, i + 1))
    return path


def command(cap: Path, *args: str) -> list[str]:
    return [*tu.TSHARK_CMD, "-n", "-X", f"lua_script:{tu.DISSECTOR}", "-r", str(cap), *args]


def new_names(n: int) -> list[bytes]:
    """Every frame sends two names never sent before (and one old one): a copy of the carried
    names per frame would grow with the frame count."""
    return [frame(f"AB|N0|T4|Qa{i}|Dx|T4|Qb{i}|Dy|T4|Qold|D{i}") for i in range(n)]


def alternating_declarations(n: int) -> list[bytes]:
    """Declarations alternating with positional frames: a new list in use every other frame."""
    out = []
    for i in range(n):
        out.append(frame(f"AB|N0|T2|QLat{i % 7}|T2|QLon{i % 5}") if i % 2 == 0 else frame(f"AB|N0|D{i}|D{i + 1}"))
    return out


def far_slot(n: int) -> list[bytes]:
    """One positional frame at a huge slot, then frames with one value each."""
    return [frame("AB|N2147483646|D1")] + [frame(f"AB|N0|D{i}") for i in range(n)]


#: name -> (frames of size n, n in make test-long, tshark options)
LUA_PATTERNS: dict[str, tuple[Callable[[int], list[bytes]], int, tuple[str, ...]]] = {
    # with the default limits, as users run it (names stop at max_names, 4096, after ~2k frames).
    # Measured 3.8-4.3x (one pass) and 4.1-4.9x (-2) on a loaded machine: the journal keeps a Lua
    # string per carried value, and Wireshark's collections of the Lua heap grow with it
    "new-names": (new_names, 2000, ()),
    "new-names-2": (new_names, 2000, ("-2",)),
    "alternating-declarations-2": (alternating_declarations, 4000, ("-2",)),
    "far-slot": (far_slot, 4000, ()),
    "far-slot-2": (far_slot, 4000, ("-2",)),
}



def _make(name: str) -> Callable[[int, Path], list[str]]:
    gen, _n, args = LUA_PATTERNS[name]

    def make(size: int, tmp: Path) -> list[str]:
        return command(write(tmp / f"{name}-{size}.pcap", gen(size)), *args)

    return make


# name -> (make, n in make test-long, n in make fuzz, growth limit)
PATTERNS: dict[str, tuple[Callable[[int, Path], list[str]], int, int, float]] = {
    name: (_make(name), n, 4 * n, 5.0)
    for name, (_gen, n, _args) in LUA_PATTERNS.items()
}
