"""SharedLink tools: protocol codecs, capture files, generators and analyses, by role.

Layout (``docs/architecture.md`` is the map):

- ``sharedlink.protocols``: one codec per protocol (``codec`` for SharedLink, ``p2os``,
  ``blackboard``) and the SharedLink variable state (``state``);
- ``sharedlink.capture``: pcap/pcapng I/O, packet headers, the serial capture format and
  live port capture, serial log import, and ``stream`` (records -> datagrams -> frames);
- ``sharedlink.generators``: beacon, P2OS, blackboard and serial session generators;
- ``sharedlink.analysis``: decode, stats, diff, transform (compress/expand), export, plot;
- on top: ``replay``, ``extcap``, ``wireshark``, ``scapy_layer``, ``cli`` and ``commands``.
"""

from __future__ import annotations

from ._interrupt import quiet_interrupt

with quiet_interrupt():  # Ctrl-C while the command loads: exit 130, no traceback
    from .protocols.codec import (
        Checksum,
        Field,
        Frame,
        SharedLinkError,
        build_frame,
        checksum,
        frame_kind,
        iter_segments,
        parse_frame,
        split_frames,
    )

__all__ = [
    "Checksum",
    "Field",
    "Frame",
    "SharedLinkError",
    "build_frame",
    "checksum",
    "frame_kind",
    "iter_segments",
    "parse_frame",
    "split_frames",
]
__version__ = "1.3.0"
