"""The block tier of :class:`~sharedlink.capture.stream.ChangeReader`: whole blocks at once.

Same contract as the per-record tiers: :func:`take` consumes the records at the start of a
block, appends the same change records and statistics the reference path would, and returns
(bytes consumed, last record number), or None when the block does not qualify (then the
per-record tier takes it: the results are the same). It applies when the capture so far has
one conversation direction whose every value is known (:func:`ready`) and every record of the
block is one plain frame of it: one ``findall`` and C-level passes over the columns, no Python
code per frame.
"""

from __future__ import annotations

import sys
import zlib
from array import array
from collections.abc import Sequence
from itertools import chain, compress, repeat
from operator import add, and_, contains, ge, mul, ne, not_, sub
from typing import TYPE_CHECKING

from sharedlink.capture.fast_records import _CKADJ
from sharedlink.capture.pcapio import LINKTYPE_ETHERNET, NS

if TYPE_CHECKING:
    from sharedlink.capture.stream import ChangeReader


def ready(reader: ChangeReader, linktype: int) -> bool:
    """Whole blocks at once: one direction so far, all its values known (no first-value
    events to report), and the last attempt did not fail."""
    if reader._bulk_backoff:
        reader._bulk_backoff -= 1
        return False
    if not reader.fast_enabled or linktype != LINKTYPE_ETHERNET or len(reader._fast) != 1:
        return False
    fk = next(iter(reader._fast.values()))
    return None not in fk.cur

def take(reader: ChangeReader, buf: bytes, mult: int, number: int) -> tuple[int, int] | None:
    """Take a block where every record is one frame of the only direction in its current
    layout, all at once: one ``findall`` and C-level passes over its columns (no Python
    code per frame). Returns (bytes consumed, last record number), or None when the block
    does not qualify (then the per-record loop does it: the results are the same)."""
    fk = next(iter(reader._fast.values()))
    positional = len(buf) > 66 and buf[66] == 68
    lazy = fk.bulk_pos if positional else fk.bulk_named
    if lazy is None:
        return None
    rx = lazy.get()
    rows = rx.findall(buf)
    n = len(rows)
    if n < 64:
        reader._bulk_backoff = 4
        return None
    cols = list(zip(*rows))
    hdrs, tls, uls, pays, cks = cols[0], cols[1], cols[2], cols[3], cols[-1]
    vals = cols[4:-1]
    sizes = list(map(len, pays))
    if max(sizes) > 256:  # the checksum shortcut below needs short frames
        return None
    total = 58 * n + sum(sizes)
    # the matches must tile the block from its start: then the last one ends at total
    m = rx.match(buf, total - 58 - sizes[-1])
    if m is None or m.end() != total:
        reader._bulk_backoff = 4
        return None
    hdr = array("I")
    hdr.frombytes(b"".join(hdrs))
    lens = array("H")
    lens.frombytes(b"".join(tls))
    lens2 = array("H")
    lens2.frombytes(b"".join(uls))
    if sys.byteorder == "little":
        lens.byteswap()
        lens2.byteswap()
    else:  # pragma: no cover - big-endian hosts
        hdr.byteswap()
    incl = hdr[2::4]
    if (
        incl != array("I", map(add, sizes, repeat(42, n)))
        or lens != array("H", map(add, sizes, repeat(28, n)))
        or lens2 != array("H", map(add, sizes, repeat(8, n)))
    ):
        return None
    # checksums: adler32's low half is 1 + the byte sum for frames up to 256 bytes
    if any(map(and_, map(sub, map(zlib.adler32, pays), map(_CKADJ.__getitem__, cks)), repeat(255, n))):
        return None  # a bad checksum in the block: the per-record loop reports it
    secs, fracs = hdr[0::4], hdr[1::4]
    if max(fracs) >= NS:
        return None
    tsq = array("Q")
    tsq.frombytes(b"".join(hdrs))
    if sys.byteorder != "little":  # pragma: no cover - big-endian hosts
        tsq.byteswap()
    ts = tsq[0::2]  # the first 8 bytes of each record header: pack_ts for nanosecond pcaps
    # changes, column by column
    cur, pre = fk.cur, fk.pre
    slots = fk.pslots if positional else fk.nslots
    pieces = []
    dense = 0
    for col, k in zip(vals, slots):
        last = cur[k]
        if all(col):  # every frame carries it (a full stream)
            dense += 1
            changed = map(ne, col, chain((last,), col))
            pieces.append(list(map(mul, map(add, repeat(pre[k], n), col), changed)))
            cur[k] = col[-1]
        else:  # present in some frames (compressed): look at those only
            piece = [b""] * n
            p = pre[k]
            for i in compress(range(n), col):
                v = col[i]
                if v != last:
                    piece[i] = p + v
                    last = v
            cur[k] = last
            pieces.append(piece)
    key = fk.key
    records = list(map(b"".join, zip(repeat(key, n), *pieces)))
    # full frames: every value present (the block has no first values, so "every value
    # known" is "every value present"); findall gives b"" for an absent named triplet as
    # for an empty positional slot, and the other groups are never empty
    if dense == len(vals) and vals:
        fidx: Sequence[int] = range(n)
    elif vals:
        fidx = list(compress(range(n), map(not_, map(contains, rows, repeat(b"", n)))))
    else:
        fidx = []
    st = reader.stats
    if fidx:
        sy = fk.sync
        limit = 2 * reader.sync_ns - reader.sync_ns // 2
        # only a gap of at least limit // NS whole seconds can reach the limit
        fsecs = [secs[i] for i in fidx] if not isinstance(fidx, range) else secs
        prev_sec = sy[0] // NS
        for j in compress(range(len(fidx)), map(ge, map(sub, fsecs, chain((prev_sec,), fsecs)), repeat(limit // NS))):
            i = fidx[j]
            t_ns = secs[i] * NS + fracs[i]
            p_ns = sy[0] if j == 0 else secs[fidx[j - 1]] * NS + fracs[fidx[j - 1]]
            if t_ns - p_ns >= limit:
                st.sync_missed += reader._missed(t_ns - p_ns)
        last = fidx[-1]
        sy[0] = secs[last] * NS + fracs[last]
    st.full += len(fidx)
    st.records += n
    st.wire_bytes += sum(incl)
    st.payload_bytes += total - 58 * n
    reader._ts.extend(ts)
    reader._num.extend(range(number + 1, number + n + 1))
    reader._recs.extend(records)
    reader._last_ts = secs[-1] * NS + fracs[-1]
    return total, number + n
