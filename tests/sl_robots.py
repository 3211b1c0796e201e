"""P2OS and blackboard captures beside tshark with every dissector, for the tests that compare
them (test_robots_counts.py, test_robot_stats.py, test_robot_export.py, test_p2os.py, and the
serial split tests: :func:`serial_frames`)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import tshark_util as tu
from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT, SerialCaptureWriter, read_capture

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = sorted((REPO / "dissector").glob("*.lua"))
OTHERS = [a for s in SCRIPTS if s.name != "sharedlink.lua" for a in ("-X", f"lua_script:{s}")]
SERIAL = {"uat:user_dlts": '"User 0 (DLT=147)","slserial","0","","0",""'}
#: a serial record's direction -> tshark's slserial.direction
P2P = {DIR_IN: "1", DIR_OUT: "0"}


def serial_frames(cap: Path) -> tuple[dict[str, list[bytes]], dict[str, list[bytes]]]:
    """(Python's, tshark's) frames of a serial capture per direction (slserial.direction's
    "0", "1"), with every dissector."""
    py: dict[str, list[bytes]] = {"0": [], "1": []}
    for _rec, d, piece in read_capture(cap):
        if piece.is_frame:
            py[P2P[d]].append(piece.data)
    lua: dict[str, list[bytes]] = {"0": [], "1": []}
    for r in tu.fields(cap, ["slserial.direction", "slserial.frame"], extra=OTHERS, two_pass=True):
        for h in r["slserial.frame"]:
            lua[r["slserial.direction"][0]].append(bytes.fromhex(h.replace(":", "")))
    return py, lua

def tshark_counts(path: Path, serial: bool = False) -> tuple[Counter, Counter]:
    """(P2OS packets, blackboard messages) per kind as tshark shows them with every dissector."""
    rows = tu.fields(path, ["p2os.header", "p2os.direction", "p2os.checksum.status", "blackboard.type"],
                     prefs=SERIAL if serial else None, extra=OTHERS, two_pass=True)
    p2 = Counter()
    bb = Counter()
    for r in rows:
        for d, s in zip(r["p2os.direction"], r["p2os.checksum.status"]):
            p2[("client" if d == "0" else "robot", s == "1")] += 1
        assert len(r["p2os.header"]) == len(r["p2os.direction"])
        for t in r["blackboard.type"]:
            bb[t] += 1
    return p2, bb


def write_tcp(path: Path, events: list[tuple[bool, bytes]], port: int, times: list[int] | None = None) -> None:
    """A TCP session of ``(from the client, payload)`` events to ``port``: 10 ms apart, or at
    ``times`` (ns from 10**18)."""
    stamps = times if times is not None else [i * 10_000_000 for i in range(len(events))]
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        evs = [(10**18 + t, c, p) for t, (c, p) in zip(stamps, events)]
        for ts, _, frame in session_frames(evs, "tcp", ("127.0.0.1", 40000), ("127.0.0.1", port)):
            w.write(ts, frame)


def write_udp_sessions(path: Path, sessions: list[list[tuple[bool, bytes]]], base_port: int,
                       other: tuple[str, int]) -> Path:
    """UDP sessions, one a source port (``base_port`` + its index, on 127.0.0.1) with ``other``,
    each a list of ``(from that port, datagram)`` 10 ms apart; the sessions 1 s apart from
    10**18 ns."""
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        t = 10**18
        for k, events in enumerate(sessions):
            evs = [(t + i * 10_000_000, c, dg) for i, (c, dg) in enumerate(events)]
            for ts, _c, frame in session_frames(evs, "udp", ("127.0.0.1", base_port + k), other):
                w.write(ts, frame)
            t += 1_000_000_000
    return path


def write_serial(path: Path, records: Sequence[tuple[bytes, int]], step_ns: int = 1_000_000,
                 times: Sequence[int] | None = None) -> Path:
    """A serial capture (pcapng, USER0): one record per ``(bytes, direction)`` (DIR_OUT, DIR_IN),
    ``step_ns`` apart from 1,700,000,000 s, or at ``times`` (ns, one a record). The tests' one
    serial capture writer (the fuzz patterns and the golden inputs' make_inputs.py too)."""
    stamps = times if times is not None else [1_700_000_000 * 10**9 + i * step_ns for i in range(len(records))]
    assert len(stamps) == len(records)
    with open(path, "wb") as fh:
        w = SerialCaptureWriter(fh, flush=False)
        for (data, d), ts in zip(records, stamps):
            w.write(data, d, ts)
    return path
