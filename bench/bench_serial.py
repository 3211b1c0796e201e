"""serial: the incremental serial reader and the serial dispatcher in tshark, side by side with
their floors.

* reader: ``serialcap.read_capture`` (records of a UART-chunked session -> frames, per
  direction, holding split frames) against ``codec.iter_segments`` on each direction's whole
  stream at once (what the reader would cost with no chunking to handle); both include reading
  the pcapng records. Target: at least a third of the floor's speed.
* dissector: tshark CPU time on the serial capture (dissector/serial.lua reassembling and
  handing off to sharedlink.lua) against the same frames one per UDP datagram (sharedlink.lua
  alone). The serial capture has about 2.6 records per frame (UART chunks), each a packet for
  tshark, so the target is at most 3x.
"""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from bench import Result
from sharedlink.capture.packets import UdpBuilder
from sharedlink.capture.pcapio import PcapWriter, read_records
from sharedlink.capture.serial_format import read_capture
from sharedlink.generators.serial import SerialGenOptions, generate_serial_file, session_frames
from sharedlink.protocols.codec import iter_segments

REPO = Path(__file__).resolve().parents[1]
TSHARK = shutil.which("tshark") or "/usr/bin/tshark"
OPTS = SerialGenOptions(duration=300, rate=10, baud=115200, noise=0.02)


def reader_time(path: Path) -> tuple[float, int]:
    t = time.perf_counter()
    n = sum(1 for _r, _d, p in read_capture(path) if p.is_frame)
    return time.perf_counter() - t, n


def floor_time(path: Path) -> tuple[float, int]:
    t = time.perf_counter()
    streams: dict[int, list[bytes]] = {}
    for r in read_records(path):
        streams.setdefault(r.flags & 3, []).append(r.data)
    n = sum(1 for v in streams.values() for s in iter_segments(b"".join(v)) if s.is_frame)
    return time.perf_counter() - t, n


def tshark_cpu(capture: Path, scripts: list[Path], conf: str) -> float:
    env = dict(os.environ, WIRESHARKCONFIGDIR=conf, HOME=conf, XDG_CONFIG_HOME=conf)
    args = [TSHARK, "-n", "-r", str(capture)] + [a for s in scripts for a in ("-X", f"lua_script:{s}")]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run(work: Path) -> list[Result]:
    serial = work / "serial.pcapng"
    generate_serial_file(OPTS, serial)
    records = sum(1 for _ in read_records(serial))
    best_reader = best_floor = float("inf")
    for _ in range(3):  # interleaved, best of three
        t, n1 = reader_time(serial)
        best_reader = min(best_reader, t)
        t, n2 = floor_time(serial)
        best_floor = min(best_floor, t)
    assert n1 == n2, (n1, n2)
    out = [
        Result(
            "serial reader records/s vs whole-stream split",
            f"{records / best_reader:,.0f} rec/s",
            f"{records / best_floor:,.0f} rec/s",
            best_floor / best_reader,
            ">= 0.33x",
            best_floor / best_reader >= 0.33,
        )
    ]
    if not Path(TSHARK).exists():
        return out
    udp = work / "udp.pcap"
    builder = UdpBuilder("192.168.1.12", "192.168.1.11", 7013, 7013)
    with open(udp, "wb") as fh:
        w = PcapWriter(fh)
        for i, lf in enumerate(session_frames(OPTS)):
            w.write(lf.ts_ns, builder.headers(len(lf.data), lf.data, i & 0xFFFF) + lf.data)
    scripts = [REPO / "dissector" / "serial.lua", REPO / "dissector" / "sharedlink.lua"]
    conf = tempfile.mkdtemp(prefix="sharedlink-bench-conf-")
    try:
        best_serial = best_udp = float("inf")
        for _ in range(2):
            best_serial = min(best_serial, tshark_cpu(serial, scripts, conf))
            best_udp = min(best_udp, tshark_cpu(udp, [REPO / "dissector" / "sharedlink.lua"], conf))
    finally:
        shutil.rmtree(conf, ignore_errors=True)
    ratio = best_serial / best_udp
    out.append(
        Result(
            f"tshark CPU: serial ({records} records) vs UDP",
            f"{best_serial:.2f} s",
            f"{best_udp:.2f} s",
            ratio,
            "<= 3x",
            ratio <= 3.0,
        )
    )
    return out
