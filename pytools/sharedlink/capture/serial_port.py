"""Live serial capture: read one port (or relay between two as a tap) into a serial capture.

Each chunk is written as it arrives (flushed, so a killed capture is still readable); the
file format and the writer are in :mod:`sharedlink.capture.serial_format`.
"""

from __future__ import annotations

import os
import selectors
import signal
import time
from dataclasses import dataclass, field
from typing import Callable

from .serial_format import DIR_IN, DIR_OUT, DIRECTION_NAMES, SerialCaptureWriter

# -- live capture -----------------------------------------------------------------------------


@dataclass
class CaptureStats:
    records: int = 0
    bytes: int = 0
    by_direction: dict[str, int] = field(default_factory=dict)
    stopped_by: str = ""


class _Stop:
    """SIGTERM / SIGINT handling for the capture loop: the loop ends, the file stays whole."""

    def __init__(self) -> None:
        self.reason = ""
        self._old: dict[int, object] = {}

    def __enter__(self) -> _Stop:
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                self._old[sig] = signal.signal(sig, self._handler)
            except (ValueError, OSError):  # not the main thread
                pass
        return self

    def _handler(self, signum: int, _frame: object) -> None:
        self.reason = signal.Signals(signum).name

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)  # type: ignore[arg-type]


def open_port(device: str, baud: int, timeout: float | None = 0) -> object:
    """Open ``device`` with pyserial (8N1, raw); ``serial.SerialException`` on failure."""
    import serial  # noqa: PLC0415 (pyserial is only needed for live capture)

    return serial.serial_for_url(device, baudrate=baud, timeout=timeout, exclusive=None)


def capture(
    writer: SerialCaptureWriter,
    device: str | None,
    baud: int,
    tap: tuple[str, str] | None = None,
    duration: float | None = None,
    count: int | None = None,
    on_record: Callable[[int, bytes], None] | None = None,
    on_ready: Callable[[], None] | None = None,
) -> CaptureStats:
    """Read ``device`` (all records inbound) or, with ``tap=(A, B)``, relay A <-> B recording
    bytes read from A as inbound and bytes read from B as outbound, until SIGINT/SIGTERM,
    ``duration`` seconds or ``count`` records; ``on_ready`` is called once the ports are open.
    Raises ``serial.SerialException`` / ``OSError`` when a port cannot be opened."""
    stats = CaptureStats()
    ports: list = []
    try:
        routes = _routes(device, baud, tap, ports)
        sel = selectors.DefaultSelector()
        for i, (src, _dst, _d) in routes.items():
            sel.register(src.fileno(), selectors.EVENT_READ, i)  # type: ignore[attr-defined]
        deadline = time.monotonic() + duration if duration else None
        with _Stop() as stop:
            if on_ready:
                on_ready()
            while not stop.reason:
                wait = _wait(stats, count, deadline)
                if wait is None:
                    break
                try:
                    events = sel.select(wait)
                except InterruptedError:  # pragma: no cover - PEP 475 retries
                    continue
                for key, _mask in events:
                    if not _relay(key.fd, routes[key.data], writer, stats, stop, on_record):
                        break
            if stop.reason and not stats.stopped_by:
                stats.stopped_by = stop.reason
        sel.close()
    finally:
        for p in ports:
            try:
                p.close()  # type: ignore[attr-defined]
            except Exception:  # pragma: no cover - closing a port that went away
                pass
    return stats


def _routes(device: str | None, baud: int, tap: tuple[str, str] | None, ports: list) -> dict[int, tuple]:
    """The ports opened (each appended to ``ports`` as it opens, to be closed): selector key ->
    (port read, port written or None, direction recorded)."""
    if tap:
        a = open_port(tap[0], baud)
        ports.append(a)
        b = open_port(tap[1], baud)
        ports.append(b)
        return {0: (a, b, DIR_IN), 1: (b, a, DIR_OUT)}
    if device is None:
        raise ValueError("no device to capture")
    a = open_port(device, baud)
    ports.append(a)
    return {0: (a, None, DIR_IN)}


def _wait(stats: CaptureStats, count: int | None, deadline: float | None) -> float | None:
    """How long to wait for the ports now; None when ``count`` records or the deadline are
    reached (said in ``stats.stopped_by``)."""
    if count is not None and stats.records >= count:
        stats.stopped_by = "count"
        return None
    if deadline is None:
        return 0.2
    left = deadline - time.monotonic()
    if left <= 0:
        stats.stopped_by = "duration"
        return None
    return min(0.2, left)


def _relay(fd: int, route: tuple, writer: SerialCaptureWriter, stats: CaptureStats, stop: _Stop,
           on_record: Callable[[int, bytes], None] | None) -> bool:
    """Read what port ``fd`` has, pass it on (a tap) and record it; False when the capture ends
    (the line gone, the output's reader gone: said in ``stats`` and ``stop``)."""
    _src, dst, d = route
    try:
        data = os.read(fd, 65536)
    except BlockingIOError:
        return True
    except OSError as exc:
        # a pty whose other end closed: EIO; the line is gone
        stats.stopped_by = f"read error: {exc.strerror or exc}"
        stop.reason = stop.reason or "eof"
        return False
    if not data:
        stats.stopped_by = "end of file"
        stop.reason = stop.reason or "eof"
        return False
    ts = time.time_ns()
    if dst is not None:
        _write_all(dst.fileno(), data)  # type: ignore[attr-defined]
    try:
        writer.write(data, d, ts)
    except BrokenPipeError:  # the reader of a fifo went away
        stats.stopped_by = "reader closed the output"
        stop.reason = stop.reason or "epipe"
        return False
    stats.records += 1
    stats.bytes += len(data)
    name = DIRECTION_NAMES[d]
    stats.by_direction[name] = stats.by_direction.get(name, 0) + len(data)
    if on_record:
        on_record(d, data)
    return True


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        try:
            n = os.write(fd, view)
        except BlockingIOError:
            time.sleep(0.001)
            continue
        view = view[n:]


def list_ports() -> list[tuple[str, str]]:
    """(device, description) of the machine's serial ports (pyserial's list_ports)."""
    try:
        from serial.tools import list_ports as lp  # noqa: PLC0415
    except ImportError:  # pragma: no cover
        return []
    return sorted((p.device, p.description or p.device) for p in lp.comports())


def port_error(device: str, exc: BaseException) -> str:
    """The one message for a serial port that would not open, in every command (serial capture,
    replay --serial, watch --serial): ``DEVICE: cannot open it: No such file or directory``.
    pyserial's own ("[Errno 2] could not open port X: [Errno 2] No such file or directory: 'X'")
    says the errno and the name twice."""
    code = getattr(exc, "errno", None)
    if isinstance(code, int) and code > 0:
        return f"{device}: cannot open it: {os.strerror(code)}"
    return f"{device}: cannot open it: {exc}"
