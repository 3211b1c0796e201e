"""Test data builders shared by the test files. Hypothesis strategies for varied SharedLink captures (test_diff, test_transform), written
as real pcap files with pcapio and packets: named and positional frames, full and delta,
declarations, replies, queries, two directions, several frames in one datagram, noise, bad
checksums, frames without CR LF, numbers written in different ways."""

from __future__ import annotations

import os
import random
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

from hypothesis import strategies as st
from sl_robots import write_serial

from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.generators.beacon import DEFAULT_START_NS
from sharedlink.protocols import blackboard, p2os
from sharedlink.protocols.codec import (
    Field,
    Frame,
    build_frame,
    declaration_fields,
    encode_named,
    encode_positional,
    iter_segments,
    named_fields,
    positional_fields,
    query_fields,
    reply_fields,
)

#: variables per direction: (name, type); the positional list of direction B>A is the beacon's
NAMES = {("B", "A"): [("AutoGpsLat", 2), ("AutoGpsLon", 2), ("Mode", 4), ("Count", 0)],
         ("C", "A"): [("Speed", 2), ("Label", 4)]}
VALUES = {0: ["0", "7", "12", "-3"], 2: ["1.5", "1.50", "2", "-0.25", "38.34698779"], 4: ["on", "off", "x y", ""]}


@st.composite
def frame_bytes(draw, direction: tuple[str, str]) -> bytes:
    """One frame of a direction, drawn from many shapes."""
    src, dst = direction
    names = NAMES[direction]
    shape = draw(st.sampled_from(["named", "named", "named", "positional", "positional", "decl", "reply", "query",
                                  "bad", "nocrlf", "odd"]))
    crlf = True

    def vals(subset: bool) -> list[tuple[str, int, str]]:
        chosen = [nt for nt in names if not subset or draw(st.booleans())]
        return [(n, t, draw(st.sampled_from(VALUES[t]))) for n, t in chosen]

    if shape in ("named", "bad", "nocrlf"):
        fields = named_fields(vals(draw(st.booleans())))
        crlf = shape != "nocrlf"
    elif shape == "positional":
        texts = [draw(st.one_of(st.none(), st.sampled_from(VALUES[2]))) for _ in range(draw(st.integers(1, 5)))]
        fields = positional_fields(texts, ordinal=draw(st.sampled_from([0, 0, 0, 1])))
    elif shape == "decl":
        fields = declaration_fields(names[: draw(st.integers(1, len(names)))])
    elif shape == "reply":
        n, t = draw(st.sampled_from(names))
        fields = reply_fields(n, draw(st.sampled_from(VALUES[t])))
    elif shape == "query":
        fields = query_fields(draw(st.sampled_from(names))[0])
    else:  # a value frame with fields a rewriter does not regenerate (no T, an unknown letter)
        n, t = draw(st.sampled_from(names))
        fields = (Field("N", "0"), Field("Q", n), Field("D", draw(st.sampled_from(VALUES[t]))), Field("X", "1"))
    frame = Frame(dst, src, tuple(fields), crlf)
    if shape == "bad":
        good = build_frame(frame)
        c = good.rfind(b"|C")
        wrong = (int(good[c + 2 : c + 4], 16) + 1) & 0xFF
        return good[: c + 2] + b"%02X" % wrong + good[c + 4 :]
    return build_frame(frame)


@st.composite
def captures(draw, max_frames: int = 30) -> list[tuple[int, bytes]]:
    """(timestamp ns, UDP payload) per datagram, in time order."""
    out = []
    ts = DEFAULT_START_NS
    for _ in range(draw(st.integers(1, max_frames))):
        ts += draw(st.sampled_from([200_000_000, 200_000_000, 200_000_000, 150_000_000, 0]))
        direction = draw(st.sampled_from([("B", "A"), ("B", "A"), ("B", "A"), ("C", "A")]))
        payload = draw(frame_bytes(direction))
        extra = draw(st.sampled_from(["", "", "", "", "frame", "noise"]))
        if extra == "frame":
            payload += draw(frame_bytes(direction))
        elif extra == "noise":
            payload = b"garbage " + payload
        out.append((ts, payload))
    return out


def write_capture(path: Path, datagrams: list[tuple[int, bytes]]) -> Path:
    """Each payload as an Ethernet/IPv4/UDP broadcast to port 7013 in a nanosecond pcap."""
    b = UdpBuilder("192.168.1.12", "255.255.255.255", 7013, 7013)
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for i, (ts, payload) in enumerate(datagrams):
            w.write(ts, b.frame(payload, i + 1))
    return path


#: how many examples a property test draws, against the figure it names: 0.4 of it in make test
#: (the default), all of it in make test-long, ten times it in make fuzz (the Makefile sets
#: SHAREDLINK_EXAMPLES); a bug a draw once found stays as an @example whatever the figure
EXAMPLES_SCALE = float(os.environ.get("SHAREDLINK_EXAMPLES", "0.4"))


def examples(n: int) -> int:
    """``n`` examples scaled by :data:`EXAMPLES_SCALE` (at least 20)."""
    return max(20, round(n * EXAMPLES_SCALE))


# -- stream strategies (test_serial, test_serial_dissector) ---------------------------------------

_values = st.one_of(st.none(), st.integers(-999, 99999).map(str), st.floats(-1e3, 1e3, allow_nan=False).map(lambda f: "%.4f" % f))


@st.composite
def sl_frame(draw: st.DrawFn) -> bytes:
    dst, src = draw(st.sampled_from("ABCP")), draw(st.sampled_from("ABCP"))
    crlf = draw(st.booleans()) if draw(st.integers(0, 5)) == 0 else True
    if draw(st.booleans()):
        return encode_positional(dst, src, draw(st.lists(_values, min_size=1, max_size=6)), draw(st.integers(0, 3)), crlf)
    vals = draw(st.lists(st.tuples(st.sampled_from(["Lat", "Lon", "X_1"]), st.sampled_from([0, 2, 4]), st.text("0123456789.-abc", max_size=8)), min_size=1, max_size=3))
    return encode_named(dst, src, vals, 0, crlf)


_noise = st.one_of(
    st.binary(min_size=1, max_size=12),
    st.text("[]:|\r\nABC xyz09", min_size=1, max_size=12).map(lambda t: t.encode()),
)


@st.composite
def sl_stream(draw: st.DrawFn, min_items: int = 1, max_items: int = 12) -> bytes:
    """Frames with noise and truncated frames between them, ending with a whole CR LF frame."""
    parts = []
    for _ in range(draw(st.integers(min_items, max_items))):
        k = draw(st.integers(0, 9))
        if k < 6:
            parts.append(draw(sl_frame()))
        elif k < 8:
            parts.append(draw(_noise))
        else:
            f = draw(sl_frame())
            parts.append(f[: draw(st.integers(1, len(f) - 1))])
    parts.append(encode_positional("A", "B", ["end"]))
    return b"".join(parts)


# P2OS packets and blackboard messages (test_serial_any_split, test_serial_split_tshark)

_serial_noise = st.one_of(st.binary(min_size=1, max_size=12),
                   st.sampled_from([b"\xfa", b"\xfa\xfb", b"\xfa\xfb\x03", b":", b"\r", b"\r\n", b":03"]))


@st.composite
def p2os_packet(draw: st.DrawFn) -> bytes:
    kind = draw(st.integers(0, 2))
    if kind == 0:
        return p2os.encode_message(p2os.command(draw(st.integers(0, 120))))
    if kind == 1:
        return p2os.encode_message(p2os.command(draw(st.integers(0, 120)), draw(st.integers(-3000, 3000))))
    return p2os.encode_message(p2os.Sip(moving=draw(st.booleans()),
                                        sonars=tuple((i, draw(st.integers(0, 5000))) for i in range(draw(st.integers(0, 3))))))


@st.composite
def blackboard_message(draw: st.DrawFn) -> bytes:
    if draw(st.booleans()):
        return blackboard.build_message(blackboard.SetMessage(draw(st.integers(0, 0xFFFF)), draw(st.integers(0, 255)),
                                                              draw(st.binary(max_size=8))))
    return blackboard.build_message(blackboard.RequestMessage(draw(st.integers(0, 0xFFFF)), draw(st.integers(0, 255)),
                                                              draw(st.integers(0, 255))))


@st.composite
def serial_stream(draw: st.DrawFn, protocol: str, max_items: int = 10) -> tuple[bytes, list[bytes] | None]:
    """Messages with noise and truncated messages between them (or none: a clean stream, one
    time in four), ending with a whole message; and the messages when the stream is clean."""
    message = p2os_packet() if protocol == "p2os" else blackboard_message()
    clean = draw(st.integers(0, 3)) == 0
    parts, messages = [], []
    for _ in range(draw(st.integers(1, max_items))):
        k = 0 if clean else draw(st.integers(0, 9))
        if k < 6:
            messages.append(draw(message))
            parts.append(messages[-1])
        elif k < 8:
            parts.append(draw(_serial_noise))
        else:
            m = draw(message)
            parts.append(m[: draw(st.integers(1, len(m) - 1))])
    messages.append(draw(message))
    parts.append(messages[-1])
    return b"".join(parts), (messages if clean else None)


def chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    pts = sorted({c % (len(data) + 1) for c in cuts} | {0, len(data)})
    return [data[a:b] for a, b in zip(pts, pts[1:]) if b > a]


def reference_frames(data: bytes) -> list[bytes]:
    return [data[s.start : s.end] for s in iter_segments(data, restart_at_bracket=True) if s.is_frame]  # (serial)


# -- an independent reader of gen captures (test_export, test_stats) -------------------------

BEACON = ["AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel"]
_FRAME = re.compile(rb"\[:(.)(.)\|(.*?)\|C([0-9A-Fa-f]{1,2})\]\r\n")


@dataclass
class RefFrame:
    number: int
    ts_ns: int
    src: str
    dst: str
    ok: bool
    values: dict[str, str] = field(default_factory=dict)  # every value after the frame
    changed: dict[str, str] = field(default_factory=dict)  # values the frame changed
    present: dict[str, str] = field(default_factory=dict)  # values the frame carries


def pcap_payloads(path: Path):
    """(record number, ts_ns, UDP payload) of a classic pcap of Ethernet/IPv4/UDP packets."""
    data = path.read_bytes()
    magic = struct.unpack("<I", data[:4])[0]
    mult = 1 if magic == 0xA1B23C4D else 1000
    off, n = 24, 0
    while off + 16 <= len(data):
        sec, frac, incl, _orig = struct.unpack("<IIII", data[off : off + 16])
        pkt = data[off + 16 : off + 16 + incl]
        off += 16 + incl
        n += 1
        yield n, sec * 1_000_000_000 + frac * mult, pkt[42:]


def reference(path: Path) -> list[RefFrame]:
    """Every SharedLink frame of a gen capture with the values it leaves (independent reader)."""
    names = list(BEACON)
    values: dict[str, str] = {}
    out = []
    for number, ts, payload in pcap_payloads(path):
        for m in _FRAME.finditer(payload):
            dst, src, body, ck = (g.decode("latin-1") for g in m.groups())
            ok = (sum(f":{dst}{src}|{body}|C".encode("latin-1")) & 0xFF) == int(ck, 16)
            fr = RefFrame(number, ts, src, dst, ok)
            if ok:
                fields = body.split("|")
                if any(f.startswith("Q") for f in fields) and not any(f.startswith("D") for f in fields):
                    names = [f[1:] for f in fields if f.startswith("Q")]  # a declaration
                elif any(f.startswith("Q") for f in fields):
                    for q, d in zip(fields[2::3], fields[3::3]):
                        fr.present[q[1:]] = d[1:]
                else:
                    for name, d in zip(names, [f for f in fields if f.startswith("D")]):
                        if d != "D":
                            fr.present[name] = d[1:]
                for k, v in fr.present.items():
                    if values.get(k) != v:
                        fr.changed[k] = v
                values.update(fr.present)
            fr.values = dict(values)
            out.append(fr)
    return out


def interleaved(streams: dict[int, list[bytes]], rng: random.Random) -> tuple[list[tuple[bytes, int]], list[int]]:
    """The chunks of each direction in ``streams`` as serial records ``(bytes, direction)``, the
    directions interleaved at random, and their times (ns, 1 us to 2 ms apart from 1,700,000,000 s)."""
    queues = {d: list(chunks) for d, chunks in streams.items()}
    ts = 1_700_000_000 * 10**9
    records: list[tuple[bytes, int]] = []
    times: list[int] = []
    while any(queues.values()):
        d = rng.choice([k for k, q in queues.items() if q])
        ts += rng.randint(1000, 2_000_000)
        records.append((queues[d].pop(0), d))
        times.append(ts)
    return records, times


def write_interleaved(path: Path, streams: dict[int, list[bytes]], seed: int) -> Path:
    """A serial capture (pcapng) of the chunks of each direction in ``streams``, the directions'
    records interleaved at random (``seed``), each chunk one record."""
    records, times = interleaved(streams, random.Random(seed))
    return write_serial(path, records, times=times)
