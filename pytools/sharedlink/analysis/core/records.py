"""The records of a capture as the core walks them: a regular pcap or pcapng file through the one
record walker (:func:`sharedlink.capture.pcap_blocks.walk_records`; in a classic pcap file a run
taker offered each record), anything else (a pipe) through
:func:`~sharedlink.capture.pcapio.read_records` (the same walker behind a Record each)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

from sharedlink.capture.pcap_blocks import PCAPNG_HEAD, RUN, walk_records
from sharedlink.capture.pcapio import PCAP_MAGIC_NS, PCAP_MAGIC_US, open_records, read_records, shown_name

__all__ = ["RUN", "capture_records", "open_capture"]

#: a classic pcap file's first four bytes, either byte order
_PCAP_HEADS = {m.to_bytes(4, e) for m in (PCAP_MAGIC_NS, PCAP_MAGIC_US) for e in ("little", "big")}


def capture_records(path: str | Path, fast: Callable | None = None) -> Iterator[tuple[int, int, int, bytes, int, int]]:
    """``(number, ts_ns, link type, data, flags, interface)`` of every record: a regular pcap or
    pcapng file read in blocks (no Record object for classic pcap, one read a block), anything else through
    :func:`~sharedlink.capture.pcapio.read_records`. The same records and the same
    :class:`~sharedlink.capture.pcapio.CaptureError` s either way. ``fast``
    (:meth:`Decoder.column_run` or :meth:`Decoder.count_run`, for little-endian Ethernet pcap
    files): offered each record of a block first; a run it takes comes as one item with link
    type :data:`~sharedlink.capture.pcap_blocks.RUN`."""
    walk = _walk(path, fast)
    if walk is not None:
        return walk[1]
    return ((r.number, r.ts_ns, r.linktype, r.data, r.flags, r.interface) for r in read_records(path))


def open_capture(path: str | Path, fast: Callable | None = None) -> tuple[str, Iterator[tuple]]:
    """``("pcap" or "pcapng", the records as :func:`capture_records` gives them)``: a missing,
    empty or foreign file raises :class:`~sharedlink.capture.pcapio.CaptureError` here, and the
    file is read once (a pipe will do)."""
    walk = _walk(path, fast)
    if walk is not None:
        return walk
    fmt, records = open_records(path)
    return fmt, ((r.number, r.ts_ns, r.linktype, r.data, r.flags, r.interface) for r in records)


def _walk(path: str | Path, fast: Callable | None) -> tuple[str, Iterator[tuple]] | None:
    """The format and walk of a regular pcap or pcapng file (None for anything else)."""
    p = str(path)
    if not os.path.isfile(p):
        return None
    try:
        with open(p, "rb") as fh:
            head = fh.read(24)
    except OSError:
        return None  # read_records reports it
    fmt = "pcapng" if head[:4] == PCAPNG_HEAD else "pcap" if head[:4] in _PCAP_HEADS and len(head) == 24 else None
    if fmt is None:
        return None
    fh = open(p, "rb")  # noqa: SIM115 - the walk closes it
    fh.seek(len(head))
    return fmt, walk_records(fh, shown_name(path), head, fast, closing=True)
