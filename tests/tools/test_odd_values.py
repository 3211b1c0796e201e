"""Odd but valid input, handled: captures from a pipe (read once), time stamps past year 9999,
file names that are not UTF-8, serial logs with a bad line or absurd times (the lines before it
are written), replay to a serial port nobody reads (stops at the first timeout), and an
interrupted top-speed replay (counts the frames really sent)."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import tty
from pathlib import Path

import pytest
from sl_cli import run_cli

from sharedlink.capture.pcapio import _block, _opt, read_records
from sharedlink.generators.beacon import GenOptions, generate_file
from sharedlink.replay import CaptureFrames, Replayer, ReplayOptions
from tshark_util import fields

CLI = [sys.executable, "-m", "sharedlink"]


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("odd") / "in.pcapng"
    generate_file(GenOptions(frames=40, fmt="pcapng"), p)
    return p


def sh(command: str) -> subprocess.CompletedProcess:
    """A bash command line (for process substitution), the CLI as ``sl``."""
    sl = " ".join(CLI)
    return subprocess.run(["bash", "-c", f"sl() {{ {sl} \"$@\"; }}; {command}"], capture_output=True, text=True, timeout=120)


# -- pipes -----------------------------------------------------------------------------------


@pytest.mark.parametrize("command, check", [
    ("sl export <(cat {c})", lambda out, tmp: out.count("\n") == 41),
    ("sl stats --json <(cat {c})", lambda out, tmp: json.loads(out)["frames"] == 40),
    ("sl diff --json <(cat {c}) <(cat {c})", lambda out, tmp: json.loads(out)["pairs"] == 40),
    ("sl compress <(cat {c}) {t}/c.pcapng", lambda out, tmp: len(list(read_records(tmp / "c.pcapng"))) == 40),
    ("sl replay --topspeed --to 127.0.0.1:9 --json <(cat {c})", lambda out, tmp: json.loads(out)["frames"] == 40),
])
def test_a_pipe_is_read_once(capture, tmp_path, command, check):
    r = sh(command.format(c=capture, t=tmp_path))
    assert r.returncode == 0, r.stderr
    assert check(r.stdout, tmp_path), r.stdout[:500]


# -- time stamps and names ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def year_11476(capture, tmp_path_factory) -> Path:
    """A pcapng in microseconds (it holds any year) stamped in the year 11476."""
    out = _block(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1))
    out += _block(1, struct.pack("<HHI", 1, 0, 65535) + _opt(9, b"\x06") + _opt(0, b""))
    for i, r in enumerate(list(read_records(capture))[:5]):
        ts = (300_000_000_000 + i) * 1_000_000
        pad = (-len(r.data)) & 3
        out += _block(6, struct.pack("<IIIII", 0, ts >> 32, ts & 0xFFFFFFFF, len(r.data), len(r.data)) + r.data + b"\0" * pad)
    p = tmp_path_factory.mktemp("y") / "y11476.pcapng"
    p.write_bytes(out)
    return p


def test_time_stamps_past_year_9999(year_11476, tmp_path):
    assert len(fields(year_11476, ["frame.number"])) == 5  # tshark reads it
    r = run_cli("export", "--format", "jsonl", str(year_11476), timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[0])["time"] == "+11476-08-15T05:20:00.000000000Z"
    r = run_cli("export", str(year_11476), "-o", str(tmp_path / "t.kml"), timeout=120)
    assert r.returncode == 0 and "+11476-08-15T05:20:00" in (tmp_path / "t.kml").read_text(), r.stderr
    r = run_cli("compress", str(year_11476), "-o", str(tmp_path / "c.pcapng"), timeout=120)
    assert r.returncode == 2 and "record 1" in r.stderr and "2554" in r.stderr and "Traceback" not in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.kml"]


@pytest.mark.parametrize("command", ["kml", "plot"])
def test_capture_names_that_are_not_utf8(capture, tmp_path, command):
    name = os.fsdecode(b"drive-\xff\xfe.pcapng")
    odd = tmp_path / name
    odd.write_bytes(capture.read_bytes())
    out = tmp_path / ("t.kml" if command == "kml" else "t.png")
    args = ["export", str(odd), "-o", str(out)] if command == "kml" else ["plot", str(odd), "-o", str(out)]
    r = run_cli(*args, text=False, timeout=120)
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 0
    if command == "kml":
        assert "drive-\ufffd\ufffd.pcapng" in out.read_text(encoding="utf-8")


# -- serial logs ------------------------------------------------------------------------------


@pytest.mark.parametrize("bad", ["garbage, not a log line", "100000000000000000000.0 > [:AB|N0|C00]"])
def test_serial_import_writes_the_lines_before_a_bad_one(tmp_path, bad):
    lines = ["1767268800.%03d > [:AB|N0|C00]" % i for i in range(21)]
    lines[10] = bad
    log = tmp_path / "l.log"
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "l.pcapng"
    r = run_cli("serial", "import", str(log), "-o", str(out), timeout=120)
    assert r.returncode == 2 and "line 11" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(fields(out, ["frame.number"])) == 10


# -- replay -----------------------------------------------------------------------------------


@pytest.mark.live
def test_replay_to_a_serial_port_nobody_reads_stops_at_the_first_timeout(tmp_path):
    cap = tmp_path / "big.pcap"
    generate_file(GenOptions(frames=2000), cap)
    master, slave = os.openpty()  # nobody reads the master: the pty fills up
    tty.setraw(slave)
    # (the subprocess timeout is the hang guard: a timeout per frame would take 2000 x 5 s; the
    # report says it stopped at the first one)
    r = run_cli("replay", "--serial", os.ttyname(slave), "--topspeed", "--json", str(cap), timeout=120)
    os.close(master)
    os.close(slave)
    assert r.returncode == 1, r.stderr
    out = json.loads(r.stdout)
    assert out["send_errors"] == 1 and "timed out" in out["first_error"]
    assert 0 < out["frames"] < 2000


class _InterruptAfter:
    """A sink that takes ``n`` payloads, then is interrupted (Ctrl-C) during the next one."""

    description = "interrupt"

    def __init__(self, n: int) -> None:
        self.n, self.sent = n, 0

    def target(self, frame):
        return True

    def send(self, payload: bytes, target) -> None:
        if self.sent == self.n:
            raise KeyboardInterrupt
        self.sent += 1

    def close(self) -> None:
        pass


@pytest.mark.parametrize("n", [0, 1, 137, 999])
def test_interrupted_topspeed_replay_counts_the_frames_really_sent(tmp_path, n):
    cap = tmp_path / "c.pcap"
    generate_file(GenOptions(frames=1000), cap)
    sink = _InterruptAfter(n)
    st = Replayer(CaptureFrames(cap), sink, ReplayOptions(topspeed=True)).run()
    assert st.interrupted
    assert st.frames == st.attempted == sink.sent == n


# -- frames near 64 KB ------------------------------------------------------------------------------


def test_expand_past_one_datagram_is_one_line_and_leaves_the_old_file(tmp_path):
    """A 64 KB frame, then new names: expanding the second frame would take more than one UDP
    datagram holds (IPv4 total length 65,535). One line naming the record, exit 2, the old
    output as it was (before: struct.error traceback). The 64 KB frame alone round-trips."""
    from sharedlink.capture.packets import UdpBuilder
    from sharedlink.capture.pcapio import PcapWriter
    from sharedlink.protocols.codec import encode_named

    b = UdpBuilder("10.0.0.2", "10.0.0.1", 7013, 7013)
    big = encode_named("A", "B", [(f"V{k:05d}", 2, f"{k}.5") for k in range(3480)])
    assert 65_000 < len(big) <= 65_507
    cap = tmp_path / "big.pcap"
    with open(cap, "wb") as fh:
        w = PcapWriter(fh)
        w.write(1_767_268_800_000_000_000, b.frame(big, 1))
        w.write(1_767_268_800_100_000_000, b.frame(big, 2))
        w.write(1_767_268_800_200_000_000, b.frame(encode_named("A", "B", [(f"W{k:03d}", 2, "1.5") for k in range(200)]), 3))
    out = tmp_path / "out.pcap"
    out.write_bytes(b"the previous version")
    for command in ("expand", "compress"):
        r = run_cli(command, str(cap), "-o", str(out), timeout=120)
        if command == "compress":  # leaves out what the receiver has: it fits
            assert r.returncode == 0, r.stderr
            continue
        assert r.returncode == 2, r.stderr
        assert r.stderr.count("\n") == 1 and "record 3" in r.stderr and "65,507" in r.stderr and "Traceback" not in r.stderr
        assert out.read_bytes() == b"the previous version"
