"""A capture read once for ``watch``: its SharedLink frames and its P2OS and blackboard messages
in one pass over the records, so standard input (a pipe, even a live one that never ends) gives
what the same file given by name gives.

The frames are :func:`~sharedlink.capture.stream.iter_frames`' and the messages
:func:`~sharedlink.analysis.sessions.iter_sessions`', merged by time as ``heapq.merge`` merges
the two readings (a frame first on equal times). Memory stays bounded: an item waits only while
an item of the other kind could still come before it, i.e. until a record with a later time is read.

Which captures have robot links is decided as
:func:`~sharedlink.robot_watch.has_robot_traffic` decides it, on the way: the messages are read
while one of the first :data:`~sharedlink.robot_watch.PROBE_RECORDS` records (or a message) shows
robot traffic, and no longer once that many records showed none.
"""

from __future__ import annotations

import heapq
import queue
import threading
import time
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Union

from sharedlink.analysis.sessions import SessionMessage, SessionReader, record_sessions
from sharedlink.capture.packets import PacketDecoder
from sharedlink.capture.pcapio import CaptureError, Record, read_records
from sharedlink.capture.serial_format import USER_LINKTYPES
from sharedlink.capture.stream import FrameSplitter, SerialSplitter, StreamFrame
from sharedlink.robot_watch import PROBE_RECORDS, is_robot_record

Item = Union[StreamFrame, SessionMessage]


class _Frames:
    """:func:`~sharedlink.capture.stream.iter_frames`, one record at a time."""

    def __init__(self) -> None:
        self.splitter = FrameSplitter()
        self.serial = SerialSplitter()
        self.decode = PacketDecoder().decode  # IP fragments reassembled

    def feed(self, rec: Record) -> list[Any]:
        if rec.linktype in USER_LINKTYPES:
            return self.serial.feed(rec.number, rec.ts_ns, rec.linktype, rec.data, rec.flags, rec.interface)
        dg = self.decode(rec.linktype, rec.data)
        if dg is None:
            return []
        return self.splitter.split(rec.number, rec.ts_ns, dg)

    def flush(self) -> list[Any]:
        return self.serial.flush()


class CaptureItems:
    """The frames (and with ``sessions``, the messages) of a capture, by time, reading it once.
    ``sessions``: True (``--foxglove``), False, or None (read them if the capture has robot
    links, decided as :func:`~sharedlink.robot_watch.has_robot_traffic` decides it). Iterating
    raises :class:`~sharedlink.capture.pcapio.CaptureError` on damage, after every item before it."""

    def __init__(self, path: str | Path, sessions: bool | None = False) -> None:
        self.path = path
        self.sessions = sessions
        self.frames: deque[StreamFrame] = deque()
        self.messages: deque[SessionMessage] = deque()

    def __iter__(self) -> Iterator[Item]:
        frames = _Frames()
        reader: SessionReader | None = SessionReader() if self.sessions is not False else None
        probe = self.sessions is None
        seen = 0
        try:
            for rec in read_records(self.path):
                self.frames.extend(f for f in frames.feed(rec) if isinstance(f, StreamFrame))
                if reader is not None:
                    self.messages.extend(record_sessions(reader, rec))
                    if probe:  # (as has_robot_traffic: the first PROBE_RECORDS records)
                        seen += 1
                        if self.messages or is_robot_record(rec):
                            probe, self.sessions = False, True
                        elif seen >= PROBE_RECORDS:
                            probe, self.sessions, reader = False, False, None
                yield from self._due(rec.ts_ns)
        except CaptureError:
            self.frames.extend(f for f in frames.flush() if isinstance(f, StreamFrame))
            yield from self._rest()
            raise
        self.frames.extend(f for f in frames.flush() if isinstance(f, StreamFrame))
        if reader is not None:
            self.messages.extend(reader.finish())  # (blackboard text a TCP stream holds at the end)
        yield from self._rest()

    def _due(self, now_ns: int) -> Iterator[Item]:
        """What can go out after a record at ``now_ns``: items to come have times from it on
        (a frame goes first on an equal time, as in ``heapq.merge``)."""
        frames, messages = self.frames, self.messages
        if self.sessions is not True:  # (undecided: no message yet, else it would be decided)
            while frames:
                yield frames.popleft()
            return
        while frames or messages:
            if frames and (frames[0].ts_ns <= messages[0].ts_ns if messages else frames[0].ts_ns <= now_ns):
                yield frames.popleft()
            elif messages and (messages[0].ts_ns < frames[0].ts_ns if frames else messages[0].ts_ns < now_ns):
                yield messages.popleft()
            else:
                return

    def _rest(self) -> Iterator[Item]:
        frames, messages = list(self.frames), list(self.messages)
        self.frames.clear()
        self.messages.clear()
        if self.sessions is not True:
            messages = []
        yield from heapq.merge(frames, messages, key=_ts_ns)


def _ts_ns(item: Any) -> int:
    return item.ts_ns


#: what :meth:`Taker.take` returns when nothing came in time, and at the capture's end
NOTHING, END = object(), object()


class Taker:
    """The items of a :class:`CaptureItems` one at a time. A file is read when an item is
    wanted; standard input by a thread of its own into a bounded queue, so a live pipe that goes
    quiet (a link down) leaves the watch free to show what it has and to tick its clock."""

    def __init__(self, items: CaptureItems, threaded: bool, backlog: int = 4096) -> None:
        self._it = iter(items)
        self._queue: queue.Queue[Any] | None = None
        if threaded:
            self._queue = queue.Queue(backlog)
            threading.Thread(target=self._read, name="watch-capture", daemon=True).start()

    def _read(self) -> None:
        put = self._queue.put  # type: ignore[union-attr]
        try:
            for item in self._it:
                put(item)
            put(END)
        except Exception as exc:  # CaptureError (damage), handed to the watch
            put(exc)

    def take(self, until: float) -> Any:
        """The next item, :data:`END`, or (standard input) :data:`NOTHING` if none came by
        ``until`` (a monotonic time); raises what the reading raised."""
        if self._queue is None:
            return next(self._it, END)
        try:
            got = self._queue.get(timeout=max(0.0, until - time.monotonic()))
        except queue.Empty:
            return NOTHING
        if isinstance(got, Exception):
            raise got
        return got
