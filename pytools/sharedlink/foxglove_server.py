"""``watch --foxglove``'s WebSocket server: foxglove-sdk's, reachable under both names of its protocol.

foxglove-sdk's server (0.30) accepts only clients that offer the ``foxglove.sdk.v1`` subprotocol
and answers any other with 400 ("Missing expected sec-websocket-protocol header"; the name is a
constant of its handshake, with no option). Foxglove offers both names, but its ``FoxgloveClient``
(``@foxglove/ws-protocol``), Lichtblick and other clients offer only ``foxglove.websocket.v1`` —
the same protocol under its earlier name (Foxglove's own statement; Lichtblick later added the new
name beside the old one). So the SDK's server listens on a free loopback port, and
:class:`SubprotocolFront` listens on the address asked for: it reads each client's HTTP upgrade
request, where the client offers ``foxglove.websocket.v1`` and not ``foxglove.sdk.v1`` it names
``foxglove.sdk.v1`` instead, and in the SDK's answer it names the client's choice again (the
``Sec-WebSocket-Accept`` key does not depend on the subprotocol); every byte after the two
headers is passed through as it is, both ways. Nothing else of the protocol is touched.

:class:`RateLimitedLog` keeps the SDK's log lines (a client subscribing to an unknown channel
10,000 times logged 10,000 errors) to one per kind of message every :data:`LOG_INTERVAL_S`
seconds, with the count of those left out.
"""

from __future__ import annotations

import logging
import re
import socket
import sys
import threading
import time
from typing import IO, Any

#: the subprotocol foxglove-sdk's server speaks, and the earlier name of the same protocol
SDK_PROTOCOL = "foxglove.sdk.v1"
WEBSOCKET_PROTOCOL = "foxglove.websocket.v1"
#: the longest HTTP upgrade request or answer head read, bytes; how long it may take, seconds
MAX_HEAD = 16384
HEAD_TIMEOUT_S = 10.0
#: seconds the relays get, at stop, to pass the SDK's close frames on before they are cut
CLOSE_GRACE_S = 2.0
#: clients served at once (a further one is closed at once)
MAX_CLIENTS = 64
#: the SDK's log: one line per kind of message in this many seconds
LOG_INTERVAL_S = 10.0

_PROTOCOL_HEADER = re.compile(rb"^sec-websocket-protocol:[ \t]*([^\r\n]*?)[ \t]*(?=\r?$)", re.I | re.M)


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP head (through the blank line) and what came after it."""
    buf = b""
    deadline = time.monotonic() + HEAD_TIMEOUT_S
    while b"\r\n\r\n" not in buf:
        left = deadline - time.monotonic()
        if left <= 0 or len(buf) > MAX_HEAD:
            raise ConnectionError("no complete HTTP head")
        sock.settimeout(left)
        chunk = sock.recv(4096)
        if not chunk:
            raise ConnectionError("closed during the handshake")
        buf += chunk
    sock.settimeout(None)
    end = buf.index(b"\r\n\r\n") + 4
    return buf[:end], buf[end:]


def offered(head: bytes) -> list[str]:
    """The subprotocols a client's upgrade request offers (every Sec-WebSocket-Protocol header)."""
    return [p.strip() for m in _PROTOCOL_HEADER.finditer(head) for p in m.group(1).decode("latin-1").split(",") if p.strip()]


def rewrite_request(head: bytes) -> tuple[bytes, str | None]:
    """The request to pass on, and the name to give the client back (None: pass the answer as is)."""
    names = offered(head)
    if SDK_PROTOCOL in names or WEBSOCKET_PROTOCOL not in names:
        return head, None
    lines = [ln for ln in head.split(b"\r\n") if not _PROTOCOL_HEADER.match(ln)]
    # the request line and headers, then ours, then the blank line that ends the head
    lines[-2:-2] = [b"Sec-WebSocket-Protocol: " + SDK_PROTOCOL.encode()]
    return b"\r\n".join(lines), WEBSOCKET_PROTOCOL


def rewrite_answer(head: bytes, name: str | None) -> bytes:
    if name is None:
        return head
    return _PROTOCOL_HEADER.sub(b"Sec-WebSocket-Protocol: " + name.encode(), head, count=1)


class SubprotocolFront:
    """Listens on ``host:port`` and relays each client to the SDK's server on ``backend``."""

    def __init__(self, host: str, port: int, backend: tuple[str, int]) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = socket.create_server((host, port), family=family)
        self.port = self.sock.getsockname()[1]
        self.backend = backend
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)  # notified when a connection is forgotten
        self._closed = False
        self._thread = threading.Thread(target=self._accept, name="foxglove-front", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while True:
            try:
                client, _addr = self.sock.accept()
            except OSError:
                return  # closed
            with self._lock:
                if self._closed or len(self._conns) >= 2 * MAX_CLIENTS:
                    client.close()
                    continue
                self._conns.add(client)
            threading.Thread(target=self._serve, args=(client,), name="foxglove-client", daemon=True).start()

    def _forget(self, *socks: socket.socket) -> None:
        with self._lock:
            for s in socks:
                self._conns.discard(s)
            self._idle.notify_all()
        for s in socks:
            try:
                s.close()
            except OSError:
                pass

    def _serve(self, client: socket.socket) -> None:
        upstream: socket.socket | None = None
        try:
            head, rest = _read_head(client)
            head, name = rewrite_request(head)
            upstream = socket.create_connection(self.backend, timeout=HEAD_TIMEOUT_S)
            with self._lock:
                if self._closed:
                    raise ConnectionError("stopped")
                self._conns.add(upstream)
            upstream.sendall(head + rest)
            answer, after = _read_head(upstream)
            client.sendall(rewrite_answer(answer, name) + after)
        except (OSError, ConnectionError, ValueError):
            self._forget(client, *([upstream] if upstream is not None else []))
            return
        back = threading.Thread(target=self._pipe, args=(upstream, client), name="foxglove-relay", daemon=True)
        back.start()
        self._pipe(client, upstream)
        back.join()
        self._forget(client, upstream)

    @staticmethod
    def _pipe(src: socket.socket, dst: socket.socket) -> None:
        """Bytes from ``src`` to ``dst`` until either side closes; then both directions end."""
        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def close(self, grace: float = 0.0) -> None:
        """Stop accepting; let the relays that are still open end by themselves for up to
        ``grace`` seconds (the SDK's close frames reach the clients), then cut the rest."""
        with self._lock:
            self._closed = True
            self._idle.wait_for(lambda: not self._conns, timeout=grace)
            conns = list(self._conns)
        try:
            self.sock.close()
        except OSError:
            pass
        for s in conns:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._thread.join(timeout=2)


class RateLimitedLog(logging.Handler):
    """Writes log records to ``stream`` (stderr), each kind of message (its text with numbers
    left out) at most once per ``interval`` seconds; the next one says how many were left out."""

    MAX_KINDS = 256

    def __init__(self, stream: IO[str] | None = None, interval: float = LOG_INTERVAL_S, prefix: str = "") -> None:
        super().__init__()
        self.stream = stream
        self.interval = interval
        self.prefix = prefix
        self._seen: dict[str, tuple[float, int]] = {}  # kind -> (when last written, left out since)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            kind = record.name + " " + re.sub(r"\d+", "#", text)
            now = time.monotonic()
            last = self._seen.get(kind)
            if last is not None and now - last[0] < self.interval:
                self._seen[kind] = (last[0], last[1] + 1)
                return
            if last is None and len(self._seen) >= self.MAX_KINDS:
                self._seen.clear()
            self._seen[kind] = (now, 0)
            more = f" ({last[1]} more like it left out)" if last is not None and last[1] else ""
            stream = self.stream if self.stream is not None else sys.stderr
            stream.write(f"{self.prefix}{text}{more}\n")
            stream.flush()
        except Exception:  # a logging handler never raises
            self.handleError(record)


def quiet_sdk_log(prefix: str = "sharedlink watch: foxglove: ") -> RateLimitedLog:
    """The SDK's log lines (logger ``foxglove`` and below) through :class:`RateLimitedLog` only."""
    log = logging.getLogger("foxglove")
    for h in list(log.handlers):
        if isinstance(h, RateLimitedLog):
            return h
    handler = RateLimitedLog(prefix=prefix)
    log.addHandler(handler)
    log.propagate = False
    return handler


class LiveServer:
    """foxglove-sdk's WebSocket server for ``context`` behind a :class:`SubprotocolFront` on
    ``host:port`` (0: any free port, then :attr:`port`)."""

    def __init__(self, context: Any, host: str = "127.0.0.1", port: int = 8765, name: str = "sharedlink watch") -> None:
        import foxglove

        quiet_sdk_log()
        self.sdk = foxglove.start_server(name=name, host="127.0.0.1", port=0, context=context)
        try:
            self.front = SubprotocolFront(host, port, ("127.0.0.1", self.sdk.port))
        except BaseException:
            self.sdk.stop()
            raise
        self.port = self.front.port

    def stop(self) -> None:
        """The SDK's server first (it closes its clients' connections properly, through the
        front), then the front."""
        try:
            self.sdk.stop()
        finally:
            self.front.close(grace=CLOSE_GRACE_S)
