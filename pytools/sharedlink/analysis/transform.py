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

from sharedlink.analysis.decode import Decoder, format_time
from sharedlink.capture.packets import PacketDecoder, network_offset, ones_complement_checksum
from sharedlink.capture.pcapio import (
    LINKTYPE_ETHERNET,
    NS,
    CaptureError,
    PcapngWriter,
    PcapWriter,
    Record,
    open_output,
    open_records,
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
        self.next_sync: dict[tuple[Hashable, str, str], int] = {}
        self.form: dict[tuple[Hashable, str, str], str] = {}  # the form each direction uses
        self.stats = TransformStats()

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
        # path learns the direction and takes the frames after it)
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
) -> TransformStats:
    """Rewrite capture ``src`` into ``dst`` (same format: pcap or pcapng);
    ``progress(bytes read, records)`` is called every few thousand records. Raises
    :class:`~sharedlink.capture.pcapio.CaptureError` when the input is missing or not a capture
    (``dst`` is then left as it was: the output goes to a temporary file renamed at the end)
    and :class:`TransformError` when the output cannot be written. A capture damaged further
    on gives the records before the damage, with ``error`` set in the stats."""
    rw = Rewriter(mode, sync_interval, variables)
    st = rw.stats
    s, d = str(src), Path(dst)
    refuse_overwrite(d, s)
    fmt, records = open_records(s)  # read once: a pipe will do
    with open_output(d) as fh:
        _transform_records(rw, s, fmt, records, fh, progress)
    return st


def _transform_records(rw: Rewriter, s: str, fmt: str, records: Iterator[Record], fh: BinaryIO,
                       progress: Callable[[int, int], None] | None = None) -> None:
    """Rewrite the records of capture ``s`` into ``fh``."""
    st = rw.stats
    read = 24  # bytes of the input read, about (pcap's headers; pcapng's blocks are a little longer)
    writer: PcapWriter | PcapngWriter | None = None
    linktype = None
    interfaces: dict[tuple[int, int], int] = {}  # (input interface, link type) -> output interface
    chunk: list[bytes] = []
    decode = PacketDecoder().decode  # IP fragments reassembled
    serial = SerialSplitter()  # serial records: copied, their frames followed and counted
    while True:
        try:
            rec = next(records)
        except StopIteration:
            break
        except CaptureError as exc:
            if exc.record is None:
                raise
            st.error = str(exc)
            break
        st.records += 1
        read += 16 + len(rec.data)
        if writer is None:
            linktype = rec.linktype
            writer = PcapngWriter(fh, linktype) if fmt == "pcapng" else PcapWriter(fh, linktype)
            interfaces[(rec.interface, rec.linktype)] = 0
        iface = interfaces.get((rec.interface, rec.linktype))
        if iface is None:  # pcapng: one more interface (a pcap has one link type)
            if not isinstance(writer, PcapngWriter):
                raise TransformError(f"{s}: record {rec.number} is on link type {rec.linktype}, not {linktype}")
            chunk.append(writer.interface(rec.linktype))
            iface = interfaces[(rec.interface, rec.linktype)] = writer.interfaces - 1
        data = rec.data
        if rec.linktype in USER_LINKTYPES:
            _follow_serial(rw, serial.feed(rec.number, rec.ts_ns, rec.linktype, data, rec.flags, rec.interface))
            dg = None
        else:
            dg = decode(rec.linktype, data)
        if dg is not None and dg.payload and b"[" in dg.payload:
            conv = (dg.proto, dg.src, dg.sport, dg.dst, dg.dport)
            # UDP in plain headers is rewritten; fragments and IPv6 extension headers copied
            if dg.proto == "udp" and _udp_header(rec.linktype, data) is not None:
                parts = []
                for seg in iter_segments(dg.payload):
                    raw = dg.payload[seg.start : seg.end]
                    parts.append(raw if seg.frame is None else rw.frame(seg.frame, raw, rec.ts_ns, conv=conv))
                payload = b"".join(parts)
                if payload != dg.payload:
                    try:
                        new = replace_udp_payload(rec.linktype, data, payload)
                    except PayloadTooLarge as exc:  # an expanded (or full) set past 64 KB
                        raise TransformError(f"{s}: record {rec.number}: the rewritten frames take {exc}: nothing "
                                             "written") from None
                    if new is None:
                        raise TransformError(f"{s}: record {rec.number}: cannot rewrite this UDP packet's headers")
                    data = new
            else:  # TCP and the rest: frames are copied; both views follow them
                for seg in iter_segments(dg.payload):
                    if seg.frame is not None:
                        rw.frame(seg.frame, dg.payload[seg.start : seg.end], rec.ts_ns, False, conv)
        try:
            chunk.append(writer.record(rec.ts_ns, data, rec.flags, iface))
        except struct.error:  # a time stamp the output format cannot hold
            raise OutputError(f"{s}: record {rec.number}: its time stamp ({format_time(rec.ts_ns)}) cannot be written "
                              f"as a nanosecond {fmt} (pcap ends in 2106, pcapng in 2554)") from None
        if len(chunk) >= 4096:
            fh.write(b"".join(chunk))
            chunk.clear()
            if progress is not None:
                progress(read, st.records)
    _follow_serial(rw, serial.flush())
    if writer is None:
        writer = PcapngWriter(fh, LINKTYPE_ETHERNET) if fmt == "pcapng" else PcapWriter(fh, LINKTYPE_ETHERNET)
    fh.write(b"".join(chunk))


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
