"""The core's record loop over a capture (:meth:`Decoder.capture`, :func:`iter_decoded`): each
record to the mode's sink or to the general path, in capture order."""

from __future__ import annotations

import socket
import struct
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from sharedlink.analysis.core.columns import Columns
from sharedlink.analysis.core.counts import Counted
from sharedlink.analysis.core.decoded import Decoded
from sharedlink.analysis.core.lanes import BATCH_FRAMES
from sharedlink.analysis.core.patterns import ETH_IPV4, UDP
from sharedlink.analysis.core.records import RUN, capture_records
from sharedlink.analysis.core.reference import ReferenceDecoder
from sharedlink.analysis.robots import FIRST_BYTES, SHAREDLINK_PORT, RobotLinks
from sharedlink.capture.packets import PacketDecoder
from sharedlink.capture.pcapio import LINKTYPE_ETHERNET, CaptureError
from sharedlink.capture.serial_format import USER_LINKTYPES
from sharedlink.capture.stream import SerialSplitter, StreamFrame
from sharedlink.protocols.limits import MAX_CONVERSATIONS
from sharedlink.protocols.state import BEACON_VARIABLES

if TYPE_CHECKING:
    from sharedlink.analysis.core.decoder import Decoder

#: from byte 12 of an Ethernet/IPv4 packet: the type and the IP version and header length (3
#: bytes), IP total length, flags and fragment offset, (TTL skipped) protocol, (checksum
#: skipped) the addresses and UDP ports (12 bytes: the conversation), UDP length
UDP_HEAD = struct.Struct("!3sxHxxHxB2x12sH")

Item = Decoded | StreamFrame | tuple[int, int] | Counted | Columns


def udp_payload(data: bytes, addrs: dict[bytes, tuple]) -> tuple | None:
    """An Ethernet packet read without the general packet decoder: ``(conversation, payload)`` of
    a plain IPv4/UDP datagram (not a fragment), ``()`` for one that holds nothing to decode
    (too short, or an empty payload), None for any other packet (the general path decides).
    ``addrs`` keeps the conversations by their addresses and ports as the packet holds them."""
    if len(data) < 42:
        return None
    eth, tlen, frag, proto, key, ulen = UDP_HEAD.unpack_from(data, 12)
    if eth != ETH_IPV4 or proto != UDP or frag & 0x3FFF or tlen < 20:
        return None
    conv = addrs.get(key)
    if conv is None:
        if len(addrs) > MAX_CONVERSATIONS:
            addrs.clear()
        sport, dport = struct.unpack_from("!HH", key, 8)
        conv = addrs[key] = ("udp", socket.inet_ntoa(key[:4]), sport, socket.inet_ntoa(key[4:8]), dport)
    end = min(14 + tlen, len(data))
    stop = (min(34 + ulen, end) if ulen >= 8 else end) if end >= 42 else 0
    return (conv, data[42:stop]) if stop > 42 else ()


class _Loop:
    """The record loop of one :meth:`Decoder.capture` (see there): ``counting``/``columns``, the
    frames the fast path takes go to the counts or columns sink, gathered into batches of about
    :data:`BATCH_FRAMES` (``taken`` frames now), each given out before the next item of any
    other kind."""

    def __init__(self, dec: Decoder, progress: Callable[[int, int], None] | None, counting: bool, columns: bool
                 ) -> None:
        self.dec, self.progress, self.columns = dec, progress, columns
        self.serial = SerialSplitter()
        self.packets = PacketDecoder().decode  # IP fragments reassembled
        self.addrs: dict[bytes, tuple] = {}
        self.count = dec.column if columns else dec.count
        self.runs = dec.column_run if columns else dec.count_run if counting else None
        self.counting = counting or columns
        self.taken = 0  # frames in dec.batch (dec.rows)
        self.read = 24  # bytes of the file read, about (pcap's headers; pcapng's blocks are a little longer)
        # P2OS/blackboard conversations (analysis/robots.py): a caller wanting messages sets dec.robots
        self.robots = getattr(dec, "robots", None) or RobotLinks()

    def items(self, path: str | Path) -> Iterator[Item]:
        datagram = self.dec.decode_datagram
        addrs = self.addrs
        progress = self.progress
        counting = self.counting
        robots, robot_first, claimed = self.robots, FIRST_BYTES, self.robots.claimed  # (claimed: filled in place)
        try:
            for number, ts_ns, linktype, data, flags, interface in capture_records(path, self.runs):
                if linktype == RUN:  # a run taker took ts_ns frames (flags: their bytes) into dec.rows (dec.batch)
                    yield from self._run(number, ts_ns, flags)
                    continue
                if progress is not None:
                    self._progress(number, 16 + len(data))
                got = udp_payload(data, addrs) if linktype == LINKTYPE_ETHERNET else None
                if got is None:
                    yield from self._other(number, ts_ns, linktype, data, flags, interface)
                elif got:
                    if claimed or got[1][0] in robot_first:  # P2OS/blackboard: never SharedLink's (issue 44)
                        taken = robots.udp(number, ts_ns, got[0], got[1])
                        if taken is not None:
                            if self.taken:
                                yield self._batch()
                            yield from taken
                            continue
                    if got[0][4] != SHAREDLINK_PORT and got[0][2] != SHAREDLINK_PORT:  # (off the port: the heuristic's)
                        robots.sharedlink(got[0], got[1])
                    if counting:
                        yield from self._counted(number, ts_ns, got[0], got[1])
                    else:
                        yield from datagram(number, ts_ns, got[0], got[1])
        except CaptureError:
            yield from self._end()
            raise
        yield from self._end()

    def _progress(self, number: int, size: int, frames: int = 0) -> None:
        self.read += size
        if (number >> 12 != (number - frames) >> 12) if frames else not number & 4095:
            self.progress(self.read, number)  # type: ignore[misc]

    def _batch(self) -> Counted | Columns:
        self.taken = 0
        dec = self.dec
        return dec.take_columns() if self.columns else Counted(dec.take_batch())

    def _run(self, number: int, frames: int, wire: int) -> Iterator[Item]:
        if self.progress is not None:
            self._progress(number, wire + 16 * frames, frames)
        self.taken = self.dec.taken if self.columns else self.taken + frames
        if self.taken >= BATCH_FRAMES:
            yield self._batch()

    def _counted(self, number: int, ts_ns: int, conv: tuple, payload: bytes) -> Iterator[Item]:
        if self.count(number, ts_ns, conv, payload):
            self.taken += 1
            if self.taken >= BATCH_FRAMES:
                yield self._batch()
            return
        if self.taken:
            yield self._batch()
        yield from self.dec.decode_datagram(number, ts_ns, conv, payload)

    def _other(self, number: int, ts_ns: int, linktype: int, data: bytes, flags: int, interface: int
               ) -> Iterator[Item]:
        """A record the general path takes: serial, or through the packet decoder and splitters."""
        if self.taken:
            yield self._batch()
        dec = self.dec
        if linktype in USER_LINKTYPES:
            for item in self.serial.feed(number, ts_ns, linktype, data, flags, interface):
                yield from decode_item(dec, item)
            if self.robots.messages:
                yield from self.robots.serial(number, ts_ns, data, flags, interface)
            return
        dg = self.packets(linktype, data)
        if dg is None:
            yield number, ts_ns
            return
        robot_items = self.robots.datagram(number, ts_ns, dg)
        if robot_items is not None:  # a P2OS or blackboard conversation: never SharedLink's (issue 44)
            yield from robot_items
            return
        self.robots.sharedlink((dg.proto, dg.src, dg.sport, dg.dst, dg.dport), dg.payload)
        for sf in dec.splitter.split(number, ts_ns, dg):
            yield from decode_item(dec, sf)

    def _end(self) -> Iterator[Item]:
        """The end of the capture (or the damage): the last batch, then the serial tails."""
        dec = self.dec
        if dec.rows if self.columns else dec.batch:
            yield self._batch()
        for item in self.serial.flush():
            yield from decode_item(dec, item)
        yield from self.robots.finish()  # (blackboard text a TCP stream holds: analysis/robots.py)


def capture_items(dec: Decoder, path: str | Path, progress: Callable[[int, int], None] | None, counting: bool = False,
                  columns: bool = False) -> Iterator[Item]:
    """The record loop of :meth:`Decoder.capture`: plain Ethernet/IPv4/UDP records (not
    fragments) go to :meth:`Decoder.decode_datagram` (``counting``: first to
    :meth:`Decoder.count`; ``columns``: to :meth:`Decoder.column`) straight from the record's
    bytes; every other record through the general reader's packet decoder and splitters (as
    :func:`~sharedlink.capture.stream.iter_frames`)."""
    return _Loop(dec, progress, counting, columns).items(path)


def decode_item(dec: Decoder, item: StreamFrame | tuple[int, int]) -> Iterator[Decoded | StreamFrame | tuple[int, int]]:
    """An item of the general path: a frame through the reference path (the core learning from
    it), bytes that hold none as :meth:`ReferenceDecoder.unframed` cuts them, a record of no
    frame unchanged."""
    if isinstance(item, StreamFrame):
        if item.frame is not None:
            d = ReferenceDecoder.decode(dec, item)
            dec._learn(d)
            yield d
            return
        yield from dec.unframed(item)
        return
    yield item


def iter_decoded(
    path: str | Path,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
    carried: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> Iterator[Decoded | StreamFrame | tuple[int, int]]:
    """Every item of a capture, through the core (:class:`Decoder`): :class:`Decoded` for
    frames, the noise :class:`StreamFrame` and ``(number, ts_ns)`` for other records unchanged.
    Raises :class:`~sharedlink.capture.pcapio.CaptureError` on damage, after everything before
    it. ``carried`` False: named frames' carried values are left out of ``updates``;
    ``progress(bytes read, records)`` is called now and then."""
    from sharedlink.analysis.core.decoder import Decoder

    return Decoder(variables, sync_interval, carried).capture(path, progress)  # type: ignore[return-value]
