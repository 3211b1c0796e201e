"""The decoding core: frames in, :class:`Decoded` frames (typed updates, the table after each) out.

Its code is the package :mod:`sharedlink.analysis.core` (docs/architecture.md, "The decoding
core"); this module is its public face: every name callers import is here.

Every command that decodes goes through :class:`Decoder` (stats, export in every format, plot,
ingest, watch): :func:`iter_decoded` walks a capture (streaming, TCP reassembled, serial captures
deframed per direction, as :func:`sharedlink.capture.stream.iter_frames`) and keeps a
:class:`~sharedlink.protocols.state.LinkState`, so every SharedLink frame comes out as a
:class:`Decoded`: its kind in stream context, its checksum verdict, the variables it set and the
direction's whole table as the frame leaves it. :class:`ReferenceDecoder` is the plain path the
core is checked against (and hands what its fast path does not take). On UDP and TCP each ``[:``
of bytes that hold no well-formed frame is a :class:`Decoded` of kind ``malformed``
(:mod:`sharedlink.analysis.malformed`: cut and checked as the dissector does; no updates, never
late). Noise and records that are neither UDP/TCP nor serial SharedLink pass through (a
:class:`~sharedlink.capture.stream.StreamFrame` with ``frame`` None, or a ``(number, ts_ns)``
tuple) so callers can count them.

Choices (shared with the dissector, see ``docs/protocol.md``):

* State is kept per conversation and direction, as the dissector keys it: UDP/TCP by
  addresses, ports and the source and destination letters, serial by capture direction and
  letters (:class:`~sharedlink.protocols.state.LinkState`). ``pair`` (``"B>A"``) is what
  reports group by.
* A frame whose checksum is wrong is counted, labelled and judged against the state before it,
  but does not touch the state: nothing is stored or carried from it, no list learnt, no sync
  clock reset. ``shown`` has its values as sent; ``updates`` is empty.
* ``late`` is the dissector's ``sharedlink.sync.late``: a data frame that is not a full set,
  seen more than the sync interval plus :data:`SYNC_SLACK_S` after the direction's last full
  set with a good (or no) checksum, or its first data frame before any.
* ``response_to``: a reply's query or declaration (the latest unanswered one whose names
  include the reply's, from the queried address to the querier's address and port, whatever
  the reply's source port), or the list request (``L?``/``N?``) a declaration answers
  (:func:`sharedlink.protocols.state.link_response`).
"""

from __future__ import annotations

from sharedlink.analysis.core.capture import iter_decoded
from sharedlink.analysis.core.checksum import CKSUB
from sharedlink.analysis.core.columns import Columns, DirColumns
from sharedlink.analysis.core.compiled import Compiled
from sharedlink.analysis.core.counts import Counted, DirCounts
from sharedlink.analysis.core.decoded import DATA_KINDS, SYNC_SLACK_S, VALUE_KINDS, Decoded
from sharedlink.analysis.core.decoder import Decoder
from sharedlink.analysis.core.direction import MAX_LAYOUTS
from sharedlink.analysis.core.lanes import BATCH_FRAMES
from sharedlink.analysis.core.patterns import MAX_COMPILED_VARS, MAX_PATTERNS, cached_pattern
from sharedlink.analysis.core.reference import ReferenceDecoder
from sharedlink.analysis.core.timefmt import format_time
from sharedlink.capture.pcap_blocks import PCAP_BLOCK
from sharedlink.capture.pcapio import NS
from sharedlink.protocols.state import parse_variables  # its home is state

__all__ = [
    "BATCH_FRAMES",
    "CKSUB",
    "DATA_KINDS",
    "MAX_COMPILED_VARS",
    "MAX_LAYOUTS",
    "MAX_PATTERNS",
    "NS",
    "PCAP_BLOCK",
    "SYNC_SLACK_S",
    "VALUE_KINDS",
    "Columns",
    "Compiled",
    "Counted",
    "Decoded",
    "Decoder",
    "DirColumns",
    "DirCounts",
    "ReferenceDecoder",
    "cached_pattern",
    "format_time",
    "iter_decoded",
    "parse_variables",
]
