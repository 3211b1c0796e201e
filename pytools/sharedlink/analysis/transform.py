"""Rewrite a capture's shared-variable frames: ``sharedlink compress`` and ``expand``.

``compress`` leaves out values a receiver already has (named form: the triplet goes;
positional form: the slot stays as an empty ``D``) and sends a full set at least every
``sync_interval`` seconds per direction; ``expand`` makes every value frame carry every value.
Each frame keeps its form, addresses, timestamp and place in the capture; the UDP/IP headers
around it are rewritten with correct lengths and checksums.

The data never change: two decoders (the core, :class:`~sharedlink.analysis.decode.Decoder`, so
the same rules as every other command) follow the stream, one as the input says it (what the
sender meant), one as the output says it (what a receiver of the output knows), and each output
frame carries exactly what the receiver lacks. Frames that
are not plain value frames (declarations, queries, replies, commands, frames with unusual
fields, bad checksums, frames inside TCP streams) are copied unchanged, and both views apply
them alike. So ``sharedlink diff IN OUT`` agrees, and compressing a full beacon capture gives
byte for byte what ``sharedlink gen --compress`` writes.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Hashable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import BinaryIO

from sharedlink.analysis.core.expand import FullSets
from sharedlink.analysis.core.records import RUN, open_capture
from sharedlink.analysis.decode import Decoder, format_time
from sharedlink.capture.packets import Datagram, PacketDecoder, network_offset, ones_complement_checksum
from sharedlink.capture.pcapio import (
    LINKTYPE_ETHERNET,
    NS,
    CaptureError,
    PcapngWriter,
    PcapWriter,
    open_output,
    refuse_overwrite,
)
from sharedlink.capture.serial_format import USER_LINKTYPES
from sharedlink.capture.stream import SerialSplitter, StreamFrame
from sharedlink.errors import OutputError
from sharedlink.protocols.codec import Field, Frame, build_frame, frame_kind, iter_segments
from sharedlink.protocols.state import BEACON_VARIABLES, VariableTable, conversation_key

MODES = ("compress", "expand")


class TransformError(OutputError):
    """The output cannot be written (bad option, unsupported capture layout, I/O error)."""


@dataclass
class TransformStats:
    records: int = 0
    frames: int = 0  # SharedLink frames
    value_frames: int = 0  # of those, full and delta frames
    rewritten: int = 0  # value frames written in the new form
    full: int = 0  # full frames written
    delta: int = 0  # delta frames written
    copied: int = 0  # value frames copied unchanged (TCP, bad checksum, unusual fields)
    bytes_in: int = 0  # SharedLink bytes read
    bytes_out: int = 0  # SharedLink bytes written
    error: str | None = None  # the input is damaged here: the records before it were written

    @property
    def saving(self) -> float | None:
        return None if not self.bytes_in else 1.0 - self.bytes_out / self.bytes_in

    def to_dict(self) -> dict:
        d = asdict(self)
        d["saving"] = self.saving
        return d


# -- frames ------------------------------------------------------------------------------


def _plain_layout(fields: Sequence[Field]) -> str | None:
    """"named" or "positional" when a value frame has only the fields this module
    regenerates (``N`` first, then ``[T] Q D`` triplets or ``D`` s); else None."""
    if not fields or fields[0].letter != "N" or not (fields[0].text.isascii() and fields[0].text.isdigit()):
        return None
    rest = fields[1:]
    if all(f.letter == "D" for f in rest):
        return "positional"
    i, n = 0, len(rest)
    while i < n:
        if rest[i].letter == "T":
            i += 1
        if i + 1 >= n or rest[i].letter != "Q" or rest[i + 1].letter != "D":
            return None
        i += 2
    return "named"


class Rewriter:
    """Rewrites value frames one at a time, in capture order."""

    def __init__(self, mode: str, sync_interval: float = 1.0, variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES) -> None:
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}")
        if not sync_interval > 0:
            raise ValueError("--sync-interval must be positive")
        self.mode = mode
        self.sync_ns = round(sync_interval * NS)
        self.src_decoder = Decoder(variables, sync_interval, carried=False)  # the data, as the input carries it
        self.out_decoder = Decoder(variables, sync_interval, carried=False)  # what a receiver of the output knows
        self.src, self.out = self.src_decoder.link, self.out_decoder.link  # (their tables)
        self.follow_out = mode == "compress"  # (expand writes full sets: what a receiver knows does not matter)
        self.next_sync: dict[tuple[Hashable, str, str], int] = {}
        self.form: dict[tuple[Hashable, str, str], str] = {}  # the form each direction uses
        self.stats = TransformStats()

    def named_form(self, key: tuple) -> bool:
        """Whether the direction ``(conversation, source, destination)`` has been written in the
        named form (so a bare ``N0`` of it is written as a named full set)."""
        return self.form.get(key) == "named"

    def frame(self, frame: Frame, raw: bytes, ts_ns: int, rewritable: bool = True, conv: Hashable = None) -> bytes:
        """The bytes to write for ``frame`` (``raw`` as read). ``conv`` keys the state: the
        conversation (a :class:`~sharedlink.capture.stream.StreamFrame` ``conv``), as the
        dissector keys it; each direction of each conversation is rewritten on its own."""
        st = self.stats
        st.frames += 1
        st.bytes_in += len(raw)
        if conv is None:  # (the decoders key by a conversation's shape)
            conv = ("", "", 0, "", 0)
        kind = frame_kind(frame.fields)
        value = kind in ("full", "delta")
        st.value_frames += value
        if frame.checksum is not None and frame.checksum.ok is False:
            st.copied += value
            st.bytes_out += len(raw)
            return raw  # a receiver drops it: neither view applies it
        layout = _plain_layout(frame.fields) if value else None
        sf = StreamFrame(0, ts_ns, conv, raw, frame)
        if layout is None or not rewritable:
            st.copied += value
            self.src_decoder.decode(sf)
            if self.follow_out:
                self.out_decoder.decode(sf)
            st.bytes_out += len(raw)
            return raw
        ckey = conversation_key(conv)
        src = self.src.table(frame.src, frame.dst, ckey)
        out = self.out.table(frame.src, frame.dst, ckey)
        key = (conv, frame.src, frame.dst)
        if len(frame.fields) == 1:  # a bare N: the form the direction has been using
            layout = self.form.get(key, layout)
        else:
            self.form[key] = layout
        self.src_decoder.decode(sf)
        full = self.mode == "expand"
        if not full:
            due = self.next_sync.get(key)
            # a full set when the interval is over, or when time went back before the last one
            # (records in file order need not be in time order)
            if due is None or ts_ns >= due or ts_ns < due - self.sync_ns:
                full = True
                self.next_sync[key] = ts_ns + self.sync_ns
        if layout == "named":
            fields = self._named(src, out, full)
        else:
            fields = self._positional(frame.fields, src, out, full)
        new = Frame(frame.dst, frame.src, fields, frame.crlf)
        data = build_frame(new)
        # the output as a receiver reads it: from its bytes (its checksum checked, so the core's fast
        # path learns the direction and takes the frames after it); a full set needs none of it
        if self.follow_out:
            for _d in self.out_decoder.decode_datagram(0, ts_ns, conv, data):
                pass
        st.rewritten += 1
        st.full += full
        st.delta += not full
        st.bytes_out += len(data)
        return data

    @staticmethod
    def _named(src: VariableTable, out: VariableTable, full: bool) -> tuple[Field, ...]:
        untyped: list[Field] = []  # before every T: a name without T after one takes its type (BUL-009)
        typed: list[Field] = []
        for name, v in src.vars.items():
            if v.text is None:
                continue
            if not full:
                o = out.vars.get(name)
                if o is not None and o.text == v.text:
                    continue
            if v.type_code is not None:
                typed += [Field("T", str(v.type_code)), Field("Q", name), Field("D", v.text)]
            else:
                untyped += [Field("Q", name), Field("D", v.text)]
        return (Field("N", "0"), *untyped, *typed)

    @staticmethod
    def _positional(in_fields: Sequence[Field], src: VariableTable, out: VariableTable, full: bool) -> tuple[Field, ...]:
        if full:
            start, count = 0, len(src.names)
        else:
            start = int(in_fields[0].text)
            count = sum(1 for f in in_fields if f.letter == "D")
        fields = [Field("N", str(start))]
        for i in range(start, start + count):
            name = src.name_at(i)
            v = src.vars.get(name) if name is not None else None
            text = v.text if v is not None else None
            if text is not None and not full:
                o = out.vars.get(name)
                if o is not None and o.text == text:
                    text = None
            fields.append(Field("D", text or ""))
        return tuple(fields)


# -- packets --------------------------------------------------------------------------------


def _udp_header(linktype: int, data: bytes) -> tuple[int, int, int] | None:
    """(IP header offset, IP version, UDP header offset) of a plain IPv4/IPv6 UDP packet
    whose headers this module can rewrite (IPv4 options are kept); None for anything else
    (IPv6 extension headers, fragments, other protocols)."""
    try:
        off = network_offset(linktype, data)
        if off is None:
            return None
        ver = data[off] >> 4
        if ver == 4:
            ihl = (data[off] & 15) * 4
            frag = struct.unpack_from("!H", data, off + 6)[0]
            if ihl < 20 or data[off + 9] != 17 or frag & 0x3FFF or len(data) < off + ihl + 8:
                return None
            return off, 4, off + ihl
        if ver == 6 and data[off + 6] == 17 and len(data) >= off + 48:
            return off, 6, off + 40
    except (struct.error, IndexError):
        return None
    return None


class PayloadTooLarge(ValueError):
    """A rewritten UDP payload longer than its IP packet's length field can say."""


def replace_udp_payload(linktype: int, data: bytes, payload: bytes) -> bytes | None:
    """``data`` (one captured packet) with its UDP payload replaced, IP and UDP lengths and
    checksums made right. None when the packet is not plain IPv4/IPv6 UDP (options are kept;
    IPv6 extension headers, fragments and anything else give None); :class:`PayloadTooLarge`
    when ``payload`` does not fit in one datagram (65,507 bytes over IPv4 without options)."""
    loc = _udp_header(linktype, data)
    if loc is None:
        return None
    off, ver, u = loc
    ulen = 8 + len(payload)
    room = 0xFFFF - (u - off if ver == 4 else 0)  # the IPv4 total length; the IPv6 payload length
    if ulen > room:
        raise PayloadTooLarge(f"{len(payload):,} bytes of UDP payload, more than the packet can hold ({room - 8:,})")
    if ver == 4:
        old_ck = struct.unpack_from("!H", data, u + 6)[0]
        ip = bytearray(data[off:u])
        struct.pack_into("!H", ip, 2, u - off + ulen)
        struct.pack_into("!H", ip, 10, 0)
        struct.pack_into("!H", ip, 10, ones_complement_checksum(bytes(ip)))
        udp = bytearray(data[u : u + 8])
        struct.pack_into("!HH", udp, 4, ulen, 0)
        if old_ck:
            pseudo = bytes(ip[12:20]) + struct.pack("!BBH", 0, 17, ulen)
            struct.pack_into("!H", udp, 6, ones_complement_checksum(pseudo + bytes(udp) + payload) or 0xFFFF)
        return data[:off] + bytes(ip) + bytes(udp) + payload
    ip = bytearray(data[off:u])
    struct.pack_into("!H", ip, 4, ulen)
    udp = bytearray(data[u : u + 8])
    struct.pack_into("!HH", udp, 4, ulen, 0)
    pseudo = bytes(ip[8:40]) + struct.pack("!IxxxB", ulen, 17)
    struct.pack_into("!H", udp, 6, ones_complement_checksum(pseudo + bytes(udp) + payload) or 0xFFFF)
    return data[:off] + bytes(ip) + bytes(udp) + payload


# -- captures -------------------------------------------------------------------------------


def transform_capture(
    src: str | Path,
    dst: str | Path,
    mode: str,
    sync_interval: float = 1.0,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    progress: Callable[[int, int], None] | None = None,
    runs: bool = True,
) -> TransformStats:
    """Rewrite capture ``src`` into ``dst`` (same format: pcap or pcapng);
    ``progress(bytes read, records)`` is called every few thousand records. Raises
    :class:`~sharedlink.capture.pcapio.CaptureError` when the input is missing or not a capture
    (``dst`` is then left as it was: the output goes to a temporary file renamed at the end)
    and :class:`TransformError` when the output cannot be written. A capture damaged further
    on gives the records before the damage, with ``error`` set in the stats. ``runs`` False:
    every frame one at a time (expand's run taker off: the reference the tests compare it with)."""
    rw = Rewriter(mode, sync_interval, variables)
    return rewrite_capture(rw, src, dst, FullSets(rw.src_decoder, rw.named_form) if runs and mode == "expand" else None,
                           progress)


def rewrite_capture(rw: Rewriter, src: str | Path, dst: str | Path, taker: FullSets | None = None,
                    progress: Callable[[int, int], None] | None = None) -> TransformStats:
    """:func:`transform_capture` with its :class:`Rewriter` and, for expand, its run taker
    (:class:`~sharedlink.analysis.core.expand.FullSets` on ``rw.src_decoder``; None: every
    frame through ``rw``)."""
    s, d = str(src), Path(dst)
    refuse_overwrite(d, s)
    fmt, records = open_capture(s, taker.run if taker is not None else None)  # read once: a pipe will do
    with open_output(d) as fh:
        _Transform(rw, s, fmt, fh, taker).records(records, progress)
    return rw.stats


class _Transform:
    """The records of capture ``s`` rewritten into ``fh``: the writer (made at the first record,
    in the input's format), its interfaces and the chunk of records not yet written."""

    def __init__(self, rw: Rewriter, s: str, fmt: str, fh: BinaryIO, taker: FullSets | None) -> None:
        self.rw, self.s, self.fmt, self.fh, self.taker = rw, s, fmt, fh, taker
        self.writer: PcapWriter | PcapngWriter | None = None
        self.linktype = LINKTYPE_ETHERNET
        self.interfaces: dict[tuple[int, int], int] = {}  # (input interface, link type) -> output interface
        self.chunk: list[bytes] = []
        self.decode = PacketDecoder().decode  # IP fragments reassembled
        self.serial = SerialSplitter()  # serial records: copied, their frames followed and counted
        self.packets = taker if fmt == "pcapng" else None  # offered each Ethernet record (no block runs)

    def records(self, records: Iterator[tuple], progress: Callable[[int, int], None] | None) -> None:
        st = self.rw.stats
        read = 24  # bytes of the input read, about (pcap's headers; pcapng's blocks are a little longer)
        chunk = self.chunk
        while True:
            try:
                number, ts_ns, linktype, data, flags, interface = next(records)
            except StopIteration:
                break
            except CaptureError as exc:
                if exc.record is None:
                    raise
                st.error = str(exc)
                break
            if linktype == RUN:  # the run taker took ts_ns records (flags: their bytes)
                self._run(ts_ns)
                read += flags + 16 * ts_ns
            else:
                st.records += 1
                read += 16 + len(data)
                self._record(number, ts_ns, linktype, data, flags, interface)
            if len(chunk) >= 4096:
                self.fh.write(b"".join(chunk))
                chunk.clear()
                if progress is not None:
                    progress(read, st.records)
        if self.packets is not None:
            self._drain(True)
        _follow_serial(self.rw, self.serial.flush())
        self._writer(LINKTYPE_ETHERNET)  # (a capture of no record: its header)
        self.fh.write(b"".join(chunk))

    def _writer(self, linktype: int) -> PcapWriter | PcapngWriter:
        """The writer, made at the first record (or at the end of a capture of none)."""
        if self.writer is None:
            self.linktype = linktype
            fh = self.fh
            self.writer = PcapngWriter(fh, linktype) if self.fmt == "pcapng" else PcapWriter(fh, linktype)
        return self.writer

    def _iface(self, number: int, linktype: int, interface: int) -> int:
        """The output interface of record ``number`` (the input's ``interface``, ``linktype``):
        in a pcapng file, an interface added for a new one."""
        writer = self._writer(linktype)
        if not self.interfaces:  # (the first record's is the writer's first)
            self.interfaces[(interface, linktype)] = 0
        iface = self.interfaces.get((interface, linktype))
        if iface is None:  # pcapng: one more interface (a pcap has one link type)
            if not isinstance(writer, PcapngWriter):
                raise TransformError(f"{self.s}: record {number} is on link type {linktype}, not {self.linktype}")
            self.chunk.append(writer.interface(linktype))
            iface = self.interfaces[(interface, linktype)] = writer.interfaces - 1
        return iface

    def _run(self, frames: int) -> None:
        """A run the run taker took in a pcap block: its records written, counted as the one at
        a time are."""
        self.rw.stats.records += frames
        self._taken()

    def _taken(self, pcapng: bool = False) -> None:
        """The frames the run taker took since the last call written (a pcapng file's packets
        in its records) and counted as the one at a time are."""
        taker, st = self.taker, self.rw.stats
        assert taker is not None
        frames = taker.frames
        st.frames += frames
        st.value_frames += frames
        st.rewritten += frames
        st.full += frames
        st.bytes_in += taker.bytes_in
        st.bytes_out += taker.bytes_out
        taker.frames = taker.bytes_in = taker.bytes_out = 0
        if pcapng:
            record, ifaces = self.writer.record, self.interfaces  # type: ignore[union-attr]
            self.chunk += [record(ts, pkt, fl, ifaces[(i, LINKTYPE_ETHERNET)]) for ts, pkt, fl, i in taker.out]
        else:
            self.chunk += taker.out
        taker.out.clear()

    def _record(self, number: int, ts_ns: int, linktype: int, data: bytes, flags: int, interface: int) -> None:
        """One record: in a pcapng file offered to the run taker first (:meth:`FullSets.packet`),
        else :meth:`_rewrite`."""
        packets = self.packets
        if packets is not None:
            if (linktype == LINKTYPE_ETHERNET and (interface, linktype) in self.interfaces
                    and packets.packet(number, ts_ns, data, flags, interface)):
                if packets.frames:  # (the run before it, ended by it)
                    self._taken(True)
                return
            self._drain(True)
        self._rewrite(number, ts_ns, linktype, data, flags, interface)

    def _drain(self, flush: bool) -> None:
        """A pcapng file: the run taken so far ended (``flush``) and written, or the records of
        a run given back rewritten one at a time."""
        packets = self.packets
        assert packets is not None
        if flush:
            packets.flush()
        if packets.frames:
            self._taken(True)
        redo, packets.redo = packets.redo, []
        for number, ts_ns, data, flags, interface in redo:
            self._rewrite(number, ts_ns, LINKTYPE_ETHERNET, data, flags, interface)

    def _rewrite(self, number: int, ts_ns: int, linktype: int, data: bytes, flags: int, interface: int) -> None:
        """One record rewritten (its UDP value frames) or copied (its frames followed)."""
        iface = self._iface(number, linktype, interface)
        if linktype in USER_LINKTYPES:
            _follow_serial(self.rw, self.serial.feed(number, ts_ns, linktype, data, flags, interface))
        else:
            dg = self.decode(linktype, data)
            if dg is not None and dg.payload and b"[" in dg.payload:
                data = self._datagram(number, ts_ns, linktype, data, dg)
        try:
            self.chunk.append(self.writer.record(ts_ns, data, flags, iface))  # type: ignore[union-attr]
        except struct.error:  # a time stamp the output format cannot hold
            raise OutputError(f"{self.s}: record {number}: its time stamp ({format_time(ts_ns)}) cannot be written "
                              f"as a nanosecond {self.fmt} (pcap ends in 2106, pcapng in 2554)") from None

    def _datagram(self, number: int, ts_ns: int, linktype: int, data: bytes, dg: Datagram) -> bytes:
        """A datagram's packet with its value frames rewritten: UDP in plain headers; frames in
        fragments, IPv6 extension headers and TCP are copied (both views follow them)."""
        rw = self.rw
        conv = (dg.proto, dg.src, dg.sport, dg.dst, dg.dport)
        if dg.proto != "udp" or _udp_header(linktype, data) is None:
            for seg in iter_segments(dg.payload):
                if seg.frame is not None:
                    rw.frame(seg.frame, dg.payload[seg.start : seg.end], ts_ns, False, conv)
            return data
        parts = []
        for seg in iter_segments(dg.payload):
            raw = dg.payload[seg.start : seg.end]
            parts.append(raw if seg.frame is None else rw.frame(seg.frame, raw, ts_ns, conv=conv))
        payload = b"".join(parts)
        if payload == dg.payload:
            return data
        try:
            new = replace_udp_payload(linktype, data, payload)
        except PayloadTooLarge as exc:  # an expanded (or full) set past 64 KB
            raise TransformError(f"{self.s}: record {number}: the rewritten frames take {exc}: nothing "
                                 "written") from None
        if new is None:
            raise TransformError(f"{self.s}: record {number}: cannot rewrite this UDP packet's headers")
        return new


def _follow_serial(rw: Rewriter, items: list) -> None:
    """Serial frames are copied as their records are (a record may hold part of a frame, so
    none is rewritten); both views follow them and they are counted as stats counts them."""
    for item in items:
        if isinstance(item, StreamFrame) and item.frame is not None:
            rw.frame(item.frame, item.raw, item.ts_ns, False, item.conv)


def compress_capture(src: str | Path, dst: str | Path, sync_interval: float = 1.0,
                     variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES) -> TransformStats:
    """Leave out unchanged values, a full set at least every ``sync_interval`` seconds."""
    return transform_capture(src, dst, "compress", sync_interval, variables)


def expand_capture(src: str | Path, dst: str | Path,
                   variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES) -> TransformStats:
    """Every value frame carries every value."""
    return transform_capture(src, dst, "expand", 1.0, variables)
