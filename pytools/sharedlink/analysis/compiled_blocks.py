"""The block tier of the core's compiled layouts (changes only): many records of a direction at once.

:class:`sharedlink.analysis.core.compiled.Compiled` ``take`` decodes a run of records of a direction one
at a time; once the run is long (:data:`BLOCK_AFTER` records in a row) it asks the direction's
block taker (:func:`block_taker`) for the records that follow: one ``findall`` of the direction's
compiled layout, with the pcap record and packet headers around it, over a window of the pcap
block, and C-level passes over the columns that gives (lengths, checksums, values changed, full
frames), no Python code per frame. It takes the records from the window's start while each is one
the per-record loop would take with the same result, and stops before the first it would not
(that one goes back to the per-record loop, which takes it or hands it to the reference path).

A frame that gives a variable its first value ends the block before it (the per-record loop
reports first values and makes the layouts again), and the block tier keeps
the same state as the per-record loop (``cur``, the variables changed, the sync clock), so a run
may go from one to the other at any record: the results are the same.
"""

from __future__ import annotations

import re
import sys
from array import array
from collections import deque
from collections.abc import Callable
from itertools import chain, compress, count, repeat
from operator import add, and_, lshift, mul, ne, or_, setitem
from struct import pack
from zlib import adler32

from sharedlink.analysis.core.checksum import low_sum_table
from sharedlink.analysis.core.patterns import cached_pattern
from sharedlink.capture.pcapio import NS

#: records a direction's per-record loop takes in a row before its block taker is asked
BLOCK_AFTER = 16
#: bytes of the pcap block one call looks at: it starts at BLOCK_MIN, doubles while calls take
#: everything they looked at, and drops to twice what a call took when one stops short
BLOCK_MIN = 1 << 12
BLOCK_MAX = 1 << 22
#: one record of a plain Ethernet/IPv4/UDP datagram of one conversation (its addresses and ports
#: go in the middle), not a fragment: a group of its first 58 bytes (pcap record header, Ethernet,
#: IP and UDP headers); the frame's pattern follows (a group, then its values and checksum)
_RECORD = rb"(?s)(.{28}\x08\x00\x45.{5}[\x00\x40]\x00.\x11..%s.{4})"
#: block patterns, shared by the directions that have the same layouts and addresses
_BLOCK_PATTERNS: dict[bytes, Callable] = {}
MAX_BLOCK_PATTERNS = 256
_LITTLE = sys.byteorder == "little"
#: the bytes a value may not hold (the per-record loop's value class leaves them out)
_NOT_VALUE = bytes(range(32)) + b"[]"
#: the checksum digits as a little-endian 16-bit number -> the low byte of 1 + the byte sum of a
#: frame whose checksum they are: the 1, "[" (91), the digits, "]" CR LF (116) and the value, as
#: the frame's other bytes add up to the value (0: not two upper-case hex digits)
_CKLOW = low_sum_table()
#: a frame's size -> the captured length, IP total length and UDP length of a record that holds
#: just its datagram, as :func:`_lengths` gives them
_LENGTHS = [pack("<I", n + 42) + pack(">HH", n + 28, n + 8) for n in range(257)]


def _findall(pattern: bytes) -> Callable:
    return cached_pattern(_BLOCK_PATTERNS, MAX_BLOCK_PATTERNS, pattern, "findall")


def block_taker(key: bytes, frame_named: bytes | None, frame_pos: bytes | None, value: bytes, nslots: list[int],
                pslots: list[int], cur: list, rec: list[bytes], sync: list) -> Callable:
    """The block tier of one direction's compiled layouts (see the module doc).

    ``frame_named`` and ``frame_pos``: the patterns of a frame in the direction's named and
    positional layouts (None: that form has none), as the per-record loop matches them: each value
    a group of ``value`` (a byte class: ``+`` named, ``*`` positional), then the checksum digits;
    ``nslots``/``pslots``: the variable each value group is; ``cur``: the variables' texts
    (bytes), kept in step; ``rec``: what a change record holds before a variable's value;
    ``sync``: the direction's sync entry (``sync[1]``: its last full frame's time).

    The taker is called as ``take(buf, off, number, mult, lane, bulk, positional, bare_ok,
    changed)`` (``bulk``: four extends, of the chunk's packed times, numbers, change records and
    the full frames' times; ``bare_ok``: a bare ``N0`` frame is a named one here; ``changed``: gets
    each variable whose value changed) and returns None when it took nothing, else ``(offset,
    number, frames taken, their captured bytes, number of the last full frame or None, whole)``,
    ``whole`` False when it stopped short of what it looked at (the next record is not one for it)."""
    patterns: dict[bytes, Callable] = {}
    window = [BLOCK_MIN]
    forms = _fast_forms(frame_named, frame_pos, value, nslots, pslots)

    def take(buf: bytes, off: int, number: int, mult: int, lane: bytes, bulk: tuple, positional: bool,
             bare_ok: bool, changed: Callable) -> tuple[int, int, int, int, int | None, bool] | None:
        frame = forms.get(positional)
        if frame is None or not _LITTLE:
            return None
        pk = lane + (b"D" if positional else b"Q")
        findall = patterns.get(pk)
        if findall is None:
            if len(patterns) >= 8:
                patterns.clear()
            findall = patterns[pk] = _findall(_RECORD % re.escape(lane) + b"(" + frame + b")")
        rows = findall(buf, off, off + window[0])
        n = len(rows)
        cols = list(zip(*rows))
        k = _rows_taken(buf, off, rows, cols, not positional and not bare_ok) if n else 0
        vals = cols[2:-1]
        # a first value (a variable without one present) ends the block before its frame: the
        # per-record loop reports it and the layouts are made again
        slots = pslots if positional else nslots
        valued = [cur[s] is not None for s in slots]
        for col, v in zip(vals, valued):
            if not v:
                k = min(k, next(compress(count(), col), k))
        if not k or True not in valued:
            window[0] = BLOCK_MIN
            return None
        sizes = list(map(len, cols[1][:k]))
        hj = b"".join(cols[0][:k])  # 58 bytes a row
        if k == n:
            window[0] = min(BLOCK_MAX, window[0] * 2)
        else:
            window[0] = max(BLOCK_MIN, 2 * (sum(sizes) + 58 * k))
            vals = [c[:k] for c in vals]
        vals = list(compress(vals, valued))
        ts_ext, num_ext, rec_ext, full_ext = bulk
        pieces, dense = _change_pieces(vals, list(compress(slots, valued)), cur, rec, k, changed)
        rec_ext(map(b"".join, zip(repeat(key, k), *pieces)) if pieces else repeat(key, k))
        hdr = _field(hj, 0, 8, False, "I")  # seconds and fractions, two a row
        if mult == 1:  # the packed time is the record header's first 8 bytes
            ts_ext(array("Q", hdr.tobytes()))
        else:
            ts_ext(map(or_, hdr[0::2], map(lshift, map(mul, hdr[1::2], repeat(mult)), repeat(32))))
        num_ext(array("q", pack("<%dq" % k, *range(number + 1, number + k + 1))))
        last = _full_frames(hdr, vals, dense, mult, sync, full_ext)
        wire = sum(sizes) + 42 * k
        return off + wire + 16 * k, number + k, k, wire, number + last + 1 if last >= 0 else None, k == n

    return take


def _fast_forms(frame_named: bytes | None, frame_pos: bytes | None, value: bytes, nslots: list[int],
                pslots: list[int]) -> dict[bool, bytes]:
    """The block tier's patterns of a frame, by form (True: positional): the same layouts, matched
    faster: a value is anything up to the next "|" (the bytes the per-record class leaves out are
    looked for in the values afterwards, all at once) and an optional named value is an
    alternative with nothing (one step for sre, not a repeat)."""
    forms = {}
    if frame_named is not None:
        fast = frame_named.replace(b"(" + value + b"+))?", rb"([^|]+)|)")
        if fast.count(rb"([^|]+)|)") == len(nslots):
            forms[False] = fast
    if frame_pos is not None:
        fast = frame_pos.replace(b"(" + value + b"*)", rb"([^|]*)")
        if fast.count(rb"([^|]*)") == len(pslots):
            forms[True] = fast
    return forms


def _rows_taken(buf: bytes, off: int, rows: list[tuple], cols: list[tuple], no_bare: bool) -> int:
    """How many of a block's rows (``cols``: its columns, head, frame, values, checksum) from
    ``off`` on the block tier may take: the rows must be the records from ``off`` on, one after
    the other (findall skips what does not match), each holding just its datagram (captured
    length = 42 + the frame), its IP and UDP lengths right, its frame at most 256 bytes (the
    checksum below) with a right checksum, its values without the bytes the per-record loop's
    class leaves out, and (``no_bare``) no bare N0: the per-record loop's checks, at C speed; the
    first row that fails one ends the block (found the slow way)."""
    heads, frames, cks = cols[0], cols[1], cols[-1]
    sizes = list(map(len, frames))
    hj = b"".join(heads)
    if (max(sizes) <= 256 and buf.startswith(b"".join(chain.from_iterable(zip(heads, frames))), off)
            and _lengths(hj) == b"".join(map(_LENGTHS.__getitem__, sizes))
            and not (no_bare and 14 in sizes)
            and bytes(map(and_, map(adler32, frames), repeat(255)))
            == bytes(map(_CKLOW.__getitem__, array("H", b"".join(cks))))
            and all(len(j) == len(j.translate(None, _NOT_VALUE)) for j in map(b"".join, cols[2:-1]))):
        return len(rows)
    return _first_bad(buf, off, rows, hj, no_bare)


def _change_pieces(vals: list, slots: list[int], cur: list, rec: list[bytes], k: int, changed: Callable
                   ) -> tuple[list, int]:
    """The change records of ``k`` rows: for each variable (``vals``: the columns of the variables
    that have a value, ``slots``: which they are) a column of what a record holds of it (b""
    when the frame did not change it); ``cur`` kept in step, ``changed`` told. Returns the
    columns and how many variables every row has."""
    pieces: list = []
    dense = 0
    for col, s in zip(vals, slots):
        if b"" not in col:  # every frame has it (a full stream)
            dense += 1
            present, where = col, None
        else:
            present = list(compress(col, col))  # (an absent value is b"")
            if not present:
                continue
            where = compress(range(k), col)
        diff = list(map(ne, present, chain((cur[s],), present)))
        changes = diff.count(True)
        if not changes:
            continue
        if changes == k:  # every frame changed it
            pieces += (repeat(rec[s], k), present)
        else:
            piece = [b""] * k
            deque(map(setitem, repeat(piece), compress(where or range(k), diff),
                      map(add, repeat(rec[s]), compress(present, diff))), maxlen=0)
            pieces.append(piece)
        cur[s] = present[-1]
        changed(s)
    return pieces, dense


def _full_frames(hdr: array, vals: list, dense: int, mult: int, sync: list, full_ext: Callable) -> int:
    """The full frames of a block's rows (every variable that has a value present): their times
    to ``full_ext``, the sync clock set to the last one's; returns its index (-1: none)."""
    k = len(hdr) // 2
    if dense == len(vals):
        secs, fracs = hdr[0::2], hdr[1::2]
        last = k - 1
    else:
        mask = list(map(all, zip(*vals)))
        last = k - 1 - mask[::-1].index(True) if True in mask else -1
        secs, fracs = compress(hdr[0::2], mask), compress(hdr[1::2], mask)
    if last >= 0:
        full_ext(map(add, map(mul, secs, repeat(NS)), map(mul, fracs, repeat(mult))))
        sync[1] = hdr[2 * last] * NS + hdr[2 * last + 1] * mult
    return last


def _field(heads: bytes, at: int, size: int, big: bool, code: str = "") -> array:
    """A field of every row of ``heads`` (58 bytes a row): ``size`` bytes at ``at``, as an array
    of native integers (``code``, else one of that size), read big-endian when ``big``."""
    ba = bytearray(len(heads) // 58 * size)
    for j in range(size):
        ba[j::size] = heads[at + (size - 1 - j if big else j) :: 58]
    a = array(code or ("H" if size == 2 else "I"))
    a.frombytes(ba)
    return a


def _lengths(heads: bytes) -> bytes:
    """The captured length (4 bytes, little-endian), IP total length and UDP length (2 bytes each,
    big-endian) of every row of ``heads`` (58 bytes a row), 8 bytes a row."""
    ba = bytearray(len(heads) // 58 * 8)
    for j, at in enumerate((8, 9, 10, 11, 32, 33, 54, 55)):
        ba[j::8] = heads[at::58]
    return bytes(ba)


def _first_bad(buf: bytes, off: int, rows: list[tuple], heads: bytes, no_bare: bool) -> int:
    """The index of the first row of a block the block tier must not take (see its checks)."""
    at = off
    for i, (h, f, *vs, ck) in enumerate(rows):
        n = len(f)
        if (n > 256 or not buf.startswith(h, at) or not buf.startswith(f, at + 58)
                or heads[58 * i + 8 : 58 * i + 12] + heads[58 * i + 32 : 58 * i + 34] + heads[58 * i + 54 : 58 * i + 56]
                != _LENGTHS[n]
                or (no_bare and n == 14) or (adler32(f) & 255) != _CKLOW[int.from_bytes(ck, "little")]
                or any(len(v) != len(v.translate(None, _NOT_VALUE)) for v in vs)):
            return i
        at += 58 + n
    return len(rows)
