"""The P2OS resynchronisation vectors (tests/vectors/p2os-resync.json; the rule:
docs/fields-p2os-blackboard.md, "Resynchronisation"), run by both decoders on every transport: a
cut-off packet whose claimed span ends on the FA of the next good packet's header gives way to
that packet (it swallowed it in Python, p2os.lua and serial.lua alike), and the neighbouring
cases keep what they gave. Python: ``p2os.iter_chunks``, the serial reader cut anywhere, the
session reader over TCP and UDP; p2os.lua over TCP (every two-segment split of each stream) and
UDP; serial.lua with p2os.lua over a serial line (a record, a byte a record)."""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import pytest
from sl_robots import OTHERS, SERIAL, serial_frames, write_serial

import tshark_util as tu
from sharedlink.analysis.sessions import iter_sessions
from sharedlink.capture.packets import session_frames
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.capture.serial_format import DIR_OUT, Deframer
from sharedlink.protocols import p2os

REPO = Path(__file__).resolve().parents[2]
VECTORS = json.loads((REPO / "tests" / "vectors" / "p2os-resync.json").read_text())["vectors"]
IDS = [v["name"] for v in VECTORS]
SYNC0 = bytes.fromhex("FAFB03000000")
NAMES = ["tcp.srcport", "udp.srcport", "p2os.count", "p2os.checksum.status", "p2os.junk"]


def _data(v: dict) -> bytes:
    return bytes.fromhex(v["hex"])


def _packets(v: dict) -> list[tuple[bytes, bool]]:
    """The vector's packets: (bytes, checksum good)."""
    return [(bytes.fromhex(p["hex"]), p["kind"] == "good") for p in v["pieces"] if p["kind"] != "junk"]


def _junk(v: dict) -> bytes:
    return b"".join(bytes.fromhex(p["hex"]) for p in v["pieces"] if p["kind"] == "junk")


def test_the_vectors_hold_the_edge_and_add_up() -> None:
    """Each stream is its pieces; the edge the rule was written for is there (a junk piece of
    8 bytes whose claimed span ends on the next header's FA)."""
    for v in VECTORS:
        assert b"".join(bytes.fromhex(p["hex"]) for p in v["pieces"]) == _data(v), v["name"]
    edge = next(v for v in VECTORS if v["name"] == "resync-span-ends-on-next-fa")
    first = bytes.fromhex(edge["pieces"][0]["hex"])
    assert first[2] + 3 == len(first) + 1 and _data(edge)[len(first)] == 0xFA


@pytest.mark.parametrize("v", VECTORS, ids=IDS)
def test_python_chunks(v: dict) -> None:
    got = [(c.data.hex().upper(), "junk" if c.packet is None else "good" if c.packet.ok else "bad")
           for c in p2os.iter_chunks(_data(v))]
    assert got == [(p["hex"], p["kind"]) for p in v["pieces"]]


@pytest.mark.parametrize("v", VECTORS, ids=IDS)
def test_python_serial_reader_cut_anywhere(v: dict) -> None:
    """The serial reader's frames, the stream whole, a byte a record, and cut once anywhere
    (a cut right after the span's last FA: it waits for the next byte)."""
    data = _data(v)
    want = [raw for raw, _ok in _packets(v)]
    splits = [[data], [data[i:i + 1] for i in range(len(data))]]
    splits += [[data[:i], data[i:]] for i in range(1, len(data))]
    for chunks in splits:
        d = Deframer("p2os")
        pieces = [p for i, c in enumerate(chunks) for p in d.feed(c, i + 1)] + d.flush()
        assert [p.data for p in pieces if p.is_frame] == want, (v["name"], [len(c) for c in chunks])
        assert b"".join(p.data for p in pieces) == data


def _write(path: Path, convs: list[tuple[str, int, list[bytes]]]) -> Path:
    """One conversation a (transport, client port, client payloads) to port 8101 (TCP) or 9000
    (UDP), one after another."""
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        t = 10**18
        for transport, port, payloads in convs:
            evs = [(t + i * 10_000_000, True, p) for i, p in enumerate(payloads)]
            server = p2os.MOBILESIM_PORT if transport == "tcp" else 9000
            for ts, _c, frame in session_frames(evs, transport, ("127.0.0.1", port), ("127.0.0.1", server)):
                w.write(ts, frame)
            t += 1_000_000_000
    return path


def _by_port(rows: list[dict], key: str) -> dict[int, dict[str, list]]:
    out: dict[int, dict[str, list]] = defaultdict(lambda: {"packets": [], "junk": []})
    for r in rows:
        if not r[key] or not (r["p2os.count"] or r["p2os.junk"]):
            continue
        got = out[int(r[key][0])]
        got["packets"] += [(int(c), s == "1") for c, s in zip(r["p2os.count"], r["p2os.checksum.status"])]
        got["junk"] += [bytes.fromhex(j.replace(":", "")) for j in r["p2os.junk"]]
    return out


def _python_by_port(path: Path) -> dict[int, list[tuple[int, bool]]]:
    out: dict[int, list[tuple[int, bool]]] = defaultdict(list)
    for m in iter_sessions(path):
        port = max(int(end.rsplit(":", 1)[1]) for end in m.label.split(" ", 1)[1].split(" - "))  # the client's
        out[port].append((m.raw[2], bool(m.ok)))
    return out


def test_p2os_lua_and_python_over_tcp_every_split(tmp_path: Path) -> None:
    """Every stream sent whole and cut into two segments at every byte (one conversation each,
    one tshark run; a SYNC0 segment first, so that the Python reader, which detects P2OS by a
    good packet, takes a stream with none): p2os.lua and the Python session reader give the
    vector's packets (count and checksum verdict), and p2os.lua its junk. (Before the rule, a
    cut at 2 or 3 bytes lost p2os.lua every packet: it asked TCP for the bytes the false count
    claimed.)"""
    convs, want = [], {}
    for v in VECTORS:
        data = _data(v)
        for i in range(len(data)):
            port = 40000 + len(convs)
            convs.append(("tcp", port, [SYNC0, data] if i == 0 else [SYNC0, data[:i], data[i:]]))
            want[port] = (v["name"], i, [(3, True)] + [(raw[2], ok) for raw, ok in _packets(v)], _junk(v))
    cap = _write(tmp_path / "tcp.pcap", convs)
    lua = _by_port(tu.fields(cap, NAMES, extra=OTHERS, two_pass=True), "tcp.srcport")
    py = _python_by_port(cap)
    for port, (name, i, packets, junk) in want.items():
        assert lua[port]["packets"] == packets, (name, i)
        assert b"".join(lua[port]["junk"]) == junk, (name, i)
        assert py[port] == packets, (name, i)


def test_p2os_lua_and_python_over_udp(tmp_path: Path) -> None:
    """Each stream in one datagram, after a SYNC0 that lets the heuristic take the conversation."""
    convs = [("udp", 41000 + k, [SYNC0, _data(v)]) for k, v in enumerate(VECTORS)]
    cap = _write(tmp_path / "udp.pcap", convs)
    lua = _by_port(tu.fields(cap, NAMES, extra=OTHERS, two_pass=True), "udp.srcport")
    py = _python_by_port(cap)
    for k, v in enumerate(VECTORS):
        packets = [(3, True)] + [(raw[2], ok) for raw, ok in _packets(v)]
        assert lua[41000 + k]["packets"] == packets, v["name"]
        assert b"".join(lua[41000 + k]["junk"]) == _junk(v), v["name"]
        assert py[41000 + k] == packets, v["name"]


@pytest.mark.parametrize("size", [0, 1, 7])
def test_serial_lua_and_python_on_a_serial_line(tmp_path: Path, size: int) -> None:
    """Every stream one after another on a serial line (each ends with a whole piece), in one
    record (0), a byte a record, 7 bytes a record: serial.lua's frames are the Python reader's,
    which are the vectors' packets, and p2os.lua's checksum verdicts theirs."""
    data = b"".join(_data(v) for v in VECTORS)
    want = [raw for v in VECTORS for raw, _ok in _packets(v)]
    chunks = [data] if size == 0 else [data[i:i + size] for i in range(0, len(data), size)]
    cap = write_serial(tmp_path / "serial.pcapng", [(c, DIR_OUT) for c in chunks], step_ns=1000)
    py, lua = serial_frames(cap)
    assert py == {"0": want, "1": []}
    assert lua == py
    rows = tu.fields(cap, ["p2os.checksum.status"], prefs=SERIAL, extra=OTHERS, two_pass=True)
    assert [s == "1" for r in rows for s in r["p2os.checksum.status"]] == [ok for v in VECTORS for _r, ok in _packets(v)]
