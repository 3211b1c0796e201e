"""Hypothesis strategies for varied SharedLink captures (test_diff, test_transform), written
as real pcap files with pcapio and packets: named and positional frames, full and delta,
declarations, replies, queries, two directions, several frames in one datagram, noise, bad
checksums, frames without CR LF, numbers written in different ways."""

from __future__ import annotations

from pathlib import Path

from hypothesis import strategies as st

from sharedlink.codec import (
    Field,
    Frame,
    build_frame,
    declaration_fields,
    named_fields,
    positional_fields,
    query_fields,
    reply_fields,
)
from sharedlink.gen import DEFAULT_START_NS
from sharedlink.packets import UdpBuilder
from sharedlink.pcapio import PcapWriter

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
