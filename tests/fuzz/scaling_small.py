"""Issue 31's patterns for p2os.lua, blackboard.lua and serial.lua, each written at a size n, and
the tshark command that decodes them (those three dissectors loaded, as in a plugin folder; not
sharedlink.lua, so its own costs do not blur these). Used by test_scaling_small.py at sizes that
keep each check to a few seconds, and by scripts/fuzz.py (``make fuzz``) at bigger ones.

Every ``make_*(n, tmp)`` writes its input into ``tmp`` and returns the command line, the shape
``scaling.check_scaling`` takes."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]
if str(TESTS) not in sys.path:
    sys.path.insert(0, str(TESTS))

from sl_robots import write_serial  # noqa: E402

import tshark_util as tu  # noqa: E402
from sharedlink.capture.packets import TcpConversation, UdpBuilder  # noqa: E402
from sharedlink.capture.pcapio import LINKTYPE_ETHERNET, PcapWriter  # noqa: E402
from sharedlink.capture.serial_format import DIR_OUT  # noqa: E402
from sharedlink.protocols import blackboard as bbc  # noqa: E402

REPO = TESTS.parent
SCRIPTS = [REPO / "dissector" / n for n in ("p2os.lua", "blackboard.lua", "serial.lua")]
T0 = 1_700_000_000 * 10**9
# a set message with a good checksum, as a master sends it
SET = bbc.build_message(bbc.SetMessage(0x1F00, 1, bytes([1, 2, 3])))


def tshark_command(capture: Path, *args: str, scripts: Sequence[Path] = SCRIPTS) -> list[str]:
    """tshark reading ``capture`` with ``scripts`` loaded (summary lines; ``args`` added)."""
    cmd = [*tu.TSHARK_CMD, "-n"] + [a for s in scripts for a in ("-X", f"lua_script:{s}")]
    return [*cmd, "-r", str(capture), *args]


def env() -> dict[str, str]:
    """The environment tshark_util runs tshark in (no personal configuration)."""
    return tu._clean_env()


def write_bb_endpoints(path: Path, n: int) -> None:
    """n blackboard set messages over UDP, each from an endpoint of its own, none answered:
    every one waits for its answer (the pending table holds n entries)."""
    with open(path, "wb") as fh:
        w = PcapWriter(fh, LINKTYPE_ETHERNET)
        for i in range(n):
            src = "10.%d.%d.%d" % (1 + i // 65536, (i // 256) % 256, i % 256)
            b = UdpBuilder(src, "10.0.0.1", 7200, 7100)
            w.write(T0 + i * 1_000_000, b.frame(SET, i & 0xFFFF))


def write_bb_tcp_no_cr(path: Path, n: int, segment: int = 256) -> None:
    """One blackboard message over TCP that never ends (no CR): ':' then n hex digits in
    segments of ``segment`` bytes."""
    conv = TcpConversation("10.0.0.2", 40000, "10.0.0.1", 7100)
    with open(path, "wb") as fh:
        w = PcapWriter(fh, LINKTYPE_ETHERNET)
        frames = list(conv.open())
        data = b":" + b"0" * n
        for i in range(0, len(data), segment):
            frames.append(conv.send(True, data[i:i + segment]))
        for k, f in enumerate(frames):
            w.write(T0 + k * 1_000_000, f)


def write_serial_unterminated(path: Path, n: int, start: bytes, filler: bytes) -> None:
    """A serial capture: ``start`` (a frame's first bytes) then n one-byte records of ``filler``
    that never finish the frame."""
    write_serial(path, [(start, DIR_OUT)] + [(filler, DIR_OUT)] * n, times=[T0 + i * 1000 for i in range(n + 1)])


def make_bb_endpoints(*args: str) -> Callable[[int, Path], list[str]]:
    """Every message stays pending (max_pending above any size used): the table grows with n,
    and every frame takes the same path (past the limit a frame would also carry an expert)."""

    def make(n: int, tmp: Path) -> list[str]:
        p = tmp / f"bb-endpoints-{n}.pcap"
        write_bb_endpoints(p, n)
        # (ff41cb3's dissectors, through SHAREDLINK_SCALING_SCRIPTS, have no such preference)
        limit = [] if os.environ.get("SHAREDLINK_SCALING_SCRIPTS") else ["-o", "blackboard.max_pending:1000000"]
        return tshark_command(p, "-o", "blackboard.udp_port:7100", *limit, *args)

    return make


def make_bb_tcp_no_cr(*args: str) -> Callable[[int, Path], list[str]]:
    def make(n: int, tmp: Path) -> list[str]:
        p = tmp / f"bb-tcp-no-cr-{n}.pcap"
        write_bb_tcp_no_cr(p, n)
        return tshark_command(p, "-o", "blackboard.tcp_port:7100", *args)

    return make


def make_serial_unterminated(protocol: str, *args: str) -> Callable[[int, Path], list[str]]:
    """``sharedlink``: "[:AB|" then "D" bytes (no "]"); ``blackboard``: ":" then "0" bytes (no CR)."""
    start, filler = {"sharedlink": (b"[:AB|", b"D"), "blackboard": (b":", b"0")}[protocol]

    def make(n: int, tmp: Path) -> list[str]:
        p = tmp / f"serial-{protocol}-{n}.pcapng"
        write_serial_unterminated(p, n, start, filler)
        return tshark_command(p, "-o", f"slserial.protocol:{protocol}", *args)

    return make


# name -> (make, n in make test-long, n in make fuzz, growth limit). The -2 run of many endpoints
# gets 6x: tshark itself, with no Lua at all, grows 5.9x from 12k to 48k distinct endpoints
# with -2 (its conversation and address tables), and ours measured 4.3x to 4.7x (ff41cb3: 58x);
# in make fuzz the endpoints stay near the sizes for the same reason (10k to 40k: 4.8x)
PATTERNS: dict[str, tuple[Callable[[int, Path], list[str]], int, int, float]] = {
    "blackboard-endpoints": (make_bb_endpoints(), 1500, 2500, 5.0),  # 2.5k to 10k: the sizes
    "blackboard-endpoints-2pass": (make_bb_endpoints("-2"), 2500, 5000, 6.0),
    "blackboard-tcp-no-cr": (make_bb_tcp_no_cr(), 16384, 65536, 5.0),
    "serial-sharedlink-unterminated": (make_serial_unterminated("sharedlink"), 2000, 16000, 5.0),
    "serial-blackboard-unterminated": (make_serial_unterminated("blackboard"), 2000, 16000, 5.0),
}

if os.environ.get("SHAREDLINK_SCALING_SCRIPTS"):  # another dissector folder (e.g. an old commit's)
    SCRIPTS[:] = [Path(os.environ["SHAREDLINK_SCALING_SCRIPTS"]) / s.name for s in SCRIPTS]
