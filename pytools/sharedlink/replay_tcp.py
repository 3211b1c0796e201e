"""Replay a TCP capture's client-to-server stream over a TCP connection (``sharedlink replay``).

A P2OS robot session (TCP 8101) or a blackboard link over TCP carries no UDP payload: replay
then plays the client's side of the conversation. It connects to ``--to HOST:PORT`` (the port
defaults to the capture's server port) and writes the payloads of the segments the capture's
client sent to its server, in capture order with the capture's timing, one ``send`` per
segment (Nagle off, so the segments keep their timing). The server's direction (a robot's SIPs)
is not sent: the host replayed to is the server and answers for itself.

The server port is the destination of the first SYN; without a handshake in the capture, the
lower port of the first conversation that carries data. Retransmitted bytes (a segment whose
sequence range was already sent) are sent once.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sharedlink.capture.packets import PacketDecoder
from sharedlink.capture.pcapio import read_records
from sharedlink.replay import (
    USER_LINKTYPES,
    FrameFilter,
    OutFrame,
    ReplayError,
    SinkStalled,
    SourceCounts,
    Target,
    _resolve,
    split_host_port,
)

SYN, ACK = 0x02, 0x10
SEQ_MOD = 1 << 32


def tcp_server_port(path: str | Path) -> int | None:
    """The server port of a capture whose first transport payload is TCP; None when the first
    payload is UDP, or there is none (or the capture is a serial one). Reading stops at the
    first payload; a damaged capture answers with what was read before the damage."""
    from sharedlink.capture.pcapio import CaptureError

    decode = PacketDecoder().decode
    syn_dst: dict[tuple[str, int, str, int], int] = {}
    try:
        for rec in read_records(path):
            if rec.linktype in USER_LINKTYPES:
                return None
            d = decode(rec.linktype, rec.data)
            if d is None:
                continue
            if d.proto == "udp":
                if d.payload:
                    return None
                continue
            if d.tcp_flags & SYN and not d.tcp_flags & ACK:
                syn_dst[(d.src, d.sport, d.dst, d.dport)] = d.dport
                continue
            if d.payload:
                for key in ((d.src, d.sport, d.dst, d.dport), (d.dst, d.dport, d.src, d.sport)):
                    if key in syn_dst:
                        return syn_dst[key]
                return min(d.sport, d.dport)
    except CaptureError:
        pass
    return None


class TcpFrames:
    """The client-to-server segments of a TCP capture (those sent to ``server_port``), as
    :class:`~sharedlink.replay.OutFrame` s; iterate again for another pass. Bytes already sent
    (retransmissions) are left out; segments without payload are counted as skipped."""

    def __init__(self, path: str | Path, server_port: int, flt: FrameFilter | None = None) -> None:
        self.path = Path(path)
        self.server_port = server_port
        self.filter = flt or FrameFilter()
        self.counts = SourceCounts()

    def __iter__(self) -> Iterator[OutFrame]:
        counts, port = self.counts, self.server_port
        ports, nets = set(self.filter.ports), self.filter.src
        decode = PacketDecoder().decode
        sent_to: dict[tuple[str, int, str], int] = {}  # (client, client port, server) -> next sequence number
        for rec in read_records(self.path):
            counts.records += 1
            d = decode(rec.linktype, rec.data)
            if d is None or d.proto != "tcp" or d.dport != port or not d.payload:
                counts.skipped += 1
                continue
            if (ports and d.sport not in ports and d.dport not in ports) or (
                nets and not any(ipaddress.ip_address(d.src) in n for n in nets)
            ):
                counts.filtered += 1
                continue
            payload = _new_bytes(sent_to, (d.src, d.sport, d.dst), d.tcp_seq, d.payload)
            if not payload:
                counts.skipped += 1  # a retransmission of bytes already sent
                continue
            yield OutFrame(rec.number, rec.ts_ns, payload, d.dport, d.src)


def _new_bytes(sent_to: dict[tuple[str, int, str], int], key: tuple[str, int, str], seq: int, payload: bytes) -> bytes:
    """The part of a segment not sent yet (sequence numbers modulo 2^32), and note it sent."""
    end = (seq + len(payload)) % SEQ_MOD
    nxt = sent_to.get(key)
    if nxt is None:
        sent_to[key] = end
        return payload
    behind = (nxt - seq) % SEQ_MOD  # how far the segment starts before the next new byte
    if behind >= SEQ_MOD // 2:  # starts after it (a gap in the capture): send it all
        sent_to[key] = end
        return payload
    if behind >= len(payload):
        return b""
    sent_to[key] = end
    return payload[behind:]


class TcpSink:
    """One TCP connection to ``host:port`` (Nagle off); a payload per ``send``. A connection the
    peer closed or reset raises :class:`~sharedlink.replay.SinkStalled` (the replay stops)."""

    def __init__(self, host: str, port: int, bind: str | None = None, timeout: float = 5.0) -> None:
        fam, addr = _resolve(host, port, "destination")
        self.host, self.port, self.family, self.address = host, port, fam, addr[0]
        self.sock = socket.socket(fam, socket.SOCK_STREAM)
        try:
            self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if bind:
                bhost, bport = split_host_port(bind, "--bind")
                try:
                    self.sock.bind(_resolve(bhost, bport or 0, "--bind")[1])
                except OSError as exc:
                    raise ReplayError(f"--bind {bind}: {exc.strerror or exc}") from None
            self.sock.settimeout(timeout)
            try:
                self.sock.connect(addr)
            except OSError as exc:
                raise ReplayError(f"--to {host}:{port}: cannot connect over TCP ({exc.strerror or exc})") from None
        except BaseException:
            self.sock.close()
            raise
        sendall = self.sock.sendall

        def send(payload: bytes, _t: Target) -> Any:
            try:
                return sendall(payload)
            except OSError as exc:
                raise SinkStalled(f"tcp {self.description[4:]}: {exc.strerror or exc}") from None

        self.send = send

    @property
    def description(self) -> str:
        host = f"[{self.address}]" if self.family == socket.AF_INET6 else self.address
        return f"tcp {host}:{self.port}"

    def target(self, frame: OutFrame) -> Target:
        return True

    def close(self) -> None:
        try:
            self.sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass
        self.sock.close()


__all__ = ["TcpFrames", "TcpSink", "tcp_server_port"]
