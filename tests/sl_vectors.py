"""Loader of the shared SharedLink vector tables ``tests/vectors/sharedlink*.json`` (issue 12;
``sharedlink-real-sessions.json``: streams shaped like real sessions, issue 29).

The table holds streams of packets, each with the frames the decoding rules of
docs/fields-sharedlink.md ("Decoding rules") expect in it. Both the tshark tests
(tests/dissector/test_vectors.py) and the Python tests read it, so the two sides cannot drift.

Shape (a key left out means "not checked")::

    {"streams": [
      {"name": ..., "rules": [1, 2], "doc": "why the expectations are what they are",
       "variables": "Lat:2,Lon:2,Note",       # optional a-priori list (sharedlink.variables / --variables)
       "pending": {"tshark": "issue 29: <rule>", "python": "...", "agreement": "..."},  # optional: the
                                               # rule that side does not follow yet (agreement: why the
                                               # two sides differ today); its test runs as a strict xfail
       "transport": "udp" | "tcp" | "serial",
       "packets": [
         {"t": 0.0,                            # seconds from the stream's start
          "src": "10.0.0.2:7013", "dst": "10.0.0.255:7013",   # udp/tcp;  serial: "dir": "in" | "out"
          "payload": "[:AB|N0|D1|C??]\\r\\n",  # latin-1 text; C?? = the right checksum, C!! = a wrong one
          "frames": [                          # one entry per SharedLink frame in the packet, in order
            {"kind": "full" | "delta" | "query" | "reply" | "declaration" | "command" | "ping" | "pong"
                     | "other" | "malformed",
             "checksum": "good" | "bad" | "missing",
             "vars": [{"name", "index", "value", "type": "long" | "double" | "string" | null,
                       "typed": number | string | null, "carried": bool, "carried_from": packet | null,
                       "bad": bool}],          # every variable the frame shows, in index order
             "experts": [...], "no_experts": [...],       # expert abbrevs that must / must not appear
             "response_to": packet | null, "response_in": packet | null}]}]}]}

Packet numbers are 1-based positions in the stream's ``packets`` (one capture record each).
A "pending" side is a rule decided and written (docs/fields-sharedlink.md) but not implemented
there yet: :func:`stream_params` marks that side's test ``xfail(strict=True)`` with the reason,
so it turns into a failure to fix (remove the key) as soon as the implementation follows it.
"""

from __future__ import annotations

import atexit
import copy
import json
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import pytest
from sl_robots import OTHERS, write_serial

from sharedlink.capture.packets import TcpBuilder, UdpBuilder
from sharedlink.capture.pcapio import PcapWriter
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT

VECTORS = Path(__file__).resolve().parent / "vectors" / "sharedlink.json"
#: every vector table, read in name order (sharedlink.json first)
VECTOR_FILES = sorted(VECTORS.parent.glob("sharedlink*.json"))
#: the sides a stream can be pending on ("agreement": tests/dissector/test_agreement.py, the two
#: decoders compared with each other, pending where they differ today)
SIDES = ("tshark", "python", "agreement")
#: capture time of a stream's t = 0 (2026-01-01 12:00 UTC, as the generators use)
START_NS = 1_767_268_800 * 1_000_000_000
SERIAL_DIRS = {"in": DIR_IN, "out": DIR_OUT}
_CHECKSUM_MARK = re.compile(rb"\|C(\?\?|!!)\]")

Stream = dict[str, Any]


def load_streams(paths: list[Path] | None = None) -> list[Stream]:
    """The streams of the vector tables (all of ``tests/vectors/sharedlink*.json`` by default)."""
    out: list[Stream] = []
    for path in VECTOR_FILES if paths is None else paths:
        with open(path, encoding="utf-8") as fh:
            out += json.load(fh)["streams"]
    names = [s["name"] for s in out]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ValueError(f"vector stream names used twice: {dupes}")
    return out


def stream_ids(streams: list[Stream]) -> list[str]:
    return [s["name"] for s in streams]


def pending(stream: Stream, side: str) -> str | None:
    """The reason ``side`` (one of :data:`SIDES`) does not follow the stream's rules yet."""
    if side not in SIDES:
        raise ValueError(f"unknown side {side!r}")
    marks = stream.get("pending") or {}
    unknown = set(marks) - set(SIDES)
    if unknown:
        raise ValueError(f"{stream['name']}: pending on unknown sides {sorted(unknown)}")
    return marks.get(side)


def stream_params(streams: list[Stream], side: str) -> list[Any]:
    """``pytest.param`` per stream, a strict xfail where ``side`` is pending."""
    out = []
    for s in streams:
        reason = pending(s, side)
        marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
        out.append(pytest.param(s, id=s["name"], marks=marks))
    return out


def payload_bytes(payload: str) -> bytes:
    """The packet's bytes: ``C??`` becomes the frame's right checksum, ``C!!`` a wrong one.

    The checksum covers the frame's bytes from the ':' after its '[' through the 'C'; the
    frame starts at the last "[:" before the mark.
    """
    raw = payload.encode("latin-1")
    out = bytearray()
    pos = 0
    for m in _CHECKSUM_MARK.finditer(raw):
        start = raw.rfind(b"[:", 0, m.start())
        if start < 0:
            raise ValueError(f"checksum mark without a frame start: {payload!r}")
        calc = sum(raw[start + 1 : m.start() + 2]) % 256
        if m.group(1) == b"!!":
            calc = (calc + 0x5A) % 256
        out += raw[pos : m.start() + 2] + b"%02X]" % calc
        pos = m.end()
    out += raw[pos:]
    return bytes(out)


def _endpoint(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host, int(port)


def timestamp_ns(packet: dict[str, Any]) -> int:
    return START_NS + round(float(packet["t"]) * 1e9)


def write_stream(stream: Stream, path: Path) -> Path:
    """Write the stream as a capture: Ethernet/IPv4/UDP or TCP pcap, or a serial pcapng."""
    transport = stream.get("transport", "udp")
    if transport == "serial":
        packets = stream["packets"]
        return write_serial(Path(path), [(payload_bytes(p["payload"]), SERIAL_DIRS[p["dir"]]) for p in packets],
                            times=[timestamp_ns(p) for p in packets])
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        seqs: dict[tuple[str, int, str, int], int] = {}
        for i, p in enumerate(stream["packets"]):
            (sip, sport), (dip, dport) = _endpoint(p["src"]), _endpoint(p["dst"])
            data = payload_bytes(p["payload"])
            if transport == "udp":
                frame = UdpBuilder(sip, dip, sport, dport).frame(data, i + 1)
            elif transport == "tcp":
                # consecutive segments of one direction, acknowledging the other (no handshake)
                key, rkey = (sip, sport, dip, dport), (dip, dport, sip, sport)
                seq, ack = seqs.setdefault(key, 1000), seqs.setdefault(rkey, 5000)
                frame = TcpBuilder(sip, dip, sport, dport).segment(seq, ack, 0x18, data, i + 1)
                seqs[key] = seq + len(data)
            else:
                raise ValueError(f"unknown transport {transport!r}")
            w.write(timestamp_ns(p), frame)
    return Path(path)


def write_streams_apart(streams: list[Stream], path: Path) -> Path:
    """The UDP and TCP streams in one capture, each in addresses of its own (stream k's a.b.c.d
    becomes 10.k.c.d, ports kept: the dissectors keep each conversation's state apart), their
    packets interleaved by time: one tshark run a mode for them all."""
    records: list[tuple[int, int, bytes]] = []
    for k, stream in enumerate(streams, 1):
        transport = stream.get("transport", "udp")
        if transport not in ("udp", "tcp"):
            raise ValueError(f"{stream['name']}: {transport} streams stay in captures of their own")
        seqs: dict[tuple[str, int, str, int], int] = {}
        for i, p in enumerate(stream["packets"]):
            (sip, sport), (dip, dport) = (
                (f"10.{k}.{'.'.join(h.split('.')[2:])}", port) for h, port in (_endpoint(p["src"]), _endpoint(p["dst"])))
            data = payload_bytes(p["payload"])
            if transport == "udp":
                frame = UdpBuilder(sip, dip, sport, dport).frame(data, i + 1)
            else:
                key, rkey = (sip, sport, dip, dport), (dip, dport, sip, sport)
                seq, ack = seqs.setdefault(key, 1000), seqs.setdefault(rkey, 5000)
                frame = TcpBuilder(sip, dip, sport, dport).segment(seq, ack, 0x18, data, i + 1)
                seqs[key] = seq + len(data)
            records.append((timestamp_ns(p), k, frame))
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        for ts, _k, frame in sorted(records, key=lambda r: r[:2]):
            w.write(ts, frame)
    return Path(path)


_json_runs: dict[tuple[str, bool], list[dict[str, Any]]] = {}
_run_dir: Path | None = None


def tshark_json(stream: Stream, two_pass: bool) -> list[dict[str, Any]]:
    """``tshark -T json`` of the stream's capture (every dissector/*.lua loaded, the stream's
    ``variables`` as the preference), checked by tshark_util: one run a stream and pass count a
    process, shared by the tests that read the same run (test_vectors.py's two-pass run is
    test_agreement.py's; both are in the xdist group "vectors"). A copy each time."""
    global _run_dir
    key = (stream["name"], two_pass)
    if key not in _json_runs:
        import tshark_util as tu  # noqa: PLC0415 (its import asks tshark its version)

        if _run_dir is None:
            _run_dir = Path(tempfile.mkdtemp(prefix="sharedlink-vectors-"))
            atexit.register(shutil.rmtree, _run_dir, True)
        ext = "pcapng" if stream.get("transport") == "serial" else "pcap"
        cap = write_stream(stream, _run_dir / f"{stream['name']}.{ext}")
        prefs = {"sharedlink.variables": stream["variables"]} if "variables" in stream else None
        _json_runs[key] = tu.json_packets(cap, prefs=prefs, two_pass=two_pass, extra=OTHERS)
    return copy.deepcopy(_json_runs[key])


def expected_frames(stream: Stream) -> list[tuple[int, int, dict[str, Any]]]:
    """(packet number, frame index within the packet, expected frame) for every frame."""
    return [(n, k, f) for n, p in enumerate(stream["packets"], 1) for k, f in enumerate(p["frames"])]


#: a real vehicle's 28-value list and its OCU's 10 control values (the public shared_link_bridge:
#: its L0 and N0 declarations), as (name, type or None)
REAL_VEHICLE_LIST = [
    ("AutoGpsHead", 2), ("AutoGpsLat", 2), ("AutoGpsLon", 2), ("AutoGpsVel", 2), ("AutoGpsReferences", 0),
    ("AutoGpsQuality", 0), ("AutoGpsStamp", 2), ("pause", 0), ("key_on", 0), ("eng_enb", 0), ("pe7", 0),
    ("bbrake", 0), ("fbrake", 0), ("steerang", 2), ("throttle", 0), ("svp_enb_eng", None), ("serialpck", 0),
    ("veh_gear", 0), ("veh_state", 0), ("veh_estop", 0), ("veh_obstacle", 0), ("vehicle_bat", 2),
    ("run_composite", 4), ("VehicleName", 4), ("Health_total", 0), ("rpm", 0), ("fuel", 0), ("sys_thd", 2),
]
#: REAL_VEHICLE_LIST as a declaration of it types it: svp_enb_eng has no T of its own, so it takes
#: the T0 before it (BUL-009, issue 40: "created with the previously defined type")
REAL_VEHICLE_TYPED = [(n, 0 if n == "svp_enb_eng" else t) for n, t in REAL_VEHICLE_LIST]
REAL_OCU_LIST = [("video_mux1", 0), ("veh_start", 0), ("veh_enable", 0), ("veh_motion", 0), ("joy_steer", 2),
       ("veh_steer", 0), ("veh_brake", 0), ("veh_throttle", 0), ("veh_shift", 0), ("veh_clutch", 0)]
