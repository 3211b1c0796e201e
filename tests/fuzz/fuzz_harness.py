"""Fuzzing tshark with our Lua dissectors, the way Wireshark's own ``tools/fuzz-test.sh`` does.

Used by ``tests/fuzz/test_fuzz_short.py`` (a short run inside ``make test``) and ``scripts/fuzz.py``
(``make fuzz``, the long run). Every tshark run:

- gets its command from ``$SHAREDLINK_TSHARK`` (a shell-split command prefix, default
  ``tshark``; ``scripts/tshark-in-rootfs SUITE`` for the newer releases) and loads every
  ``dissector/*.lua`` with ``-X lua_script:``;
- runs as ``tshark -nVxr FILE`` under CPU and memory limits (``setrlimit``, what ``ulimit -t -v``
  sets) and a wall-clock limit, with Wireshark's fuzzing environment (strict wmem allocator,
  abort on a dissector bug or too many tree items, glibc heap checks);
- fails on a crash (a signal or a non-zero exit), any ``Lua Error`` in the tree
  (``_ws.lua.error``), any unexpected line on stderr (Lua messages included), a run past a
  limit, and a run in which our dissectors decoded nothing (they did not load).

Inputs: editcap ``-E`` mutations of the sample captures (link, IP and UDP/TCP headers kept with
``-o``), every prefix of every sample frame, random and protocol-alphabet payloads on our ports,
and 64 KB adversarial payloads whose dissection time must stay linear.
"""

from __future__ import annotations

import functools
import hashlib
import os
import random
import re
import resource
import shlex
import shutil
import signal
import struct
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from sharedlink.capture.packets import (
    TCP_ACK,
    TCP_PSH,
    TcpBuilder,
    TcpConversation,
    UdpBuilder,
    decode_packet,
)
from sharedlink.capture.pcapio import LINKTYPE_ETHERNET, CaptureError, PcapWriter, read_records
from sharedlink.generators.beacon import GenOptions, beacon_payloads, generate_file
from sharedlink.protocols import codec

REPO = Path(__file__).resolve().parents[2]
DISSECTOR_DIR = REPO / "dissector"
CAPTURES_DIR = REPO / "captures"
REGRESSIONS_DIR = Path(__file__).resolve().parent / "fuzz-regressions"

TSHARK_ENV = "SHAREDLINK_TSHARK"
EDITCAP_ENV = "SHAREDLINK_EDITCAP"

#: editcap -E: the probability that a byte is changed (Wireshark's fuzz-test.sh default)
ERR_PROB = 0.02

#: what tools/test-common.sh exports for fuzz runs
FUZZ_ENV = {
    "WIRESHARK_DEBUG_WMEM_OVERRIDE": "strict",
    "WIRESHARK_ABORT_ON_DISSECTOR_BUG": "1",
    "WIRESHARK_ABORT_ON_TOO_MANY_ITEMS": "1",
    "G_SLICE": "debug-blocks",
    "MALLOC_CHECK_": "3",
    "MALLOC_PERTURB_": "165",
}

#: stderr lines that are not a problem (tshark's warning when run as root on the host)
BENIGN_STDERR = (re.compile(r'^Running as user "[^"]*" and group "[^"]*"\. This could be dangerous\.$'),)

#: the port the heuristic dissectors are tried on (not registered by anyone)
HEURISTIC_PORT = 47013
#: ports always fuzzed besides the ones our dissectors' preferences name
DEFAULT_PORTS = (7013,)


class HarnessError(RuntimeError):
    """The harness cannot do its job (tshark missing, dissectors not loading...)."""


# --- commands ---------------------------------------------------------------------------------


def tool_command(var: str, default: str) -> list[str]:
    cmd = shlex.split(os.environ.get(var, "") or default)
    if not cmd:
        raise HarnessError(f"${var} is empty")
    return cmd


def tshark_command() -> list[str]:
    return tool_command(TSHARK_ENV, "tshark")


def editcap_command() -> list[str]:
    return tool_command(EDITCAP_ENV, "editcap")


def dissector_scripts() -> list[Path]:
    scripts = sorted(DISSECTOR_DIR.glob("*.lua"))
    if not scripts:
        raise HarnessError(f"no Lua dissectors in {DISSECTOR_DIR}")
    return scripts


def lua_args() -> list[str]:
    args: list[str] = []
    for p in dissector_scripts():
        args += ["-X", f"lua_script:{p}"]
    return args


def _run(cmd: Sequence[str], timeout: float = 120) -> subprocess.CompletedProcess[str]:
    try:
        return subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout, errors="replace")
    except FileNotFoundError as exc:
        raise HarnessError(f"{cmd[0]}: not found (set ${TSHARK_ENV} / ${EDITCAP_ENV})") from exc


@functools.cache
def _version(cmd: tuple[str, ...]) -> str:
    out = _run([*cmd, "--version"]).stdout.splitlines()
    return out[0].strip() if out else "unknown"


def tshark_version() -> str:
    """``TShark (Wireshark) 4.0.17 (...)``: the first line of ``--version``."""
    return _version(tuple(tshark_command()))


def version_tuple(text: str) -> tuple[int, ...]:
    m = re.search(r"(\d+)\.(\d+)\.(\d+)", text)
    return tuple(int(x) for x in m.groups()) if m else (0, 0, 0)


def stderr_problems(text: str) -> list[str]:
    """Every stderr line that is not known to be harmless (Lua messages among them)."""
    return [ln for ln in text.splitlines() if ln.strip() and not any(p.match(ln.strip()) for p in BENIGN_STDERR)]


@dataclass(frozen=True)
class Protocol:
    name: str  # long name: the top line of its tree in -V output
    short: str
    filter: str


@dataclass(frozen=True)
class Dissectors:
    """What loading dissector/*.lua adds to tshark: protocols and the ports in their preferences."""

    version: str
    protocols: tuple[Protocol, ...]
    ports: tuple[int, ...]


def _protocols(extra: Sequence[str]) -> tuple[dict[str, Protocol], str]:
    r = _run([*tshark_command(), "-G", "protocols", *extra])
    if r.returncode != 0:
        raise HarnessError(f"tshark -G protocols failed ({r.returncode}): {r.stderr.strip()[:500]}")
    protos = {}
    for ln in r.stdout.splitlines():
        parts = ln.split("\t")
        if len(parts) >= 3:
            protos[parts[2]] = Protocol(parts[0], parts[1], parts[2])
    return protos, r.stderr


def _port_range(text: str) -> Iterator[int]:
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m:
            continue
        lo = int(m.group(1))
        hi = int(m.group(2) or lo)
        if 0 < lo <= hi < 65536 and hi - lo < 16:
            yield from range(lo, hi + 1)


@functools.cache
def _load_dissectors(cmd: tuple[str, ...], scripts: tuple[str, ...]) -> Dissectors:
    base, _ = _protocols([])
    mine, err = _protocols(lua_args())
    problems = stderr_problems(err)
    if problems:
        raise HarnessError("loading the dissectors printed on stderr:\n  " + "\n  ".join(problems[:20]))
    added = tuple(p for f, p in sorted(mine.items()) if f not in base)
    if not added:
        raise HarnessError(
            f"{tshark_version()}: the dissectors registered no protocol: the Lua scripts did not load "
            f"(Wireshark 4.6 skips Lua plugins when run as root; is Lua enabled?) - command: {shlex.join(cmd)}"
        )
    r = _run([*cmd, "-G", "defaultprefs", *lua_args()])
    ports: set[int] = set(DEFAULT_PORTS) | generator_ports()
    filters = {p.filter for p in added}
    for ln in r.stdout.splitlines():
        m = re.match(r"^#?\s*([\w.-]+)\.(\w*ports?)\s*:\s*(.*)$", ln)
        if m and m.group(1) in filters:
            ports.update(_port_range(m.group(3)))
    return Dissectors(tshark_version(), added, tuple(sorted(ports)))


def load_dissectors() -> Dissectors:
    """Load every dissector/*.lua into tshark once; raise :class:`HarnessError` if they do not
    register any protocol (a run that decodes nothing must never pass)."""
    return _load_dissectors(tuple(tshark_command()), tuple(str(p) for p in dissector_scripts()))


# --- running tshark under limits --------------------------------------------------------------


@dataclass(frozen=True)
class Limits:
    """Per run: CPU seconds (ulimit -t), address space in KiB (ulimit -v), wall-clock seconds."""

    cpu_s: int = 60
    vmem_kb: int = 2_000_000
    wall_s: float = 180.0

    def apply(self) -> None:  # in the child, before exec
        for res, soft in (
            (resource.RLIMIT_CPU, self.cpu_s),
            (resource.RLIMIT_AS, self.vmem_kb * 1024),
            (resource.RLIMIT_CORE, 0),
        ):
            _, hard = resource.getrlimit(res)
            if hard != resource.RLIM_INFINITY:
                soft = min(soft, hard)
            resource.setrlimit(res, (soft, hard))


@dataclass
class Outcome:
    """One tshark run on one capture."""

    path: Path
    returncode: int
    cpu_s: float
    wall_s: float
    timed_out: bool
    frames: int = 0
    decoded: int = 0  # frames with one of our protocols in the tree
    lua_errors: list[tuple[int, str]] = field(default_factory=list)  # (frame, message)
    stderr: list[str] = field(default_factory=list)  # unexpected stderr lines
    require_decoded: bool = True
    mode: str = "tree"

    @property
    def problems(self) -> list[str]:
        out = []
        if self.timed_out:
            out.append(f"ran past the wall-clock limit ({self.wall_s:.1f} s)")
        elif self.returncode < 0:
            sig = -self.returncode
            name = signal.Signals(sig).name if sig in signal.Signals._value2member_map_ else str(sig)
            why = " (CPU limit)" if sig == signal.SIGXCPU else ""
            out.append(f"killed by {name}{why}")
        elif self.returncode != 0:
            out.append(f"exit status {self.returncode}")
        for frame, msg in self.lua_errors[:5]:
            out.append(f"frame {frame}: {msg}")
        if len(self.lua_errors) > 5:
            out.append(f"... {len(self.lua_errors) - 5} more Lua errors")
        out += [f"stderr: {ln}" for ln in self.stderr[:10]]
        if self.require_decoded and not self.timed_out and self.returncode == 0 and self.decoded == 0:
            if self.mode == "tree":
                out.append(f"our dissectors decoded none of its {self.frames} frames (did they load?)")
            else:
                out.append(f"with -T fields, no field of our protocols is set in any of its {self.frames} frames")
        return out

    @property
    def ok(self) -> bool:
        return not self.problems

    def describe(self) -> str:
        return f"{self.path.name}: " + "; ".join(self.problems) if self.problems else f"{self.path.name}: ok"


_FRAME_LINE = re.compile(rb"^Frame (\d+): ")
_HEX_LINE = re.compile(rb"^[0-9a-f]{4,}  ")


def scan_output(stdout: Path, protocols: Sequence[Protocol]) -> tuple[int, int, list[tuple[int, str]]]:
    """(frames, frames decoded by our protocols, Lua errors) from ``tshark -V`` text output."""
    tops = tuple(p.name.encode() for p in protocols)
    frames = decoded = 0
    frame = 0
    counted = False
    errors: list[tuple[int, str]] = []
    with open(stdout, "rb") as fh:
        for line in fh:
            if line[:6] == b"Frame ":
                m = _FRAME_LINE.match(line)
                if m:
                    frame = int(m.group(1))
                    frames += 1
                    counted = False
                    continue
            if not counted and line.startswith(tops):
                rest = line[len(next(t for t in tops if line.startswith(t))) :]
                if rest[:1] in (b"\n", b",", b" ", b"\r", b""):
                    decoded += 1
                    counted = True
            if b"Lua Error" in line and not _HEX_LINE.match(line) and (not errors or errors[-1][0] != frame):
                errors.append((frame, line.decode("utf-8", "replace").strip().strip("[]")))  # first per frame
    return frames, decoded, errors


def scan_fields(stdout: Path) -> tuple[int, int, list[tuple[int, str]]]:
    """(frames, frames decoded by our protocols, Lua errors) from the ``-T fields`` output of
    :data:`MODES` ``"fields"``: frame number, _ws.lua.error, then one column per protocol."""
    frames = decoded = 0
    errors: list[tuple[int, str]] = []
    with open(stdout, "rb") as fh:
        for line in fh:
            cols = line.rstrip(b"\r\n").split(b"\t")
            if not cols[0].isdigit():
                continue
            frames += 1
            if len(cols) > 1 and cols[1]:
                errors.append((int(cols[0]), "Lua Error (_ws.lua.error set; the tree mode shows the message)"))
            if any(c for c in cols[2:]):
                decoded += 1
    return frames, decoded, errors


#: how tshark is run: "tree" is Wireshark's fuzz run (-nVxr, the whole tree); "fields" asks for a
#: few fields only (-T fields), so the dissectors get the sparse tree that filters and field
#: extraction use, which takes other code paths
MODES = ("tree", "fields")


def run_tshark(
    capture: Path,
    limits: Limits = Limits(),  # noqa: B008 - frozen
    require_decoded: bool = True,
    extra: Sequence[str] = (),
    mode: str = "tree",
) -> Outcome:
    """``tshark -nVxr CAPTURE`` (or ``-T fields``) with our dissectors, under ``limits``,
    scanned for problems."""
    dissectors = load_dissectors()
    cmd = [*tshark_command(), *lua_args(), *extra]
    if mode == "tree":
        cmd += ["-nVxr", str(capture)]
    elif mode == "fields":
        cmd += ["-nr", str(capture), "-T", "fields", "-E", "separator=/t", "-E", "occurrence=f", "-e", "frame.number", "-e", "_ws.lua.error"]
        for p in dissectors.protocols:
            cmd += ["-e", p.filter]
    else:
        raise ValueError(f"unknown mode {mode!r}")
    env = dict(os.environ, **FUZZ_ENV)
    with tempfile.TemporaryDirectory(prefix="slfuzz-out-") as tmp:
        out_path, err_path = Path(tmp, "stdout"), Path(tmp, "stderr")
        with open(out_path, "wb") as out, open(err_path, "wb") as err:
            t0 = time.perf_counter()
            proc = subprocess.Popen(cmd, stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env, preexec_fn=limits.apply)
            timed_out = threading.Event()

            def kill() -> None:
                timed_out.set()
                proc.kill()

            timer = threading.Timer(limits.wall_s, kill)
            timer.start()
            try:
                _, status, usage = os.wait4(proc.pid, 0)
            finally:
                timer.cancel()
            proc.returncode = os.waitstatus_to_exitcode(status)
            wall = time.perf_counter() - t0
        if mode == "tree":
            frames, decoded, errors = scan_output(out_path, dissectors.protocols)
        else:
            frames, decoded, errors = scan_fields(out_path)
        stderr = stderr_problems(err_path.read_text("utf-8", "replace"))
    return Outcome(
        path=capture,
        returncode=proc.returncode,
        cpu_s=usage.ru_utime + usage.ru_stime,
        wall_s=wall,
        timed_out=timed_out.is_set(),
        frames=frames,
        decoded=decoded,
        lua_errors=errors,
        stderr=stderr,
        require_decoded=require_decoded,
        mode=mode,
    )


# --- sample captures --------------------------------------------------------------------------

#: (file name, generator options) of the generated samples: every form and fault gen knows
SAMPLE_OPTIONS: tuple[tuple[str, dict[str, object]], ...] = (
    ("named.pcap", {"frames": 40}),
    ("compressed.pcap", {"frames": 60, "compress": True, "sync_interval": 1.0}),
    ("positional.pcap", {"frames": 40, "form": "positional"}),
    ("positional-compressed.pcapng", {"frames": 60, "form": "positional", "compress": True, "fmt": "pcapng"}),
    ("faults.pcap", {"frames": 60, "compress": True, "bad_checksum": 0.2, "drop": 0.1, "jitter_ms": 80.0, "seed": 7}),
)


def make_samples(folder: Path, include_repo_captures: bool = True) -> list[Path]:
    """Sample captures in ``folder``: generated ones (every form, compression and fault), a
    capture of every other frame kind over UDP and TCP, and ``captures/*.pcap*`` when present."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, kw in SAMPLE_OPTIONS:
        p = folder / name
        generate_file(GenOptions(**kw), p)  # type: ignore[arg-type]
        out.append(p)
    out += _other_protocol_samples(folder)
    p = folder / "kinds-udp.pcap"
    write_udp(p, [payload for _, payload in sample_payloads()])
    out.append(p)
    p = folder / "kinds-tcp.pcap"
    write_tcp(p, [payload for _, payload in sample_payloads()])
    out.append(p)
    if include_repo_captures and CAPTURES_DIR.is_dir():
        for c in sorted(CAPTURES_DIR.glob("*.pcap*")):
            if c.stat().st_size <= 4 << 20:
                out.append(c)
    return out


def _other_protocol_samples(folder: Path) -> list[Path]:
    """P2OS and blackboard sessions from their generators, when those exist."""
    out = []
    try:
        from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file

        generate_p2os_file(P2osGenOptions(duration=3.0), folder / "p2os.pcap")
        out.append(folder / "p2os.pcap")
    except ImportError:
        pass
    try:
        from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file

        for transport in ("udp", "tcp"):
            p = folder / f"blackboard-{transport}.pcap"
            generate_blackboard_file(BlackboardGenOptions(duration=2.0, transport=transport), p)
            out.append(p)
    except ImportError:
        pass
    return out


def generator_ports() -> set[int]:
    """The ports our capture generators use by default."""
    ports = {GenOptions().port}
    try:
        from sharedlink.generators.p2os import P2osGenOptions

        ports.add(P2osGenOptions().port)
    except ImportError:
        pass
    try:
        from sharedlink.generators.blackboard import BlackboardGenOptions

        ports.add(BlackboardGenOptions().port)
    except ImportError:
        pass
    return ports


@dataclass(frozen=True)
class Sample:
    """A payload and where it travels."""

    name: str
    payload: bytes
    transport: str = "udp"
    sport: int = 7013
    dport: int = 7013


def sample_payloads() -> list[tuple[str, bytes]]:
    """(name, payload): one payload of every SharedLink frame kind (and of the other protocols)."""
    return [(s.name, s.payload) for s in samples_with_endpoints()]


def samples_with_endpoints() -> list[Sample]:
    """One payload of every SharedLink frame kind (and of the other protocols we decode), each
    with the transport and ports its dissector listens on."""
    named = [("AutoGpsLat", 2, "38.34698779"), ("AutoGpsLon", 2, "-77.05734791"), ("Mode", 0, "3"), ("Name", 4, "rover 1")]
    frames = [
        ("full", codec.encode_named("A", "B", named)),
        ("delta", codec.encode_named("A", "B", named[:1])),
        ("positional", codec.encode_positional("A", "B", ["1", None, "2.5", "x"])),
        ("declaration", codec.build_fields(codec.declaration_fields([("AutoGpsLat", 2), ("Mode", 0)]))),
        ("declaration-in", codec.build_fields(codec.declaration_fields([("Speed", 2)], inbound=True))),
        ("query", codec.build_fields(codec.query_fields("AutoGpsLat"), dst="B", src="A")),
        ("reply", codec.build_fields(codec.reply_fields("AutoGpsLat", "38.1"))),
        ("command", codec.build_fields([codec.Field("E", "Stop"), codec.Field("D", "1")])),
        ("mode", codec.build_fields([codec.Field("M", "2")])),
        ("ping", codec.build_fields([codec.Field("P", "17")])),
        ("pong", codec.build_fields([codec.Field("G", "17")], dst="B", src="A")),
        ("no-checksum", b"[:AB|N0|T0|QMode|D3]\r\n"),
        ("lower-checksum", b"[:AB|P3|C" + b"%02x" % codec.checksum(b":AB|P3|C") + b"]\r\n"),
        ("two-frames", codec.encode_named("A", "B", named[:2]) + codec.encode_named("A", "C", named[2:])),
    ]
    first = next(beacon_payloads(GenOptions(frames=1, form="positional")))
    frames.append(("beacon-declaration", first[1]))
    return [Sample(n, p) for n, p in frames] + _other_protocol_payloads()


def _other_protocol_payloads() -> list[Sample]:
    """P2OS and blackboard messages, when those codecs exist (built with their own encoders)."""
    out: list[Sample] = []
    try:
        from sharedlink.protocols import p2os

        port = p2os.MOBILESIM_PORT
        out.append(Sample("p2os-command", p2os.encode_message(p2os.command(1)), "tcp", 45678, port))
        sip = p2os.encode_message(p2os.Sip(moving=True, xpos=100, sonars=((1, 500),)))
        out.append(Sample("p2os-sip", sip, "tcp", port, 45678))
    except Exception:  # noqa: BLE001 - not there (yet), or another API: skip them
        pass
    try:
        from sharedlink.generators.blackboard import BlackboardGenOptions
        from sharedlink.protocols import blackboard

        o = BlackboardGenOptions()
        set_msg = blackboard.SetMessage(0x1F00, 1, b"\x01\x02\x03")
        out.append(Sample("bb-set", blackboard.build_message(set_msg), "udp", o.master_port, o.port))
        out.append(Sample("bb-request", blackboard.build_message(blackboard.RequestMessage(0xE000, 1, 5)), "udp", o.master_port, o.port))
    except Exception:  # noqa: BLE001
        pass
    return out


# --- writing test captures --------------------------------------------------------------------

_T0 = 1_767_268_800 * 1_000_000_000


def write_udp(path: Path, payloads: Iterable[bytes], port: int = 7013, sport: int | None = None) -> int:
    """One Ethernet/IPv4/UDP packet per payload (127.0.0.1 to 127.0.0.2); returns the count."""
    b = UdpBuilder("127.0.0.1", "127.0.0.2", sport or port, port)
    n = 0
    with open(path, "wb") as fh:
        w = PcapWriter(fh, LINKTYPE_ETHERNET)
        for n, payload in enumerate(payloads, 1):
            w.write(_T0 + n * 1_000_000, b.frame(payload[:65507], n & 0xFFFF))
    return n


def write_tcp(path: Path, payloads: Iterable[bytes], port: int = 7013) -> int:
    """One TCP connection carrying each payload as one segment, alternating directions."""
    conv = TcpConversation("127.0.0.1", 40000, "127.0.0.2", port)
    n = 0
    with open(path, "wb") as fh:
        w = PcapWriter(fh, LINKTYPE_ETHERNET)
        frames = list(conv.open())
        for i, payload in enumerate(payloads):
            frames.append(conv.send(i % 2 == 0, payload[:65000]))
        frames += conv.close()
        for n, f in enumerate(frames, 1):
            w.write(_T0 + n * 1_000_000, f)
    return n


def write_truncations(path: Path, samples: Sequence[Sample]) -> int:
    """Every prefix of every sample payload, twice: as a shorter datagram or segment (consistent
    lengths) and as a record cut by the snapshot length (captured < on the wire, as a short
    snaplen does). TCP prefixes each travel in a connection of their own (a fresh client port)."""
    n = 0
    udp: dict[tuple[int, int], UdpBuilder] = {}
    with open(path, "wb") as fh:
        w = PcapWriter(fh, LINKTYPE_ETHERNET)
        for i, smp in enumerate(samples):
            payload = smp.payload
            for k in range(len(payload) + 1):
                if smp.transport == "udp":
                    b = udp.setdefault((smp.sport, smp.dport), UdpBuilder("127.0.0.1", "127.0.0.2", smp.sport, smp.dport))
                    short, whole = b.frame(payload[:k], n & 0xFFFF), b.frame(payload, n & 0xFFFF)
                else:
                    # a fresh connection (ephemeral port) per prefix, the server port kept
                    eph = 20000 + (i * 4099 + k) % 40000
                    sport, dport = (eph, smp.dport) if smp.dport < smp.sport else (smp.sport, eph)
                    t = TcpBuilder("127.0.0.1", "127.0.0.2", sport, dport)
                    short = t.segment(1, 1, TCP_PSH | TCP_ACK, payload[:k], 1)
                    whole = t.segment(1, 1, TCP_PSH | TCP_ACK, payload, 1)
                n += 1
                w.write(_T0 + n * 1000, short)
                n += 1
                rec = w.record(_T0 + n * 1000, whole[: len(whole) - len(payload) + k])
                fh.write(rec[:12] + struct.pack("<I", len(whole)) + rec[16:])
    return n


# --- mutation (editcap -E) --------------------------------------------------------------------


def header_length(capture: Path) -> int:
    """Bytes of link, IP and UDP/TCP headers common to every packet of ``capture`` (what editcap
    -o must keep intact so that the damage reaches our dissectors)."""
    lengths = []
    try:
        for rec in read_records(capture):
            d = decode_packet(rec.linktype, rec.data)
            if d is not None:
                lengths.append(len(rec.data) - len(d.payload))
    except CaptureError:
        pass
    return min(lengths) if lengths else 0


def mutate(src: Path, dst: Path, seed: int, offset: int | None = None, prob: float = ERR_PROB) -> Path:
    """``editcap -E prob -o offset --seed seed src dst``."""
    off = header_length(src) if offset is None else offset
    r = _run([*editcap_command(), "-E", str(prob), "-o", str(off), "--seed", str(seed), str(src), str(dst)])
    if r.returncode != 0:
        raise HarnessError(f"editcap failed on {src}: {r.stderr.strip()[:300]}")
    return dst


# --- random and adversarial payloads ----------------------------------------------------------

ALPHABET = [b"[", b"]", b":", b"|", b"\r\n", b"\r", b"\n", b"[:", b"|C", b"]\r\n"] + [
    bytes([c]) for c in b"ABCDEFGHIJKLMNOPQRTEMGLZ0123456789abcdef.-+eE \x00\xff\xfa\xfb;"
]


def random_payloads(rng: random.Random, count: int, samples: Sequence[bytes]) -> Iterator[bytes]:
    """Random bytes, protocol-alphabet soup and mutated / spliced sample frames, in turn."""
    for i in range(count):
        k = i % 4
        if k == 0:
            yield rng.randbytes(rng.choice((rng.randrange(0, 16), rng.randrange(0, 200), rng.randrange(0, 1500))))
        elif k == 1:
            yield b"".join(rng.choice(ALPHABET) for _ in range(rng.randrange(0, 120)))
        elif k == 2 and samples:
            b = bytearray(rng.choice(samples))
            for _ in range(rng.randrange(1, 6)):
                if b:
                    j = rng.randrange(len(b))
                    op = rng.randrange(4)
                    if op == 0:
                        b[j] = rng.randrange(256)
                    elif op == 1:
                        b[j:j] = rng.choice(ALPHABET)
                    elif op == 2:
                        del b[j : j + rng.randrange(1, 8)]
                    else:
                        b[j:j] = b[j : j + rng.randrange(1, 40)]
            yield bytes(b)
        elif samples:
            a, c = rng.choice(samples), rng.choice(samples)
            yield a[: rng.randrange(len(a) + 1)] + c[rng.randrange(len(c) + 1) :]
        else:
            yield rng.randbytes(rng.randrange(0, 64))


def adversarial_patterns() -> dict[str, bytes]:
    """Payload units that, repeated to 64 KB, stress a line parser's worst cases."""
    return {
        "opens": b"[",
        "header-opens": b"[:AB",
        "closes": b"]",
        "empty-fields": b"[:AB" + b"|" * 64,
        "fields": b"|T2|QAutoGpsLat|D38.1",
        "frames": codec.encode_named("A", "B", [("V", 0, "1")]),
        "frames-no-crlf": codec.encode_named("A", "B", [("V", 0, "1")], crlf=False),
        "crlf": b"\r\n",
        "digits": b"9",
        "nested": b"[:AB|[:AB|",
        "unterminated-frames": b"[:AB|N0|T0|QX|D1|C00",
        "positional": b"|D1",
        "p2os": b"\xfa\xfb",
        "blackboard": b":0",
    }


def adversarial_payload(unit: bytes, size: int) -> bytes:
    if unit.startswith(b"[:AB") and unit.endswith(b"|"):
        head, body = b"[:AB", b"|"
        return (head + body * size)[:size]
    if unit.startswith(b"|"):
        return (b"[:AB|N0" + unit * (size // len(unit) + 1))[:size]
    return (unit * (size // len(unit) + 1))[:size]


# --- keeping failures -------------------------------------------------------------------------


def minimize(outcome: Outcome, work: Path, limits: Limits = Limits()) -> Path:  # noqa: B008 - frozen
    """The smallest of: the first failing frame alone, the frames up to it, the whole capture,
    that still fails the same way (a Lua error may need the frames before it for its state)."""
    if not outcome.lua_errors:
        return outcome.path
    n = outcome.lua_errors[0][0]
    for i, frames in enumerate((str(n), f"1-{n}")):
        cut = work / f"min{i}-{outcome.path.name}"
        r = _run([*editcap_command(), "-r", str(outcome.path), str(cut), frames])
        if r.returncode == 0 and cut.exists():
            o = run_tshark(cut, limits, require_decoded=False, mode=outcome.mode)
            if o.lua_errors:
                return cut
    return outcome.path


def keep_regression(outcome: Outcome, label: str, limits: Limits = Limits()) -> Path:  # noqa: B008 - frozen
    """Keep a failing capture (minimized) in tests/fuzz/fuzz-regressions/, named by its content, with
    a note of the release, the mode and the failure."""
    REGRESSIONS_DIR.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="slfuzz-min-") as tmp:
        os.chmod(tmp, 0o755)
        capture = minimize(outcome, Path(tmp), limits)
        digest = hashlib.sha256(capture.read_bytes()).hexdigest()[:12]
        suffix = "".join(capture.suffixes[-1:]) or ".pcap"
        dst = REGRESSIONS_DIR / f"{re.sub(r'[^A-Za-z0-9_.-]+', '-', label)}-{digest}{suffix}"
        shutil.copyfile(capture, dst)
    dst.with_suffix(".txt").write_text(f"{label}\n{tshark_version()}\nmode: {outcome.mode}\n{outcome.describe()}\n")
    return dst


def regression_captures() -> list[Path]:
    if not REGRESSIONS_DIR.is_dir():
        return []
    return sorted(p for p in REGRESSIONS_DIR.iterdir() if p.suffix in (".pcap", ".pcapng"))


def readable_tmpdir(prefix: str) -> Path:
    """A temporary folder; tshark in a root filesystem reads it through CAP_DAC_READ_SEARCH, but
    we also open it up (0755) so that a plain unprivileged tshark can read it too."""
    d = Path(tempfile.mkdtemp(prefix=prefix))
    d.chmod(0o755)
    return d
