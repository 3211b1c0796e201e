"""The one walker of classic pcap records: a file read a block at a time, its records cut from
the blocks, and the one set of texts for a damaged one.

:func:`walk_pcap` serves :func:`sharedlink.capture.pcapio.read_records` (as
:class:`~sharedlink.capture.pcapio.Record` s) and the decoding core (as tuples, with a run taker
offered each record first: :func:`sharedlink.analysis.core.records.capture_records`);
:class:`PcapBlocks` is the block loop itself, for a reader that walks a block its own way
(:class:`sharedlink.analysis.changes.ChangeReader`). Damage is reported the same way by all:
every record before it first, then a :class:`~sharedlink.capture.pcapio.CaptureError` from
:func:`implausible` or :func:`truncated`.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from typing import Any, BinaryIO

from sharedlink.capture.pcapio import NS, CaptureError, Record, pcap_header

#: bytes of a classic pcap file read at a time
PCAP_BLOCK = 1 << 20
#: a record longer than this is damage (as tshark: 64 MiB)
MAX_RECORD = 0x4000000
#: the link type :func:`walk_pcap` gives a run ``offer`` took: ``(last number, frames, RUN, b"", bytes, 0)``
RUN = -1


def implausible(name: str, number: int, incl: int) -> CaptureError:
    """The error of record ``number`` whose captured length ``incl`` is past :data:`MAX_RECORD`."""
    return CaptureError(name, number, f"record length {incl} is implausible (damaged file)")


def truncated(name: str, number: int, rest: bytes, endian: str = "<") -> CaptureError:
    """The error of a file that ends inside record ``number`` (``rest``: its bytes)."""
    if len(rest) < 16:
        return CaptureError(name, number, f"truncated record header ({len(rest)} of 16 bytes)")
    incl = struct.unpack_from(endian + "I", rest, 8)[0]
    return CaptureError(name, number, f"truncated record ({len(rest) - 16} of {incl} bytes)")


class PcapBlocks:
    """The blocks of a classic pcap file after its 24-byte header, each with the unwalked tail of
    the one before it in front: iterate, walk each block's whole records and say where the walk
    stopped (:meth:`keep`); after the last block (the one read at the end of the file, possibly
    empty), :meth:`end` raises :func:`truncated` when bytes are left. ``fh.read1`` is used when
    the file has it (a pipe gives what it has: a live capture is not held back)."""

    def __init__(self, fh: Any, name: str, size: int = PCAP_BLOCK) -> None:
        self.name, self.size = name, size
        self._read: Callable[[int], bytes] = getattr(fh, "read1", None) or fh.read
        self.rest = b""
        self.eof = False

    def __iter__(self) -> Iterator[bytes]:
        read, size = self._read, self.size
        while not self.eof:
            data = read(size)
            self.eof = not data
            rest = self.rest
            self.rest = b""
            yield rest + data if rest else data

    def keep(self, buf: bytes, off: int) -> None:
        """The walk of ``buf`` stopped at ``off``: the bytes after it go in front of the next block."""
        self.rest = buf[off:]

    def end(self, number: int, endian: str = "<") -> None:
        """The end of the file, ``number`` records walked: bytes left are a truncated record."""
        if self.rest:
            raise truncated(self.name, number + 1, self.rest, endian)


def walk_pcap(fh: BinaryIO, name: str, head: bytes, offer: Callable | None = None, records: bool = False,
              size: int = PCAP_BLOCK, closing: bool = False) -> Iterator[Any]:
    """The records of a classic pcap file whose first 24 bytes ``head`` were read (``fh`` is
    after them): ``(number, ts_ns, link type, data, 0, 0)`` each, or with ``records`` a
    :class:`~sharedlink.capture.pcapio.Record`. ``offer`` (a run taker, for little-endian
    Ethernet files only: ``offer(buf, sbuf, off, number, mult)`` -> None or ``(offset, number,
    frames, bytes)``) is offered each record of a block first (after misses in a row it skips
    0, 1, 3, 7 ... 63 records: a capture it takes nothing of costs it a call in 64 records); a
    run it takes comes as ``(number, frames, RUN, b"", bytes, 0)``. Raises
    :class:`~sharedlink.capture.pcapio.CaptureError` after every record before the damage.
    ``closing``: ``fh`` is closed when the walk ends (or is given up)."""
    try:
        endian, mult, linktype = pcap_header(name, head)
        offer = offer if endian == "<" and linktype == 1 else None
        unpack = struct.Struct(endian + "IIII").unpack_from
        blocks = PcapBlocks(fh, name, size)
        number = skip = miss = 0
        for buf in blocks:
            end = len(buf)
            off = 0
            sbuf = buf.decode("latin-1") if offer is not None else ""
            while off + 16 <= end:
                if offer is not None:
                    if skip:
                        skip -= 1
                    else:
                        run = offer(buf, sbuf, off, number, mult)
                        if run is not None:
                            miss = 0
                            off, number, taken, wire = run
                            yield number, taken, RUN, b"", wire, 0
                            continue
                        skip = miss
                        miss = min(2 * miss + 1, 63)
                sec, frac, incl, orig = unpack(buf, off)
                if incl > MAX_RECORD:
                    raise implausible(name, number + 1, incl)
                e = off + 16 + incl
                if e > end:
                    break
                number += 1
                if records:
                    yield Record(number, sec * NS + frac * mult, linktype, buf[off + 16 : e], orig)
                else:
                    yield number, sec * NS + frac * mult, linktype, buf[off + 16 : e], 0, 0
                off = e
            blocks.keep(buf, off)
            sbuf = ""  # (at most two blocks' worth held: this one's bytes and text)
        blocks.end(number, endian)
    finally:
        if closing:
            fh.close()
