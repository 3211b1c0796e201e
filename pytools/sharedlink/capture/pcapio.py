"""Streaming pcap and pcapng reading and writing with integer-nanosecond timestamps.

Written by hand rather than through scapy because it is the hot path of gen, replay and diff:
records are read one at a time (memory does not grow with the capture) and timestamps stay
integers (a float loses nanoseconds at today's epoch).
"""

from __future__ import annotations

import os
import shutil
import signal
import stat
import struct
import sys
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, BinaryIO

from sharedlink.errors import InputError, OutputError

#: nanoseconds per second: every timestamp in the package is an integer count of ns (the one home
#: of this constant; other modules import it)
NS = 1_000_000_000

# -- link types (tcpdump.org LINKTYPE_ values) --
LINKTYPE_NULL = 0  # BSD loopback, host-order address family
LINKTYPE_ETHERNET = 1
LINKTYPE_RAW = 101
LINKTYPE_RAW_DLT12 = 12  # DLT_RAW as some systems number it (libpcap maps it to RAW)
LINKTYPE_RAW_DLT14 = 14
LINKTYPE_LOOP = 108  # OpenBSD loopback, network-order address family
LINKTYPE_LINUX_SLL = 113
LINKTYPE_USER0 = 147
LINKTYPE_IPV4 = 228
LINKTYPE_IPV6 = 229
LINKTYPE_LINUX_SLL2 = 276
#: link types a classic pcap header may name (tcpdump.org's registry, where Wireshark maps
#: them): anything else is a header tshark refuses ("network type N unknown or unsupported")
KNOWN_LINKTYPES = frozenset(range(0, 16)) | {50, 51} | frozenset(range(98, 300))
#: the pcap header's link-type field: bits 16-25 are reserved and must be zero
PCAP_LINKTYPE_RESERVED = 0x03FF0000

PCAP_MAGIC_US = 0xA1B2C3D4
PCAP_MAGIC_NS = 0xA1B23C4D
PCAPNG_SHB = 0x0A0D0D0A
PCAPNG_BOM = 0x1A2B3C4D

#: pcapng EPB flags: direction bits
DIR_UNKNOWN, DIR_INBOUND, DIR_OUTBOUND = 0, 1, 2

# -- pcapng block types --
BT_IDB, BT_SPB, BT_EPB, BT_JOURNAL = 1, 3, 6, 9
#: the obsolete Packet Block (a 16-bit interface id, then the EPB's fields): still read by
#: Wireshark, and written by old tools
BT_PB = 2
#: blocks that are no packet but that Wireshark shows as frames (custom blocks, copied and not,
#: systemd journal exports, sysdig events): they take a frame number
FRAME_BLOCKS = frozenset({0x00000BAD, 0x40000BAD, BT_JOURNAL, 0x204, 0x208, 0x216, 0x217, 0x221, 0x222})


class CaptureError(InputError):
    """A capture that cannot be read (further). ``record`` counts from 1; ``None`` when the
    file header itself is bad."""

    whole = "file header"


@dataclass(frozen=True)
class Record:
    number: int  # 1-based, as Wireshark counts frames
    ts_ns: int
    linktype: int
    data: bytes
    orig_len: int
    flags: int = 0  # pcapng EPB flags (direction in the low two bits)
    interface: int = 0


# -- writing ------------------------------------------------------------------------------


class PcapWriter:
    """Classic pcap, nanosecond resolution (magic a1b23c4d)."""

    def __init__(self, fh: BinaryIO, linktype: int = LINKTYPE_ETHERNET, snaplen: int = 262144) -> None:
        self.fh = fh
        fh.write(struct.pack("<IHHiIII", PCAP_MAGIC_NS, 2, 4, 0, 0, snaplen, linktype))
        self._hdr = struct.Struct("<IIII")

    def record(self, ts_ns: int, data: bytes, flags: int = 0, interface: int = 0) -> bytes:
        """The bytes of one record (for writers that batch); a pcap has one interface."""
        n = len(data)
        return self._hdr.pack(ts_ns // 1_000_000_000, ts_ns % 1_000_000_000, n, n) + data

    def write(self, ts_ns: int, data: bytes, flags: int = 0) -> None:
        self.fh.write(self.record(ts_ns, data, flags))


class PcapngWriter:
    """pcapng with one interface (if_tsresol 9: nanoseconds); EPB flags carry direction."""

    def __init__(
        self,
        fh: BinaryIO,
        linktype: int = LINKTYPE_ETHERNET,
        snaplen: int = 262144,
        if_name: str | None = None,
        if_description: str | None = None,
        comment: str | None = None,
    ) -> None:
        self.fh = fh
        shb_opts = _opt(1, comment.encode()) if comment else b""
        shb_opts += _opt(4, b"sharedlink") + _opt(0, b"")
        body = struct.pack("<IHHq", PCAPNG_BOM, 1, 0, -1) + shb_opts
        fh.write(_block(PCAPNG_SHB, body))
        opts = b""
        if if_name:
            opts += _opt(2, if_name.encode())
        if if_description:
            opts += _opt(3, if_description.encode())
        opts += _opt(9, b"\x09") + _opt(0, b"")
        fh.write(_block(1, struct.pack("<HHI", linktype, 0, snaplen) + opts))
        self.interfaces = 1

    def interface(self, linktype: int, snaplen: int = 262144) -> bytes:
        """The bytes of one more Interface Description Block (nanosecond times), to write before
        the records on it; its id is ``interfaces - 1`` after the call."""
        self.interfaces += 1
        return _block(1, struct.pack("<HHI", linktype, 0, snaplen) + _opt(9, b"\x09") + _opt(0, b""))

    def record(self, ts_ns: int, data: bytes, flags: int = 0, interface: int = 0) -> bytes:
        n = len(data)
        pad = (-n) & 3
        opts = struct.pack("<HHI", 2, 4, flags) + b"\0\0\0\0" if flags else b""
        total = 32 + n + pad + len(opts)
        return (
            struct.pack("<IIIIIII", 6, total, interface, ts_ns >> 32, ts_ns & 0xFFFFFFFF, n, n)
            + data
            + b"\0" * pad
            + opts
            + struct.pack("<I", total)
        )

    def write(self, ts_ns: int, data: bytes, flags: int = 0) -> None:
        self.fh.write(self.record(ts_ns, data, flags))


def _opt(code: int, value: bytes) -> bytes:
    return struct.pack("<HH", code, len(value)) + value + b"\0" * ((-len(value)) & 3)


def _block(btype: int, body: bytes) -> bytes:
    total = 12 + len(body)
    return struct.pack("<II", btype, total) + body + struct.pack("<I", total)


def make_writer(fh: BinaryIO, fmt: str = "pcap", linktype: int = LINKTYPE_ETHERNET, **kw: object) -> PcapWriter | PcapngWriter:
    if fmt == "pcap":
        return PcapWriter(fh, linktype)
    if fmt == "pcapng":
        return PcapngWriter(fh, linktype, **kw)  # type: ignore[arg-type]
    raise ValueError(f"unknown capture format {fmt!r} (pcap or pcapng)")


#: the output path that means standard output
STDOUT_PATH = "-"


def is_stdout(path: str | Path | None) -> bool:
    return path is not None and str(path) == STDOUT_PATH


def _descriptor_name(path: Path) -> bool:
    """Whether ``path`` names a file descriptor (``/dev/stdout``, ``/dev/fd/N``, ``/proc/...``:
    links to whatever the descriptor is, a redirected regular file included)."""
    text = str(path)
    return text.startswith(("/proc/", "/dev/fd/", "/dev/std")) or os.path.realpath(text).startswith("/proc/")


def _in_place(path: Path) -> bool:
    """Whether ``path`` must be written where it is: anything but a regular file (a FIFO, a
    terminal, a device, a socket) and a file descriptor's name."""
    if _descriptor_name(path):
        return True
    try:
        return not stat.S_ISREG(os.stat(path).st_mode)
    except OSError:
        return False  # does not exist (yet): a new regular file


#: ``--force``: an output that is a symbolic link is replaced (the link itself, never its target)
#: instead of refused; set by :func:`replacing_links` around a command
_REPLACE_LINKS: ContextVar[bool] = ContextVar("replace_links", default=False)


@contextmanager
def replacing_links(force: bool = True) -> Iterator[None]:
    """Within the block, :func:`open_output` (and :class:`DeferredOutput`) replace an output
    that is a symbolic link by the new file when ``force`` (a command's ``--force``)."""
    token = _REPLACE_LINKS.set(force)
    try:
        yield
    finally:
        _REPLACE_LINKS.reset(token)


def check_link(path: str | Path) -> bool:
    """An output never follows a symbolic link onto another file: ``path`` being a link to a
    regular file, or to nothing (a dangling link: never created through), raises
    :class:`~sharedlink.errors.OutputError`; under ``--force`` (:func:`replacing_links`) the
    answer is True: the link itself is to be replaced. False: not a link, a file descriptor's
    name (``/dev/stdout``), or a link to a special file (a FIFO, a device), written in place."""
    p = Path(path)
    if not os.path.islink(p) or _descriptor_name(p):
        return False
    try:
        if not stat.S_ISREG(os.stat(p).st_mode):
            return False
        what = "a symbolic link to"
    except OSError:
        what = "a dangling symbolic link to"
    if _REPLACE_LINKS.get():
        return True
    raise OutputError(f"{display_name(p)}: is {what} {display_name(os.readlink(p))}: refusing to write through it "
                      "(--force replaces the link itself)")


def display_name(name: str | Path) -> str:
    """A file name as text that can be written anywhere: bytes that are not UTF-8 (which
    Python keeps as surrogates) become U+FFFD."""
    return os.fsencode(str(name)).decode("utf-8", "replace")


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name one file (the same inode: hard links and symbolic links too)."""
    try:
        sa, sb = os.stat(a), os.stat(b)
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def refuse_overwrite(output: str | Path | None, *inputs: str | Path | None) -> None:
    """Raise :class:`~sharedlink.errors.OutputError` when ``output`` is one of ``inputs``
    (same inode): writing it would destroy the data being read."""
    if output is None or is_stdout(output):
        return
    for inp in inputs:
        if inp is not None and not is_stdout(inp) and same_file(output, inp):
            raise OutputError(f"{output}: is the input {inp}: refusing to overwrite it (write elsewhere)")


@contextmanager
def open_output(path: str | Path, mode: str = "wb", inputs: Iterable[str | Path | None] = (), **kw: Any) -> Iterator[IO[Any]]:
    """The one way a command writes a file: a context manager giving the open file.

    * ``-``: standard output (not closed).
    * Special files (FIFO, terminal, ``/dev/stdout`` and the rest of ``/dev`` and ``/proc``):
      opened and written in place, never replaced.
    * A regular file: written to a hidden sibling ``.<name>.<random>.part`` that is renamed over
      it only when the block ends without an exception.
    * A symbolic link to a regular file or to nothing: refused (:func:`check_link`), or under
      ``--force`` replaced itself by the new file; its target is never written. On any exception (a full disk, Ctrl-C, SIGTERM) the sibling is removed: the
      old file, if any, stays as it was, and nothing is left behind.

    ``inputs``: files being read; writing over one of them is refused (:func:`refuse_overwrite`).
    An ``OSError`` opening, writing or closing becomes :class:`~sharedlink.errors.OutputError`
    naming ``path``.
    """
    refuse_overwrite(path, *inputs)
    if is_stdout(path):
        yield sys.stdout.buffer if "b" in mode else sys.stdout
        (sys.stdout.buffer if "b" in mode else sys.stdout).flush()
        return
    p = Path(path)
    replace_link = check_link(p)
    try:
        if not replace_link and _in_place(p):
            with open(p, mode, **kw) as fh:
                yield fh
            return
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise OutputError(f"{path}: {exc.strerror or exc}") from None
    # Ctrl-C or SIGTERM held while the temporary file is made, so one arriving then is taken
    # inside the try whose finally removes the file (a signal between mkstemp and the try left it)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        target = Path(os.path.realpath(p.parent)) / p.name if replace_link else Path(os.path.realpath(p))
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    except OSError as exc:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        raise OutputError(f"{path}: {exc.strerror or exc}") from None
    tmp = Path(tmp_name)
    try:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        try:
            os.chmod(tmp, _new_file_mode(target))
            with open(fd, mode, **kw) as fh:
                yield fh
            tmp.replace(target)
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise OutputError(f"{path}: {exc.strerror or exc}") from None
    finally:
        if tmp.exists():
            tmp.unlink()


class DeferredOutput:
    """A binary output file opened only by :meth:`open`, for a live capture: its file is opened
    once the device is, so a capture that cannot start leaves an existing file untouched; what
    is written before is held until then. Written in place and flushed as written (not replaced
    at the end: the file can be read while it grows and survives a kill). A symbolic link is
    refused, or replaced under ``--force`` (:func:`check_link`), when the object is made."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._replace_link = check_link(self.path)
        self._fh: BinaryIO | None = None
        self._held = bytearray()

    def open(self) -> None:
        """Open (create or truncate) the file and write what was held; OutputError naming it."""
        try:
            if self._replace_link:
                self.path.unlink()
            fh = open(self.path, "wb")  # noqa: SIM115 - closed by close()
            fh.write(self._held)
            fh.flush()
        except OSError as exc:
            raise OutputError(f"{display_name(self.path)}: {exc.strerror or exc}") from None
        self._fh, self._held = fh, bytearray()

    def write(self, data: bytes) -> int:
        if self._fh is None:
            self._held += data
            return len(data)
        return self._fh.write(data)

    def flush(self) -> None:
        if self._fh is not None:
            self._fh.flush()

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()

    def __enter__(self) -> DeferredOutput:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextmanager
def buffered_stdout(binary: bool = True) -> Iterator[IO[Any]]:
    """Standard output opened again as a buffered stream of its own (closing it leaves the
    descriptor open), for output written while a signal handler that does not raise is in
    place (a live capture's, or Ctrl-C held until a frame is written).

    Under ``python -u`` / PYTHONUNBUFFERED=1 ``sys.stdout.buffer`` is the raw file: a write
    there that a signal interrupts after part of it went into a pipe (the reader lagging)
    returns that part, and ``write``'s callers drop the rest, so a record or a line is cut
    short and the next follows (measured: a pcapng block of 4140 bytes written as 44, exit 0).
    A BufferedWriter writes the rest. Where standard output has no descriptor (replaced in
    process), that stream itself.

    The caller flushes what it counts as written: closing the stream once the reader is gone
    (the caller saw BrokenPipeError flushing, and stopped) drops the unflushed rest quietly."""
    sys.stdout.flush()
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation: no descriptor
        yield sys.stdout.buffer if binary else sys.stdout
        return
    if binary:
        fh: IO[Any] = open(fd, "wb", closefd=False)
    else:
        fh = open(fd, "w", encoding=sys.stdout.encoding, errors=sys.stdout.errors, closefd=False)
    try:
        yield fh
    finally:
        try:
            fh.close()
        except BrokenPipeError:
            pass


def _new_file_mode(target: Path) -> int:
    """The mode the finished file gets: the old file's, else what ``open`` would give."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


@contextmanager
def rereadable(path: str | Path) -> Iterator[Path]:
    """A path that can be read more than once: ``path`` itself when it is a regular file, else
    (a pipe such as ``<(cat capture.pcap)``, a FIFO) a temporary copy of everything it gives,
    read once and removed after the block. For readers that need two passes."""
    p = Path(path)
    try:
        regular = stat.S_ISREG(os.stat(p).st_mode)
    except OSError:
        regular = True  # missing: the reader reports it
    if regular:
        yield p
        return
    src = _open_input(str(p))
    fd, name = tempfile.mkstemp(prefix="sharedlink-", suffix=".spool")
    _SPOOLS[name] = str(p)
    try:
        with src, open(fd, "wb") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
        yield Path(name)
    finally:
        del _SPOOLS[name]
        os.unlink(name)


#: the copies :func:`rereadable` made -> the name the user gave (``/dev/null``, ``/dev/fd/63``):
#: what the readers name in their errors
_SPOOLS: dict[str, str] = {}


def shown_name(path: str | Path) -> str:
    """The name messages give ``path``: the user's name for a copy :func:`rereadable` made."""
    return _SPOOLS.get(str(path), str(path))


#: the old name of :func:`open_output`
atomic_open = open_output


# -- reading ------------------------------------------------------------------------------


def read_records(path: str | Path, chunk: int = 1 << 20) -> Iterator[Record]:
    """Yield the records of a pcap or pcapng file, one at a time.

    On damage it yields every good record before it, then raises :class:`CaptureError`
    naming the file and the record. The file is read once, front to back: a pipe will do.
    """
    fh = _open_input(str(path))
    try:
        yield from records_from(fh, shown_name(path))
    finally:
        fh.close()


def open_records(path: str | Path) -> tuple[str, Iterator[Record]]:
    """``("pcap" or "pcapng", the records)`` of a capture, the file opened once (a pipe will
    do). A missing, empty or foreign file raises :class:`CaptureError` here."""
    fh = _open_input(str(path))
    p = shown_name(path)
    try:
        head = fh.read(4)
        fmt = capture_format(p, head)
    except BaseException:
        fh.close()
        raise

    def records() -> Iterator[Record]:
        try:
            yield from records_from(fh, p, head)
        finally:
            fh.close()

    return fmt, records()


def capture_format(p: str, head: bytes) -> str:
    """"pcapng" or "pcap" from a file's first four bytes (CaptureError for fewer)."""
    if len(head) < 4:
        raise CaptureError(p, None, "file too short to be a capture" if head else "empty file")
    return "pcapng" if struct.unpack("<I", head[:4])[0] == PCAPNG_SHB else "pcap"


def records_from(fh: BinaryIO, p: str, head: bytes = b"") -> Iterator[Record]:
    """The records of capture ``p`` open as ``fh``, whose first bytes ``head`` were read
    already (a pipe cannot seek back to them): the one record walker's
    (:func:`sharedlink.capture.pcap_blocks.walk_records`)."""
    from sharedlink.capture.pcap_blocks import walk_records  # (it builds on this module)

    src: Any = _Prefixed(head, fh) if head else fh
    first = src.read(4)
    capture_format(p, first)
    yield from walk_records(src, p, first, records=True)


def _open_input(p: str) -> BinaryIO:
    try:
        return open(p, "rb")
    except OSError as exc:
        raise CaptureError(shown_name(p), None, exc.strerror or str(exc)) from None


class _Prefixed:
    """A binary file whose first bytes were read already: ``read`` gives them first."""

    def __init__(self, head: bytes, fh: BinaryIO) -> None:
        self._head, self._fh = head, fh

    def read1(self, n: int = -1) -> bytes:
        if not self._head:
            read1 = getattr(self._fh, "read1", None)
            return read1(n) if read1 is not None else self._fh.read(n)
        return self.read(min(n, len(self._head)) if n >= 0 else len(self._head))

    def read(self, n: int = -1) -> bytes:
        if not self._head:
            return self._fh.read(n)
        if n < 0:
            out, self._head = self._head + self._fh.read(), b""
            return out
        out, self._head = self._head[:n], self._head[n:]
        if len(out) < n:
            out += self._fh.read(n - len(out))
        return out


def pcap_header(p: str, header: bytes) -> tuple[str, int, int]:
    """``(endian, nanoseconds per time unit, link type)`` of a classic pcap file header (24
    bytes). Raises :class:`CaptureError` where tshark refuses the file: a major version
    below 2, reserved bits set in the link-type field, a link type nobody registered."""
    head = header[:4]
    for endian in ("<", ">"):
        magic = struct.unpack(endian + "I", head)[0]
        if magic in (PCAP_MAGIC_US, PCAP_MAGIC_NS):
            break
    else:
        raise CaptureError(p, None, f"not a pcap or pcapng file (magic {head.hex()})")
    if len(header) < 24:
        raise CaptureError(p, None, "truncated pcap file header")
    major, _minor, _zone, _sigfigs, _snaplen, network = struct.unpack(endian + "HHiIII", header[4:24])
    if major < 2:
        raise CaptureError(p, None, f"pcap major version {major} is not supported (damaged header?)")
    if network & PCAP_LINKTYPE_RESERVED:
        raise CaptureError(p, None, f"link-type field has reserved bits set (0x{network:08x}): damaged header")
    linktype = network & 0xFFFF
    if linktype not in KNOWN_LINKTYPES:
        raise CaptureError(p, None, f"unknown link type {linktype} (damaged header?)")
    return endian, (1 if magic == PCAP_MAGIC_NS else 1000), linktype


def _interface(body: bytes, endian: str, p: str, number: int) -> tuple[int, int, int]:
    """An interface description block: ``(link type, time units a second, time offset ns)``;
    each interface has its own time resolution (if_tsresol, default microseconds) and time
    offset (if_tsoffset, seconds added to every time on it)."""
    if len(body) < 8:
        raise CaptureError(p, number, "truncated interface description")
    linktype = struct.unpack(endian + "H", body[:2])[0]
    units, offset = 1_000_000, 0
    for code, val in _options(body[8:], endian):
        if code == 9 and val:
            r = val[0]
            units = 2 ** (r & 0x7F) if r & 0x80 else 10 ** (r & 0x7F)
        elif code == 14 and len(val) == 8:
            offset = struct.unpack(endian + "q", val)[0] * 1_000_000_000
    return linktype, units, offset


def _packet(btype: int, body: bytes, endian: str, interfaces: list[tuple[int, int, int]], snaplens: list[int],
            p: str, number: int) -> Record:
    """An enhanced, simple or (obsolete) packet block: its record."""
    if btype == BT_SPB:
        if not interfaces or len(body) < 4:
            raise CaptureError(p, number, "simple packet block without interface")
        orig = struct.unpack(endian + "I", body[:4])[0]
        # the captured length is not stored: the original length, cut at interface 0's
        # SnapLen (the block's padding is no packet data)
        return Record(number, 0, interfaces[0][0], body[4 : 4 + (min(orig, snaplens[0]) if snaplens[0] else orig)], orig)
    if len(body) < 20:
        raise CaptureError(p, number, "truncated enhanced packet block" if btype == BT_EPB else "truncated packet block")
    if btype == BT_EPB:
        iface, hi, lo, incl, orig = struct.unpack(endian + "IIIII", body[:20])
    else:  # interface id and drops count are 16 bits each
        iface, _drops, hi, lo, incl, orig = struct.unpack(endian + "HHIIII", body[:20])
    if iface >= len(interfaces):
        raise CaptureError(p, number, f"packet on undeclared interface {iface}")
    if 20 + incl > len(body):
        raise CaptureError(p, number, "packet data longer than its block")
    flags = 0
    optstart = 20 + incl + ((-incl) & 3)
    if optstart < len(body):
        for code, val in _options(body[optstart:], endian):
            if code == 2 and len(val) == 4:
                flags = struct.unpack(endian + "I", val)[0]
    linktype, units, offset = interfaces[iface]
    ts = (hi << 32) | lo
    ts_ns = (ts * 1_000_000_000 // units if units != 1_000_000_000 else ts) + offset
    return Record(number, ts_ns, linktype, body[20 : 20 + incl], orig, flags, iface)


def _options(buf: bytes, endian: str) -> Iterator[tuple[int, bytes]]:
    i = 0
    while i + 4 <= len(buf):
        code, length = struct.unpack(endian + "HH", buf[i : i + 4])
        if code == 0:
            return
        val = buf[i + 4 : i + 4 + length]
        yield code, val
        i += 4 + length + ((-length) & 3)
