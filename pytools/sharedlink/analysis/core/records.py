"""The records of a capture as the core walks them: a classic pcap file through the one block
walker (:func:`sharedlink.capture.pcap_blocks.walk_pcap`, a run taker offered each record), anything
else through :func:`~sharedlink.capture.pcapio.read_records`."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

from sharedlink.capture.pcap_blocks import RUN, walk_pcap
from sharedlink.capture.pcapio import PCAP_MAGIC_NS, PCAP_MAGIC_US, open_records, read_records, shown_name

__all__ = ["RUN", "capture_records", "open_capture"]

#: a classic pcap file's first four bytes, either byte order
_PCAP_HEADS = {m.to_bytes(4, e) for m in (PCAP_MAGIC_NS, PCAP_MAGIC_US) for e in ("little", "big")}


def capture_records(path: str | Path, fast: Callable | None = None) -> Iterator[tuple[int, int, int, bytes, int, int]]:
    """``(number, ts_ns, link type, data, flags, interface)`` of every record: a regular classic
    pcap file read in blocks (no Record object, one read a block), anything else through
    :func:`~sharedlink.capture.pcapio.read_records`. The same records and the same
    :class:`~sharedlink.capture.pcapio.CaptureError` s either way. ``fast``
    (:meth:`Decoder.column_run` or :meth:`Decoder.count_run`, for little-endian Ethernet pcap
    files): offered each record of a block first; a run it takes comes as one item with link
    type :data:`~sharedlink.capture.pcap_blocks.RUN`."""
    walk = _pcap_walk(path, fast)
    if walk is not None:
        return walk
    return ((r.number, r.ts_ns, r.linktype, r.data, r.flags, r.interface) for r in read_records(path))


def open_capture(path: str | Path, fast: Callable | None = None) -> tuple[str, Iterator[tuple]]:
    """``("pcap" or "pcapng", the records as :func:`capture_records` gives them)``: a missing,
    empty or foreign file raises :class:`~sharedlink.capture.pcapio.CaptureError` here, and the
    file is read once (a pipe will do)."""
    walk = _pcap_walk(path, fast)
    if walk is not None:
        return "pcap", walk
    fmt, records = open_records(path)
    return fmt, ((r.number, r.ts_ns, r.linktype, r.data, r.flags, r.interface) for r in records)


def _pcap_walk(path: str | Path, fast: Callable | None) -> Iterator[tuple] | None:
    """The walk of a regular classic pcap file (None for anything else)."""
    p = str(path)
    if not os.path.isfile(p):
        return None
    try:
        with open(p, "rb") as fh:
            head = fh.read(24)
    except OSError:
        return None  # read_records reports it
    if head[:4] not in _PCAP_HEADS or len(head) != 24:
        return None
    fh = open(p, "rb")  # noqa: SIM115 - the walk closes it
    fh.seek(24)
    return walk_pcap(fh, shown_name(path), head, fast, closing=True)
