"""The records of a capture as the core walks them: a classic pcap file through the one block
walker (:func:`sharedlink.capture.pcap_blocks.walk_pcap`, a run taker offered each record), anything
else through :func:`~sharedlink.capture.pcapio.read_records`."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

from sharedlink.capture.pcap_blocks import RUN, walk_pcap
from sharedlink.capture.pcapio import PCAP_MAGIC_NS, PCAP_MAGIC_US, read_records, shown_name

__all__ = ["RUN", "capture_records"]

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
    p = str(path)
    if os.path.isfile(p):
        try:
            with open(p, "rb") as fh:
                head = fh.read(24)
        except OSError:
            head = b""  # read_records reports it
        if head[:4] in _PCAP_HEADS and len(head) == 24:
            fh = open(p, "rb")  # noqa: SIM115 - the walk closes it
            fh.seek(24)
            return walk_pcap(fh, shown_name(path), head, fast, closing=True)
    return ((r.number, r.ts_ns, r.linktype, r.data, r.flags, r.interface) for r in read_records(path))
