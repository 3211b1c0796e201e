"""Replay a TCP capture over TCP (``sharedlink replay``), either side or both.

A P2OS robot session (TCP 8101) or a blackboard link over TCP carries no UDP payload: replay then
plays one side of the conversation, or both (``--side``), one ``send`` per captured segment (Nagle
off, so the segments keep their timing), in capture order with the capture's timing:

* ``client`` (the default): it connects to ``--to HOST:PORT`` (the port defaults to the capture's
  server port) and writes the client-to-server segments' payloads; the host replayed to is the
  server (a robot, MobileSim) and answers for itself (:class:`TcpSink`);
* ``server``: it plays the robot (or the blackboard post office): it listens on ``--bind
  ADDR[:PORT]`` (default 127.0.0.1 on the captured server port), waits for one client to connect
  (ARIA, a ROS driver, a test program) and writes the server-to-client segments' payloads (a
  robot's SIPs) from then on, at the capture's pace, whatever the client sends (read and
  dropped: the recording does not answer) (:class:`TcpServerSink`);
* ``both``: the whole conversation again on this machine: a listener on ``--to HOST:PORT``
  (default 127.0.0.1 on the captured server port; port 0: any free one) and a connection to it,
  each side's segments written on its own end (:class:`TcpPairSink`): what a sniffer (``watch
  --interface lo``, Wireshark) sees is the session replayed.

The server port is the destination of the first SYN; without a handshake in the capture, the
lower port of the first conversation that carries data. Retransmitted bytes (a segment whose
sequence range was already sent) are sent once.
"""

from __future__ import annotations

import ipaddress
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sharedlink.capture.packets import PacketDecoder
from sharedlink.capture.pcapio import read_records
from sharedlink.replay import USER_LINKTYPES, FrameFilter, OutFrame, SourceCounts
from sharedlink.replay_sinks import ReplayError, SinkStalled, Target, _resolve, split_host_port

SYN, ACK = 0x02, 0x10
SEQ_MOD = 1 << 32
#: what ``--side`` may be
SIDES = ("client", "server", "both")


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
    """The segments of a TCP capture one side sent (``side`` client: those sent to ``server_port``;
    server: those sent from it; both), as :class:`~sharedlink.replay.OutFrame` s (``port``: the
    segment's destination port, the server port for a client's); iterate again for another pass.
    Bytes already sent (retransmissions) are left out; segments without payload are counted as
    skipped."""

    def __init__(self, path: str | Path, server_port: int, flt: FrameFilter | None = None, side: str = "client") -> None:
        self.path = Path(path)
        self.server_port = server_port
        self.filter = flt or FrameFilter()
        self.counts = SourceCounts()
        self.side = side

    def __iter__(self) -> Iterator[OutFrame]:
        counts, port = self.counts, self.server_port
        ports, nets = set(self.filter.ports), self.filter.src
        decode = PacketDecoder().decode
        sent_to: dict[tuple[str, int, str], int] = {}  # (sender, its port, receiver) -> next sequence number
        client, server = self.side in ("client", "both"), self.side in ("server", "both")
        for rec in read_records(self.path):
            counts.records += 1
            d = decode(rec.linktype, rec.data)
            if (d is None or d.proto != "tcp" or not d.payload
                    or not ((client and d.dport == port) or (server and d.sport == port and d.dport != port))):
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
    peer closed or reset raises :class:`~sharedlink.replay_sinks.SinkStalled` (the replay stops)."""

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


def _drain(sock: socket.socket) -> threading.Thread:
    """Read and drop what the peer sends until it closes (a thread): the recording does not
    answer, and an unread socket would stop the peer once the buffers are full."""

    def run() -> None:
        while True:
            try:
                if not sock.recv(65536):
                    return
            except socket.timeout:  # (a connection with a send timeout: quiet for a while)
                continue
            except OSError:
                return

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def _listener(host: str, port: int, what: str) -> socket.socket:
    fam, addr = _resolve(host, port, what)
    lsock = socket.socket(fam, socket.SOCK_STREAM)
    try:
        lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        lsock.bind(addr)
        lsock.listen(1)
    except OSError as exc:
        lsock.close()
        raise ReplayError(f"{what} {host}:{port}: cannot listen over TCP ({exc.strerror or exc})") from None
    return lsock


def _sender(sock: socket.socket, what: str) -> Any:
    sendall = sock.sendall

    def send(payload: bytes) -> Any:
        try:
            return sendall(payload)
        except OSError as exc:
            raise SinkStalled(f"{what}: {exc.strerror or exc}") from None

    return send


def _where(sockname: tuple) -> str:
    host = f"[{sockname[0]}]" if ":" in sockname[0] else sockname[0]
    return f"{host}:{sockname[1]}"


class TcpServerSink:
    """``--side server``: a TCP listener on ``host:port`` that waits (``announce`` says where)
    for one client, then writes each payload to it (Nagle off); what the client sends is read
    and dropped. A client that closed or reset the connection raises SinkStalled."""

    def __init__(self, host: str, port: int, announce: Any = None) -> None:
        lsock = _listener(host, port, "--bind")
        self.where = _where(lsock.getsockname())
        if announce is not None:
            announce(f"waiting for a client to connect to tcp {self.where} (Ctrl-C stops)")
        try:
            self.conn, peer = lsock.accept()
        finally:
            lsock.close()
        self.peer = _where(peer)
        self.conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.reader = _drain(self.conn)
        send = _sender(self.conn, f"tcp {self.peer}")
        self.send = lambda payload, _t: send(payload)

    @property
    def description(self) -> str:
        return f"tcp server {self.where} to client {self.peer}"

    def target(self, frame: OutFrame) -> Target:
        return True

    def close(self) -> None:
        try:
            self.conn.shutdown(socket.SHUT_RDWR)  # (what was written still goes, then the end; the reader wakes)
        except OSError:
            pass
        self.reader.join(5)
        self.conn.close()


class TcpPairSink:
    """``--side both``: a listener on ``host:port`` and a connection to it; a frame sent to the
    server port (a client's) goes out of the client's end, any other (the server's) out of the
    server's; each end's incoming bytes are read and dropped."""

    def __init__(self, host: str, port: int, server_port: int, bind: str | None = None) -> None:
        lsock = _listener(host, port, "--to")
        self.server_port = server_port
        try:
            self.where = _where(lsock.getsockname())
            client = TcpSink(lsock.getsockname()[0], lsock.getsockname()[1], bind=bind)
            lsock.settimeout(5)
            self.conn, _ = lsock.accept()
        finally:
            lsock.close()
        self.client = client
        self.conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.readers = [_drain(self.conn), _drain(client.sock)]
        to_server, to_client = client.send, _sender(self.conn, f"tcp server {self.where}")

        def send(payload: bytes, t: Target) -> Any:
            return to_server(payload, t) if t == "client" else to_client(payload)

        self.send = send

    @property
    def description(self) -> str:
        return f"tcp both sides over {self.where}"

    def target(self, frame: OutFrame) -> Target:
        return "client" if frame.port == self.server_port else "server"  # type: ignore[return-value]

    def close(self) -> None:
        for sock in (self.client.sock, self.conn):
            try:
                sock.shutdown(socket.SHUT_WR)
            except OSError:
                pass
        for t in self.readers:
            t.join(5)
        self.client.sock.close()
        self.conn.close()


__all__ = ["SIDES", "TcpFrames", "TcpPairSink", "TcpServerSink", "TcpSink", "tcp_server_port"]
