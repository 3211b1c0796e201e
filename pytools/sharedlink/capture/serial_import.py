"""Import serial logs that users already have into serial captures (pcapng, USER link type).

Formats (``detect_format`` picks one when asked for "auto"):

- ``raw``: the bytes of the line as dumped (``cat /dev/ttyUSB0 > dump``); no timing, so the
  records are ``chunk`` bytes each, timed at ``baud`` from ``start_ns``.
- ``hex``: a hex dump by ``xxd``, ``hexdump -C``, ``od -A x -t x1z`` or plain ``od`` (octal
  16-bit words); ``*`` lines (repeats) are expanded. Timing as for raw.
- ``log``: a text log, one line per chunk: a timestamp (ISO 8601 date-time, or seconds, in
  optional brackets), an optional direction (``<``/``>``, ``RX``/``TX``, ``IN``/``OUT``,
  ``R``/``W``, with an optional colon), then the data: hex bytes (``5b 3a 41``) or text with C
  escapes (``[:AB|N0|...]\\r\\n``). Lines without a timestamp in interceptty's style
  (``< 0x5b ([)``: one byte per line) are accepted too; consecutive bytes of one direction
  become one record.

Direction words: ``<``, RX, IN, R are inbound (read from the device); ``>``, TX, OUT, W are
outbound. Input problems raise :class:`SerialImportError` with the line number.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from sharedlink.capture.pcapio import NS
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT, DIR_UNKNOWN
from sharedlink.errors import InputError
from sharedlink.protocols.limits import MAX_HELD_BYTES

FORMATS = ("auto", "raw", "hex", "log")


class SerialImportError(InputError, ValueError):
    """A log that cannot be imported; ``line`` (= ``record``) counts from 1 (None: the file as
    a whole). Also a ``ValueError``, as it always was."""

    unit = "line"
    #: what the log gave before the bad line (a text log: the chunks of the lines before it)
    partial: list = []

    @property
    def line(self) -> int | None:
        return self.record


@dataclass(frozen=True)
class Chunk:
    ts_ns: int
    direction: int
    data: bytes


# -- format detection ------------------------------------------------------------------------

_XXD = re.compile(r"^([0-9a-fA-F]{4,16}):((?: [0-9a-fA-F]{2,4})*)(?:  .*)?$")
_HEXDUMP_C = re.compile(r"^([0-9a-fA-F]{4,16})((?:  ?[0-9a-fA-F]{2}){0,16})\s*(?:\|.*\|)?\s*$")
_OD_HEX = re.compile(r"^([0-9a-fA-F]{4,16})((?: [0-9a-fA-F]{2})+)\s*(?:>.*<)?\s*$")
_OD_OCT = re.compile(r"^([0-7]{7,16})((?: [0-7]{6})+)\s*$")
_OFFSET_ONLY = re.compile(r"^([0-9a-fA-F]{4,16}):?\s*$")


def _is_text(data: bytes) -> bool:
    return all(b in (9, 10, 13) or 32 <= b < 127 for b in data[:65536])


def detect_format(data: bytes) -> str:
    """raw, hex or log, from the content."""
    if not data or not _is_text(data):
        return "raw"
    lines = [ln for ln in data.decode("ascii").splitlines() if ln.strip()]
    if not lines:
        return "raw"
    if all(ln.strip() == "*" or _hex_line(ln) is not None for ln in lines):
        return "hex"
    probe = lines[:50]
    ok = sum(1 for ln in probe if _log_line(ln) is not None)
    if ok >= max(1, int(len(probe) * 0.9)):
        return "log"
    return "raw"


# -- hex dumps -------------------------------------------------------------------------------


def _hex_line(line: str) -> tuple[str, int, bytes] | None:
    """(style, offset, bytes) of one hex dump line, None if it is none."""
    s = line.rstrip("\r\n")
    m = _XXD.match(s)
    if m:
        digits = m.group(2).replace(" ", "")
        return "xxd", int(m.group(1), 16), bytes.fromhex(digits)
    m = _OD_OCT.match(s)
    if m:
        words = [int(w, 8) for w in m.group(2).split()]
        if all(w <= 0xFFFF for w in words):
            return "od", int(m.group(1), 8), b"".join(w.to_bytes(2, "little") for w in words)
    m = _HEXDUMP_C.match(s) or _OD_HEX.match(s)
    if m and m.group(2).strip():
        return "hexdump", int(m.group(1), 16), bytes.fromhex(m.group(2).replace(" ", ""))
    m = _OFFSET_ONLY.match(s)
    if m:
        return "end", int(m.group(1), 16), b""
    return None


#: the most bytes a hex dump may expand to with its ``*`` lines (a few lines could otherwise
#: ask for terabytes)
MAX_DUMP_BYTES = 1 << 30


def parse_hexdump(text: str, path: str = "<hex>") -> bytes:
    """The bytes of an xxd / hexdump -C / od dump (``*`` repeats expanded, at most
    :data:`MAX_DUMP_BYTES` in all; the last offset line, when present, gives the length)."""
    out = bytearray()
    prev: bytes | None = None
    repeat = False
    style = None
    for no, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        if line.strip() == "*":
            repeat = True
            continue
        parsed = _hex_line(line)
        if parsed is None:
            raise SerialImportError(path, no, "not a hex dump line (xxd, hexdump -C or od)")
        st, off, data = parsed
        if st == "end" and style == "od":
            off = int(line.strip().rstrip(":"), 8)  # od offsets are octal
        elif st == "od":
            style = "od"
        if off > MAX_DUMP_BYTES:
            raise SerialImportError(path, no, f"offset {off:#x} is past what a dump may expand to ({MAX_DUMP_BYTES:,} bytes)")
        if repeat and prev:
            out += prev * ((off - len(out)) // len(prev))  # the '*' lines: prev repeated up to off
            repeat = False
        if off < len(out) and st != "end":
            raise SerialImportError(path, no, f"offset {off:#x} goes back (expected {len(out):#x})")
        if st == "end":
            del out[off:]
            break
        if off > len(out):
            raise SerialImportError(path, no, f"offset {off:#x} skips bytes (expected {len(out):#x})")
        out += data
        prev = data
    return bytes(out)


# -- text logs -------------------------------------------------------------------------------

_TS = r"\[?(?P<ts>\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}:\d{2}(?:[.,]\d+)?(?:Z|[+-]\d{2}:?\d{2})?|\d+(?:\.\d+)?)\]?"
_DIR = r"(?:(?P<dir><|>|RX|TX|IN|OUT|R|W|rx|tx|in|out|r|w)\b:?|(?P<dir2><|>):?)"
_LOG = re.compile(r"^\s*" + _TS + r"\s+(?:" + _DIR + r"\s*)?(?P<data>.*?)\s*$")
_INTERCEPTTY = re.compile(r"^\s*(?P<dir>[<>])\s+0x(?P<byte>[0-9a-fA-F]{2})\b.*$")
_HEXDATA = re.compile(r"^(?:[0-9a-fA-F]{2})(?:[ :]?[0-9a-fA-F]{2})*$")
_INBOUND = {"<", "rx", "in", "r"}


def _log_line(line: str) -> tuple[int | None, int, bytes] | None:
    """(timestamp ns or None, direction, data) or None if the line is not a log line."""
    m = _INTERCEPTTY.match(line)
    if m:
        return None, DIR_IN if m.group("dir") == "<" else DIR_OUT, bytes.fromhex(m.group("byte"))
    m = _LOG.match(line)
    if not m:
        return None
    ts = _parse_ts(m.group("ts"))
    if ts is None:
        return None
    d = m.group("dir") or m.group("dir2")
    direction = DIR_UNKNOWN if d is None else (DIR_IN if d.lower() in _INBOUND else DIR_OUT)
    return ts, direction, _parse_data(m.group("data"))


def _parse_ts(text: str) -> int | None:
    if "-" in text[:5] or ":" in text:
        try:
            t = text.replace(",", ".").replace(" ", "T")
            if t.endswith("Z"):
                t = t[:-1] + "+00:00"
            frac = ""
            m = re.match(r"^(.*T\d{2}:\d{2}:\d{2})(\.\d+)?(.*)$", t)
            if m:
                t, frac = m.group(1) + m.group(3), (m.group(2) or "")[1:]
            dt = datetime.fromisoformat(t)
            if dt.tzinfo is None:
                dt = dt.replace(tzinfo=timezone.utc)
            ns = int(dt.timestamp()) * NS
            return ns + int((frac + "000000000")[:9]) if frac else ns
        except ValueError:
            return None
    whole, _, frac = text.partition(".")
    return int(whole) * NS + int((frac + "000000000")[:9])


_ESC = re.compile(rb"\\(x[0-9a-fA-F]{2}|[rnt0\\\"'])")
_ESC_MAP = {b"r": b"\r", b"n": b"\n", b"t": b"\t", b"0": b"\0", b"\\": b"\\", b'"': b'"', b"'": b"'"}


def _parse_data(text: str) -> bytes:
    t = text.strip()
    if _HEXDATA.match(t) and (" " in t or ":" in t or len(t) == 2):
        return bytes.fromhex(t.replace(" ", "").replace(":", ""))
    if len(t) >= 2 and t[0] == t[-1] and t[0] in "\"'":
        t = t[1:-1]
    raw = t.encode("latin-1", "replace")
    return _ESC.sub(lambda m: bytes((int(m.group(1)[1:], 16),)) if m.group(1)[:1] == b"x" else _ESC_MAP[m.group(1)], raw)


#: the latest time a log line may carry: what a nanosecond pcapng holds (the year 2554)
MAX_LOG_NS = (1 << 64) - 1


def parse_log(text: str, path: str = "<log>", start_ns: int = 0, byte_ns: int = 0) -> list[Chunk]:
    """Chunks of a text log. interceptty-style lines carry no time: they get ``start_ns``
    plus ``byte_ns`` per byte, and consecutive bytes of one direction are one chunk (at most
    ``MAX_HELD_BYTES``: a longer run is cut into chunks of that size, the bytes gathered in
    linear time). A bad line raises :class:`SerialImportError` whose ``partial`` holds the
    chunks of the lines before it."""
    out: list[Chunk] = []
    clock = start_ns
    run: list[bytes] = []  # the untimed bytes of one direction not yet made a chunk
    run_len = 0
    run_dir = DIR_UNKNOWN

    def end_run() -> None:
        nonlocal run, run_len
        if run:
            out.append(Chunk(clock, run_dir, b"".join(run)))
            run, run_len = [], 0

    for no, line in enumerate(text.splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parsed = _log_line(line)
        reason = None
        if parsed is None:
            reason = "not a log line: expected TIMESTAMP [DIRECTION] DATA"
        elif parsed[0] is not None and not 0 <= parsed[0] <= MAX_LOG_NS:
            reason = "time stamp out of range (a capture holds 1970 to 2554)"
        if parsed is None or reason is not None:
            end_run()
            err = SerialImportError(path, no, reason or "")
            err.partial = list(out)
            raise err
        ts, d, data = parsed
        if ts is None:  # interceptty: merge consecutive bytes of one direction
            if run and (d != run_dir or run_len + len(data) > MAX_HELD_BYTES):
                end_run()
            clock += byte_ns
            run.append(data)
            run_len += len(data)
            run_dir = d
            continue
        end_run()
        if data:
            out.append(Chunk(ts, d, data))
            clock = ts
    end_run()
    return out


# -- the whole import --------------------------------------------------------------------------


def read_log(
    path: str | Path,
    fmt: str = "auto",
    baud: int = 9600,
    chunk: int = 64,
    direction: int = DIR_IN,
    start_ns: int | None = None,
) -> tuple[str, list[Chunk]]:
    """(format used, chunks) of a log file. Raw and hex dumps: ``chunk`` bytes per record,
    timed at ``baud`` (10 bits per byte) from ``start_ns`` (default: the file's mtime)."""
    p = Path(path)
    try:
        data = p.read_bytes()
        mtime_ns = p.stat().st_mtime_ns
    except OSError as exc:
        raise SerialImportError(str(p), None, exc.strerror or str(exc)) from None
    if fmt not in FORMATS:
        raise SerialImportError(str(p), None, f"unknown format {fmt!r} ({', '.join(FORMATS)})")
    if fmt == "auto":
        fmt = detect_format(data)
    byte_ns = 10 * NS // max(1, baud)
    t0 = mtime_ns if start_ns is None else start_ns
    if fmt in ("hex", "log"):
        try:
            text = data.decode("ascii")
        except UnicodeDecodeError as exc:
            line = data[: exc.start].count(b"\n") + 1
            raise SerialImportError(str(p), line, f"non-ASCII byte in a {fmt} file") from None
    if fmt == "log":
        return fmt, parse_log(text, str(p), t0, byte_ns)
    raw = parse_hexdump(text, str(p)) if fmt == "hex" else data
    if chunk < 1:
        raise SerialImportError(str(p), None, "chunk size must be at least 1")
    return fmt, list(_timed_chunks(raw, t0, baud, chunk, direction))


def _timed_chunks(raw: bytes, t0: int, baud: int, size: int, direction: int) -> Iterator[Chunk]:
    """Each chunk timed when its last byte arrived at ``baud`` (10 bits per byte)."""
    for i in range(0, len(raw), size):
        part = raw[i : i + size]
        yield Chunk(t0 + (i + len(part)) * 10 * NS // max(1, baud), direction, part)
