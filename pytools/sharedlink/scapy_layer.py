"""A scapy layer for SharedLink, bound to UDP port 7013, for crafting frames interactively.

>>> from scapy.all import Ether, IP, UDP
>>> from sharedlink.scapy_layer import SharedLink
>>> pkt = IP(dst="127.0.0.1") / UDP(sport=7013, dport=7013) / SharedLink(dst="A", src="B",
...         body="N0|T2|QAutoGpsLat|D38.34698779")
>>> bytes(pkt[SharedLink])
b'[:AB|N0|T2|QAutoGpsLat|D38.34698779|C37]\\r\\n'

``chksum`` left as None is computed by the codec when the packet is built; set it to a string
to send a wrong one. Dissecting goes through :func:`sharedlink.protocols.codec.parse_frame`, so the
layer and the command line tools agree on every byte.
"""

from __future__ import annotations

from typing import Any

from scapy.fields import StrField
from scapy.layers.inet import UDP
from scapy.packet import Packet, bind_layers

from sharedlink.protocols.codec import Field, Frame, SharedLinkError, build_frame, parse_frame

SHAREDLINK_PORT = 7013


def _fields_of(body: str) -> tuple[Field, ...]:
    if not body:
        return ()
    return tuple(Field(p[:1], p[1:]) for p in body.split("|"))


class SharedLink(Packet):
    name = "SharedLink"
    fields_desc = [
        StrField("dst", b"A"),
        StrField("src", b"B"),
        StrField("body", b""),
        StrField("chksum", None),
        StrField("crlf", b"\r\n"),
    ]

    def frame(self) -> Frame:
        return Frame(
            self.dst.decode("latin-1"),
            self.src.decode("latin-1"),
            _fields_of(self.body.decode("latin-1")),
            crlf=bool(self.crlf),
        )

    def self_build(self, *args: Any, **kwargs: Any) -> bytes:
        ck = self.chksum.decode("latin-1") if self.chksum is not None else None
        return build_frame(self.frame(), checksum_text=ck)

    def do_dissect(self, s: bytes) -> bytes:
        end = s.find(b"]")
        if end < 0:
            self.body = s
            return b""
        end += 1
        if s[end : end + 2] == b"\r\n":
            end += 2
        raw, rest = s[:end], s[end:]
        try:
            fr = parse_frame(raw)
        except SharedLinkError:
            self.body = raw
            return rest
        self.dst = fr.dst.encode("latin-1")
        self.src = fr.src.encode("latin-1")
        self.body = "|".join(f.encode() for f in fr.fields).encode("latin-1")
        self.chksum = fr.checksum.text.encode("latin-1") if fr.checksum and fr.checksum.text is not None else None
        self.crlf = b"\r\n" if fr.crlf else b""
        return rest

    def guess_payload_class(self, payload: bytes) -> type[Packet]:
        return SharedLink if payload.startswith(b"[") else Packet.guess_payload_class(self, payload)

    def mysummary(self) -> str:
        try:
            fr = parse_frame(bytes(self)[: len(self.self_build())])
        except SharedLinkError:
            return "SharedLink (malformed)"
        status = {True: "good", False: "BAD", None: "unverified"}[fr.checksum.ok if fr.checksum else None]
        return f"SharedLink {fr.src}->{fr.dst} {fr.kind} checksum {status}"


bind_layers(UDP, SharedLink, dport=SHAREDLINK_PORT)
bind_layers(UDP, SharedLink, sport=SHAREDLINK_PORT)
