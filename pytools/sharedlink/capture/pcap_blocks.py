"""The one walker of capture records, pcap and pcapng (serial captures are pcapng): a file read a
block at a time, its records cut from the blocks, and the one set of texts for a damaged one.

:func:`walk_records` (:func:`walk_pcap` for classic pcap, :func:`walk_pcapng`) serves
:func:`sharedlink.capture.pcapio.read_records` (as :class:`~sharedlink.capture.pcapio.Record` s)
and the decoding core (as tuples, with a run taker offered each record of a classic pcap file
first: :func:`sharedlink.analysis.core.records.capture_records`); :class:`PcapBlocks` is the block
loop itself, for a reader that walks a block its own way
(:class:`sharedlink.analysis.changes.ChangeReader`). Damage is reported the same way by all:
every record before it first, then a :class:`~sharedlink.capture.pcapio.CaptureError` (a classic
pcap file's from :func:`implausible` or :func:`truncated`).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from typing import Any, BinaryIO

from sharedlink.capture.pcapio import (
    BT_EPB,
    BT_IDB,
    BT_PB,
    BT_SPB,
    FRAME_BLOCKS,
    NS,
    PCAPNG_BOM,
    PCAPNG_SHB,
    CaptureError,
    Record,
    _interface,
    _packet,
    pcap_header,
)

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


#: a pcapng file's first four bytes (the section header block's type reads the same either way)
PCAPNG_HEAD = PCAPNG_SHB.to_bytes(4, "little")


def walk_records(fh: BinaryIO, name: str, head: bytes, offer: Callable | None = None, records: bool = False,
                 closing: bool = False) -> Iterator[Any]:
    """The records of capture ``name``, pcap or pcapng, whose first bytes ``head`` (at least
    four) were read: :func:`walk_pcapng` or :func:`walk_pcap` (``offer`` is for classic pcap
    files only), the same items either way."""
    if head[:4] == PCAPNG_HEAD:
        return walk_pcapng(fh, name, head, records, closing=closing)
    if len(head) < 24:
        head += fh.read(24 - len(head))
    return walk_pcap(fh, name, head, offer, records, closing=closing)


def walk_pcapng(fh: BinaryIO, name: str, head: bytes, records: bool = False, size: int = PCAP_BLOCK,
                closing: bool = False) -> Iterator[Any]:
    """The records of a pcapng file whose first bytes ``head`` were read: as :func:`walk_pcap`
    gives them, ``(number, ts_ns, link type, data, flags, interface)`` each or with ``records`` a
    :class:`~sharedlink.capture.pcapio.Record`; read a block of the file at a time
    (:class:`PcapBlocks`). Blocks that are no packet but that Wireshark numbers take a number;
    a new section starts its interfaces anew. Raises
    :class:`~sharedlink.capture.pcapio.CaptureError` after every record before the damage."""
    try:
        blocks = PcapBlocks(fh, name, size)
        blocks.rest = head
        walk = _PcapngWalk(name)
        for buf in blocks:
            for rec in walk.blocks(buf, blocks.eof):
                yield rec if records else (rec.number, rec.ts_ns, rec.linktype, rec.data, rec.flags, rec.interface)
            blocks.keep(buf, walk.off)
    finally:
        if closing:
            fh.close()


class _PcapngWalk:
    """The state of a pcapng walk: the section's byte order, its interfaces and their SnapLens,
    the records numbered so far; :meth:`blocks` walks a buffer's whole blocks."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.endian = "<"
        self.interfaces: list[tuple[int, int, int]] = []  # (link type, units per second, offset in ns)
        self.snaplens: list[int] = []  # each interface's SnapLen (0: none)
        self.number = 0
        self.first = True
        self.off = 0  # where the last walk stopped

    def blocks(self, buf: bytes, eof: bool) -> Iterator[Record]:
        """The records of ``buf``'s whole blocks (``eof``: no more bytes come: a block cut short
        is damage); :attr:`off` is where the walk stopped."""
        off, end = 0, len(buf)
        name = self.name
        while off < end:
            where = None if self.first else self.number + 1
            if end - off < 8:
                if eof:
                    raise CaptureError(name, where, "truncated block header")
                break
            if self.first or buf[off : off + 4] == PCAPNG_HEAD:
                total = self._section(buf, off, eof, where)
                if total is None:
                    break
                off += total
                continue
            btype, total = struct.unpack_from(self.endian + "II", buf, off)
            if total < 12 or total % 4 or total > MAX_RECORD:
                raise CaptureError(name, self.number + 1, f"bad block length {total} (damaged file)")
            if end - off < total:
                if eof:
                    raise CaptureError(name, self.number + 1, f"truncated block ({end - off} of {total} bytes)")
                break
            body = buf[off + 8 : off + total - 4]
            off += total
            if btype == BT_IDB:
                self.interfaces.append(_interface(body, self.endian, name, self.number + 1))
                self.snaplens.append(struct.unpack_from(self.endian + "I", body, 4)[0])
            elif btype in (BT_EPB, BT_PB, BT_SPB):
                self.number += 1
                yield _packet(btype, body, self.endian, self.interfaces, self.snaplens, name, self.number)
            elif btype in FRAME_BLOCKS:
                self.number += 1  # no packet, but Wireshark gives it a frame number
            # other blocks (name resolution, statistics, secrets) are skipped
        self.off = off

    def _section(self, buf: bytes, off: int, eof: bool, where: int | None) -> int | None:
        """A section header block at ``off``: its length, its byte order and a new section's
        (empty) interfaces taken; None when it is not whole yet."""
        name, have = self.name, len(buf) - off
        if have < 12:
            if eof:
                raise CaptureError(name, where, "truncated section header")
            return None
        for endian in ("<", ">"):
            if struct.unpack_from(endian + "I", buf, off + 8)[0] == PCAPNG_BOM:
                break
        else:
            raise CaptureError(name, where, "bad pcapng byte-order magic")
        total = struct.unpack_from(endian + "I", buf, off + 4)[0]
        if total < 28 or total % 4:
            raise CaptureError(name, where, f"bad section header length {total}")
        if have < total:
            if eof:
                raise CaptureError(name, where, "truncated section header")
            return None
        self.endian, self.interfaces, self.snaplens, self.first = endian, [], [], False
        return total
