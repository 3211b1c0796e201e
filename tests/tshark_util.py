"""Helpers for driving the real tshark with the working tree's SharedLink dissector.

Every run is isolated from personal Wireshark configuration (an empty config dir is
used for WIRESHARKCONFIGDIR, XDG_CONFIG_HOME and HOME) and checked for Lua trouble:
tshark's return code must be 0, the output must not contain ``_ws.lua.error`` (or a
"Lua Error" label), stderr must not carry Lua error text, and the dissector must have
been loaded (``tshark -G protocols`` with the script lists ``sharedlink``).
"""

from __future__ import annotations

import atexit
import json
import os
import re
import shlex
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple, Union

REPO = Path(__file__).resolve().parents[1]
DISSECTOR = REPO / "dissector" / "sharedlink.lua"
TSHARK = shutil.which("tshark") or "/usr/bin/tshark"
# the tshark command prefix: $SHAREDLINK_TSHARK (shell-split; e.g. "scripts/tshark-in-rootfs sid"
# for the version matrix), else tshark from PATH
TSHARK_CMD = shlex.split(os.environ.get("SHAREDLINK_TSHARK", "")) or [TSHARK]

def _tshark_version() -> tuple[int, int]:
    try:
        out = subprocess.run([*TSHARK_CMD, "--version"], capture_output=True, text=True, timeout=60).stdout
        m = re.search(r"TShark \(Wireshark\) (\d+)\.(\d+)", out)
        if m:
            return int(m.group(1)), int(m.group(2))
    except (OSError, subprocess.SubprocessError):
        pass
    return (4, 0)


TSHARK_VERSION = _tshark_version()
# The Info column field was renamed in Wireshark 4.2.
INFO_FIELD = "_ws.col.info" if TSHARK_VERSION >= (4, 2) else "_ws.col.Info"

# stderr lines that are harmless
_BENIGN_STDERR = (
    re.compile(r'^Running as user "root" and group "root"\. This could be dangerous\.$'),
    re.compile(r"^\s*$"),
)
# Lua trouble on stderr
_LUA_ERROR_RE = re.compile(r"Lua:|lua:|\.lua:|Error|error|attempt to|stack traceback")

_config_dir: Path | None = None
_loaded_checked: set[tuple[str, float]] = set()


def _clean_env() -> dict[str, str]:
    global _config_dir
    if _config_dir is None:
        _config_dir = Path(tempfile.mkdtemp(prefix="sharedlink-wsconf-"))
        (_config_dir / "wireshark").mkdir()
        atexit.register(shutil.rmtree, _config_dir, True)
    env = dict(os.environ)
    env["WIRESHARKCONFIGDIR"] = str(_config_dir / "wireshark")
    env["XDG_CONFIG_HOME"] = str(_config_dir)
    env["HOME"] = str(_config_dir)
    env.pop("WIRESHARK_RUN_FROM_BUILD_DIRECTORY", None)
    env.pop("SHAREDLINK_SERIAL_INTERFACES", None)  # serial.lua's opt-in field extractor: tests ask for it
    env["LC_ALL"] = "C.UTF-8"
    return env


class TsharkResult(NamedTuple):
    args: list[str]
    returncode: int
    stdout: str
    stderr: str


class TsharkFailure(AssertionError):
    pass


def check_stderr(stderr: str) -> None:
    for line in stderr.splitlines():
        if any(p.match(line) for p in _BENIGN_STDERR):
            continue
        if _LUA_ERROR_RE.search(line):
            raise TsharkFailure(f"Lua/tshark error on stderr: {line!r}\n--- full stderr ---\n{stderr}")


def _run(args: Sequence[str], timeout: float) -> TsharkResult:
    proc = subprocess.run(
        list(args), capture_output=True, env=_clean_env(), timeout=timeout,
        encoding="utf-8", errors="replace",
    )
    return TsharkResult(list(args), proc.returncode, proc.stdout, proc.stderr)


def _assert_ok(res: TsharkResult) -> None:
    if res.returncode != 0:
        raise TsharkFailure(f"tshark exited {res.returncode}: {' '.join(res.args)}\n{res.stderr}")
    if "_ws.lua.error" in res.stdout or "Lua Error" in res.stdout:
        idx = max(res.stdout.find("_ws.lua.error"), res.stdout.find("Lua Error"))
        raise TsharkFailure(f"Lua error in output: ...{res.stdout[max(0, idx - 500): idx + 500]}...")
    check_stderr(res.stderr)


def ensure_loaded(script: Path = DISSECTOR) -> None:
    """Assert (once per script version) that tshark loads the script and knows ``sharedlink``."""
    script = Path(script).resolve()
    key = (str(script), script.stat().st_mtime)
    if key in _loaded_checked:
        return
    res = _run([*TSHARK_CMD, "-G", "protocols", "-X", f"lua_script:{script}"], timeout=60)
    _assert_ok(res)
    names = {line.split("\t")[2] for line in res.stdout.splitlines() if line.count("\t") >= 2}
    if "sharedlink" not in names:
        raise TsharkFailure(f"sharedlink protocol not registered by {script}\n{res.stderr}")
    _loaded_checked.add(key)


def tshark(
    capture: str | Path | None,
    args: Sequence[str] = (),
    prefs: Mapping[str, Any] | None = None,
    two_pass: bool = False,
    script: str | Path = DISSECTOR,
    timeout: float = 120,
) -> TsharkResult:
    """Run tshark on ``capture`` with the dissector, ``-o`` prefs and extra args; checked."""
    script = Path(script).resolve()
    ensure_loaded(script)
    cmd = [*TSHARK_CMD, "-n", "-X", f"lua_script:{script}"]
    if capture is not None:
        cmd += ["-r", str(capture)]
    if two_pass:
        cmd.append("-2")
    for name, value in (prefs or {}).items():
        if isinstance(value, bool):
            value = "TRUE" if value else "FALSE"
        cmd += ["-o", f"{name}:{value}"]
    cmd += list(args)
    res = _run(cmd, timeout)
    _assert_ok(res)
    return res


_BOOL_TEXT = {"True": "1", "False": "0"}
_booleans: set[str] | None = None


def _boolean_fields() -> set[str]:
    """Names of the boolean fields of every dissector in dissector/ and of Wireshark."""
    global _booleans
    if _booleans is None:
        cmd = [*TSHARK_CMD, "-G", "fields"]
        for script in sorted((REPO / "dissector").glob("*.lua")):
            cmd += ["-X", f"lua_script:{script}"]
        out = subprocess.run(cmd, capture_output=True, text=True, env=_clean_env(), timeout=120).stdout
        _booleans = {
            cols[2] for cols in (line.split("\t") for line in out.splitlines()) if len(cols) > 3 and cols[3] == "FT_BOOLEAN"
        }
        assert "sharedlink.var.carried" in _booleans, "tshark -G fields did not list the dissectors' fields"
    return _booleans


def fields(
    capture: str | Path,
    names: Sequence[str],
    prefs: Mapping[str, Any] | None = None,
    display_filter: str | None = None,
    two_pass: bool = True,
    extra: Sequence[str] = (),
    **kw: Any,
) -> list[dict[str, list[str]]]:
    """``-T fields`` output as one dict per packet: field name -> list of occurrences.

    ``_ws.lua.error`` is always requested too and asserted empty.  The occurrence
    aggregator is the ASCII unit separator, so values containing commas survive.
    """
    all_names = list(names) + ["_ws.lua.error", "_ws.expert.message"]
    args = ["-T", "fields", "-E", "occurrence=a", "-E", "aggregator=\x1f", "-E", "quote=n", "-E", "separator=\t"]
    for n in all_names:
        args += ["-e", n]
    if display_filter:
        args += ["-Y", display_filter]
    args += list(extra)
    res = tshark(capture, args, prefs=prefs, two_pass=two_pass, **kw)
    booleans = _boolean_fields() & set(names)
    rows: list[dict[str, list[str]]] = []
    # one packet a line: split at "\n" alone (str.splitlines would also split a value that holds
    # \x0b, \x0c, \x1c-\x1e or \x85, bytes an expert message may quote from the packet)
    for line in res.stdout.split("\n"):
        if not line:
            continue
        cols = line.split("\t")
        cols += [""] * (len(all_names) - len(cols))
        row = {n: (c.split("\x1f") if c != "" else []) for n, c in zip(all_names, cols)}
        for n in booleans:  # 4.0 prints booleans as 1/0, 4.2 and later as True/False
            row[n] = [_BOOL_TEXT.get(v, v) for v in row[n]]
        if row["_ws.lua.error"]:
            raise TsharkFailure(f"Lua error: {row['_ws.lua.error']}")
        for msg in row["_ws.expert.message"]:
            if msg.startswith("Lua Error") or "attempt to" in msg:
                raise TsharkFailure(f"Lua expert message: {msg}")
        rows.append(row)
    return rows



def as_list(x: Any) -> list[Any]:
    """A tshark JSON value as a list (one value is not wrapped in a list there)."""
    if x is None:
        return []
    return list(x) if isinstance(x, list) else [x]


def walk(node: Any, key: str) -> list[Any]:
    """Every value of ``key`` anywhere below ``node`` of a tshark JSON tree."""
    out: list[Any] = []
    if isinstance(node, dict):
        for k, v in node.items():
            if k == key:
                out += as_list(v)
            for item in as_list(v):
                out += walk(item, key)
    return out


def json_packets(
    capture: str | Path,
    prefs: Mapping[str, Any] | None = None,
    display_filter: str | None = None,
    two_pass: bool = True,
    extra: Sequence[str] = (),
    **kw: Any,
) -> list[dict[str, Any]]:
    """``-T json`` output (duplicate keys merged into lists) as a list of packets."""
    args = ["-T", "json", *extra]
    if display_filter:
        args += ["-Y", display_filter]
    res = tshark(capture, args, prefs=prefs, two_pass=two_pass, **kw)

    def hook(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in pairs:
            if k in out:
                if not isinstance(out[k], list) or not getattr(out[k], "_dup", False):
                    lst = _DupList([out[k]])
                    out[k] = lst
                out[k].append(v)
            else:
                out[k] = v
        return out

    return json.loads(res.stdout or "[]", object_pairs_hook=hook)


class _DupList(list):
    _dup = True


def verbose(capture: str | Path, prefs: Mapping[str, Any] | None = None, two_pass: bool = True,
            extra: Sequence[str] = (), **kw: Any) -> str:
    """``-V`` output text."""
    return tshark(capture, ["-V", *extra], prefs=prefs, two_pass=two_pass, **kw).stdout


def summary(capture: str | Path, prefs: Mapping[str, Any] | None = None, two_pass: bool = False,
            extra: Sequence[str] = (), **kw: Any) -> list[str]:
    """Summary lines (one per packet)."""
    return tshark(capture, list(extra), prefs=prefs, two_pass=two_pass, **kw).stdout.splitlines()


# ---------------------------------------------------------------------------
# Capture writing
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Pkt:
    """One packet: payload sent at ``ts`` from (src, sport) to (dst, dport) over udp or tcp."""

    ts: float
    payload: bytes
    sport: int = 7013
    dport: int = 7013
    proto: str = "udp"
    src: str = "10.0.0.2"
    dst: str = "10.0.0.255"


PacketSpec = Union[Pkt, tuple]


def _mac_for(ip: str) -> str:
    if ip.endswith(".255"):
        return "ff:ff:ff:ff:ff:ff"
    parts = [int(x) for x in ip.split(".")]
    return "02:00:%02x:%02x:%02x:%02x" % tuple(parts)


def write_pcap(path: str | Path, packets: Iterable[PacketSpec]) -> Path:
    """Write Ethernet/IPv4 packets with scapy.

    Each item is a :class:`Pkt` or a tuple ``(ts, payload, sport, dport, proto, src, dst)``
    (trailing items optional).  TCP packets of the same 4-tuple get consecutive sequence
    numbers (PSH/ACK, no handshake), so consecutive TCP items form one stream that
    Wireshark reassembles.
    """
    from scapy.all import IP, TCP, UDP, Ether, wrpcap  # noqa: PLC0415 (slow import)

    seqs: dict[tuple[str, int, str, int], int] = {}
    out = []
    for spec in packets:
        p = spec if isinstance(spec, Pkt) else Pkt(*spec)
        l2 = Ether(src=_mac_for(p.src), dst=_mac_for(p.dst))
        l3 = IP(src=p.src, dst=p.dst)
        if p.proto == "udp":
            pkt = l2 / l3 / UDP(sport=p.sport, dport=p.dport) / p.payload
        elif p.proto == "tcp":
            key = (p.src, p.sport, p.dst, p.dport)
            rkey = (p.dst, p.dport, p.src, p.sport)
            seq = seqs.setdefault(key, 1000)
            ack = seqs.setdefault(rkey, 5000)
            pkt = l2 / l3 / TCP(sport=p.sport, dport=p.dport, flags="PA", seq=seq, ack=ack, window=65535) / p.payload
            seqs[key] = seq + len(p.payload)
        else:
            raise ValueError(f"unknown proto {p.proto!r}")
        pkt.time = p.ts
        out.append(pkt)
    path = Path(path)
    wrpcap(str(path), out)
    return path


def checksum(body: str) -> str:
    """SharedLink checksum (2 upper-case hex digits) of a frame text from ':' through 'C'."""
    return "%02X" % (sum(body.encode("latin-1")) % 256)


def frame(dst: str, src: str, *fields: str, crlf: bool = True, cs: str | None = None) -> bytes:
    """Build ``[:DS|f1|f2|...|Cxx]`` (+ CR LF) with a correct checksum unless ``cs`` is given."""
    body = f":{dst}{src}|" + "".join(f + "|" for f in fields) + "C"
    c = checksum(body) if cs is None else cs
    return ("[" + body + c + "]" + ("\r\n" if crlf else "")).encode("latin-1")


def shown_matches(
    capture: str | Path,
    filters: Sequence[str],
    prefs: Mapping[str, Any] | None = None,
    two_pass: bool = False,
    extra: Sequence[str] = (),
    **kw: Any,
) -> dict[str, list[int]]:
    """The frames each display filter matches in a shown tree, from one tshark run: ``-V``
    (every item made with its range and label, as ``-V -Y F`` makes it) and one Lua tap
    (``Listener``) a filter, each noting the frames its filter matches (with ``two_pass``, the
    second pass's, as ``-2 -V -Y F`` prints). One run instead of one a filter: the shown tree is
    the same whatever the filters reference."""
    with tempfile.TemporaryDirectory(prefix="sharedlink-taps-") as tmp:
        os.chmod(tmp, 0o777)  # (tshark may run as another user: make test-matrix's roots run it as sharedlink)
        out = Path(tmp, "matches.txt")
        script = Path(tmp, "taps.lua")
        # the taps are made in a protocol's init (before the file is read): the dissectors'
        # fields are registered only after every script has loaded
        lines = [f"local out = assert(io.open([==[{out}]==], 'w'))", "out:setvbuf('line')",
                 "local taps = Proto('sharedlinktesttaps', 'Test taps')", "local made = false",
                 "function taps.init()", "  if made then return end", "  made = true"]
        for i, flt in enumerate(filters):
            assert "]==]" not in flt, flt
            lines += [f"  local l{i} = Listener.new('frame', [==[{flt}]==])",
                      f"  function l{i}.packet(pinfo) out:write('{i} ', pinfo.number, '\\n') end"]
        script.write_text("\n".join([*lines, "end"]) + "\n")
        tshark(capture, ["-V", "-O", "frame", "-X", f"lua_script:{script}", *extra], prefs=prefs, two_pass=two_pass,
               **kw)
        found: dict[str, list[int]] = {flt: [] for flt in filters}
        for line in out.read_text().splitlines():
            i, number = line.split()
            found[filters[int(i)]].append(int(number))
    return found


def env_for(home: Path) -> dict[str, str]:
    """The environment of a user whose home (and Wireshark's personal folders) is ``home``."""
    env = dict(os.environ, HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"), LC_ALL="C.UTF-8")
    for name in ("WIRESHARKCONFIGDIR", "WIRESHARK_CONFIG_DIR"):
        env.pop(name, None)
    return env
