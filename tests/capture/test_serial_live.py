"""Live serial capture through real pseudo-terminals: `sharedlink serial capture` (one port and
a two-port tap) and the Wireshark extcap writing into a fifo."""

from __future__ import annotations

import json
import os
import re
import select
import signal
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

import pytest
from sl_pipes import (
    environment,
    one_page_pipe,
    read_to_end,
    signal_taken,
    wait_selecting,
    wait_writing,
    wait_written,
)

import tshark_util as tu
from sharedlink.capture.pcapio import CaptureError, read_records
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT
from sharedlink.protocols.codec import encode_positional

REPO = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "sharedlink"]
EXTCAP = [sys.executable, str(REPO / "extcap" / "sharedlink-serial")]
pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs ptys")


def pty_pair() -> tuple[int, str]:
    """(master fd, slave path); the slave is opened by the capture under test."""
    m, s = os.openpty()
    tty.setraw(m)
    path = os.ttyname(s)
    os.close(s)
    return m, path


def wait_ready(proc: subprocess.Popen) -> None:
    line = proc.stderr.readline()
    if "capturing" not in line:
        proc.kill()
        raise AssertionError(f"capture did not start: {line}{proc.stderr.read()}")


def wait_open(pid: int, path: str, timeout: float = 20) -> None:
    """Until process ``pid`` has ``path`` open (the extcap prints nothing) and, its port set up
    (which flushes the input), waits for input."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
            if any(os.readlink(f"/proc/{pid}/fd/{fd}") == path for fd in fds):
                wait_selecting(pid, timeout)
                return
        except OSError:
            pass
        time.sleep(0.02)
    raise AssertionError(f"{path} never opened by {pid}")


def read_all(fd: int, n: int, timeout: float = 10) -> bytes:
    """``n`` bytes from ``fd``, each read when select says it is readable."""
    out = b""
    end = time.monotonic() + timeout
    while len(out) < n and (left := end - time.monotonic()) > 0:
        if select.select([fd], [], [], left)[0]:
            out += os.read(fd, 4096)
    return out


def captured(path: Path) -> int:
    """Bytes in the records written so far (a record being written may be cut short)."""
    n = 0
    try:
        for r in read_records(path):
            n += len(r.data)
    except CaptureError:
        pass
    return n


def wait_captured(path: Path, n: int, timeout: float = 10) -> None:
    """Until the records in ``path`` hold ``n`` bytes (each record is flushed as it is written),
    asked again each time the file is written to."""
    wait_written(path, lambda: captured(path) >= n, timeout)


def frames(n: int, tag: str) -> list[bytes]:
    return [encode_positional("A", "B", [tag, str(i), "%.3f" % (i / 7)]) for i in range(n)]


def test_capture_one_port_records_what_was_written(tmp_path):
    m, path = pty_pair()
    out = tmp_path / "live.pcapng"
    proc = subprocess.Popen([*CLI, "serial", "capture", path, "--baud", "115200", "-o", str(out), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_ready(proc)
        sent = b""
        for i, f in enumerate(frames(20, "x")):
            for part in (f[: i % 9 + 1], f[i % 9 + 1 :]):  # frames split across writes
                os.write(m, part)
                sent += part
            wait_captured(out, len(sent))  # (recorded: the next frame a record of its own)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=20)
    finally:
        os.close(m)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    summary = json.loads(stdout)
    recs = list(read_records(out))
    assert b"".join(r.data for r in recs) == sent
    assert summary["bytes"] == len(sent) and summary["records"] == len(recs) and summary["stopped_by"] == "SIGTERM"
    assert all(r.linktype == 147 and r.flags & 3 == DIR_IN for r in recs)
    assert all(b.ts_ns >= a.ts_ns for a, b in zip(recs, recs[1:]))
    assert abs(recs[0].ts_ns - time.time_ns()) < 120 * 10**9


@pytest.mark.parametrize("unbuffered", ["", "1"])
def test_ctrl_c_while_stdout_is_full_leaves_the_record_whole(tmp_path, unbuffered):
    """Ctrl-C while the capture is blocked writing a record into a pipe that its reader has
    not emptied (a one-page pipe, a record longer than the room left): the record is written
    whole, and the summary counts what the stream holds. Under PYTHONUNBUFFERED=1 standard
    output was the raw file, whose write returned the part that went before the signal and the
    rest was dropped: a truncated block (44 of 4140 bytes) with exit 0 and "1 records"."""
    m, path = pty_pair()
    r, w = one_page_pipe()
    proc = subprocess.Popen([*CLI, "serial", "capture", path, "--baud", "115200", "-o", "-"],
                            stdout=w, stderr=subprocess.PIPE, text=True, env=environment(unbuffered))
    os.close(w)
    sent = bytes(range(256)) * 40
    try:
        wait_ready(proc)
        os.write(m, sent)  # read 4095 bytes at once: a record longer than the pipe's room
        wait_writing(proc.pid)
        proc.send_signal(signal.SIGINT)  # Ctrl-C inside the write
        signal_taken(proc.pid, signal.SIGINT)
    finally:
        try:
            got, stderr = read_to_end(proc, r, 30)
        finally:
            os.close(m)
    assert proc.returncode == 0, stderr
    out = tmp_path / "stdout.pcapng"
    out.write_bytes(got)
    recs = list(read_records(out))  # CaptureError on a truncated block
    summary = re.search(r"wrote -: ([\d,]+) records?, ([\d,]+) bytes? \(stopped: SIGINT\)", stderr)
    assert summary, stderr
    n = sum(len(rec.data) for rec in recs)
    assert (int(summary[1].replace(",", "")), int(summary[2].replace(",", ""))) == (len(recs), n) and recs
    assert b"".join(rec.data for rec in recs) == sent[:n]


def test_tap_relays_both_ways_and_records_both_directions(tmp_path):
    ma, pa = pty_pair()
    mb, pb = pty_pair()
    out = tmp_path / "tap.pcapng"
    proc = subprocess.Popen([*CLI, "serial", "capture", "--tap", pa, pb, "--baud", "9600", "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_ready(proc)
        a_to_b = b"".join(frames(5, "a"))
        b_to_a = b"".join(frames(4, "b"))
        os.write(ma, a_to_b[:50])
        os.write(mb, b_to_a)
        os.write(ma, a_to_b[50:])
        got_b = read_all(mb, len(a_to_b))
        got_a = read_all(ma, len(b_to_a))
        wait_captured(out, len(a_to_b) + len(b_to_a))  # (relayed first, then recorded)
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        _, stderr = proc.communicate(timeout=20)
    finally:
        os.close(ma)
        os.close(mb)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert got_b == a_to_b and got_a == b_to_a  # the relay works both ways
    recs = list(read_records(out))
    assert b"".join(r.data for r in recs if r.flags & 3 == DIR_IN) == a_to_b
    assert b"".join(r.data for r in recs if r.flags & 3 == DIR_OUT) == b_to_a


def test_extcap_answers_wireshark_and_captures_into_a_fifo(tmp_path):
    r = subprocess.run([*EXTCAP, "--extcap-interfaces"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and r.stdout.startswith("extcap {version=")
    assert "interface {value=sharedlink-serial}{display=" in r.stdout
    r = subprocess.run([*EXTCAP, "--extcap-interface", "sharedlink-serial", "--extcap-dlts"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and r.stdout.startswith("dlt {number=147}{name=USER0}")
    r = subprocess.run([*EXTCAP, "--extcap-interface", "sharedlink-serial", "--extcap-config"], capture_output=True, text=True, timeout=30)
    args = [ln for ln in r.stdout.splitlines() if ln.startswith("arg ")]
    assert r.returncode == 0 and [a.split("{call=")[1].split("}")[0] for a in args] == ["--device", "--baud", "--tap", "--linktype"]
    assert "{call=--baud}{display=Baud rate}{type=integer}" in r.stdout and "{default=9600}" in r.stdout
    bad = subprocess.run([*EXTCAP, "--capture", "--extcap-interface", "sharedlink-serial", "--fifo", str(tmp_path / "f"),
                          "--device", str(tmp_path / "no-tty")], capture_output=True, text=True, timeout=30)
    assert bad.returncode == 1 and "no-tty" in bad.stderr and "Traceback" not in bad.stderr

    m, path = pty_pair()
    fifo = tmp_path / "wireshark.fifo"
    os.mkfifo(fifo)
    proc = subprocess.Popen([*EXTCAP, "--capture", "--extcap-interface", "sharedlink-serial", "--fifo", str(fifo),
                             "--device", path, "--baud", "57600", "--linktype", "user0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    received = bytearray()

    grown = threading.Condition()

    def drain() -> None:
        with open(fifo, "rb", buffering=0) as fh:  # as Wireshark does: read until the extcap closes it
            while chunk := fh.read(4096):
                with grown:
                    received.extend(chunk)
                    grown.notify_all()

    def wait_received(n: int, timeout: float = 10) -> None:
        """Until the pcapng read from the fifo so far holds ``n`` bytes of records, asked again
        each time the reader gets more."""
        so_far = tmp_path / "so-far.pcapng"

        def enough() -> bool:
            so_far.write_bytes(bytes(received))
            return captured(so_far) >= n

        with grown:
            assert grown.wait_for(enough, timeout), f"{n} bytes never came through the fifo"

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        wait_open(proc.pid, path)
        sent = b""
        for f in frames(12, "e"):
            os.write(m, f[:11])
            wait_received(len(sent) + 11)  # (recorded: the frame cut across two records)
            os.write(m, f[11:])
            sent += f
        wait_received(len(sent))
        proc.send_signal(signal.SIGTERM)  # how Wireshark stops an extcap
        _, stderr = proc.communicate(timeout=20)
        reader.join(timeout=20)
    finally:
        os.close(m)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    cap = tmp_path / "from-fifo.pcapng"
    cap.write_bytes(bytes(received))
    recs = list(read_records(cap))
    assert b"".join(r.data for r in recs) == sent and all(r.linktype == 147 for r in recs)
    # and Wireshark decodes it: the same frames through the serial dispatcher
    scripts = [a for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua" for a in ("-X", f"lua_script:{s}")]
    rows = tu.fields(cap, ["slserial.frame", "sharedlink.kind"], extra=scripts, two_pass=True)
    got = [bytes.fromhex(h.replace(":", "")) for r in rows for h in r["slserial.frame"]]
    assert got == frames(12, "e")


def test_killed_capture_is_still_readable(tmp_path):
    m, path = pty_pair()
    out = tmp_path / "killed.pcapng"
    proc = subprocess.Popen([*CLI, "serial", "capture", path, "--baud", "9600", "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_ready(proc)
        data = b"".join(frames(6, "k"))
        os.write(m, data)
        wait_captured(out, len(data))
        proc.kill()
        proc.communicate(timeout=20)
    finally:
        os.close(m)
    assert b"".join(r.data for r in read_records(out)) == data


def _install_extcap(conf: Path) -> dict[str, str]:
    """The extcap as `make install` puts it (first line: this Python) in a private config dir."""
    d = conf / "wireshark" / "extcap"
    d.mkdir(parents=True)
    body = (REPO / "extcap" / "sharedlink-serial").read_text().split("\n", 1)[1]
    (d / "sharedlink-serial").write_text(f"#!{sys.executable}\n{body}")
    (d / "sharedlink-serial").chmod(0o755)
    return dict(os.environ, WIRESHARKCONFIGDIR=str(conf / "wireshark"), HOME=str(conf), XDG_CONFIG_HOME=str(conf), LC_ALL="C.UTF-8")


def test_tshark_captures_a_serial_port_through_the_extcap(tmp_path):
    """What a Wireshark user does: pick the interface, set device and baud, capture."""
    env = _install_extcap(tmp_path / "conf")
    listed = subprocess.run([tu.TSHARK, "-D"], env=env, capture_output=True, text=True, timeout=60).stdout
    assert "sharedlink-serial (SharedLink serial" in listed
    m, path = pty_pair()
    out = tmp_path / "ws.pcapng"
    proc = subprocess.Popen([tu.TSHARK, "-i", "sharedlink-serial", "-o", f"extcap.sharedlink_serial.device:{path}",
                             "-o", "extcap.sharedlink_serial.baud:19200", "-w", str(out), "-c", "3"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    f = encode_positional("A", "B", ["42"])
    try:
        end = time.monotonic() + 30
        while proc.poll() is None and time.monotonic() < end:
            os.write(m, f)  # until tshark has its three packets (bytes before the port opened are lost)
            try:
                proc.wait(timeout=0.15)
            except subprocess.TimeoutExpired:
                pass
        _, stderr = proc.communicate(timeout=30)
    finally:
        os.close(m)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    recs = list(read_records(out))
    assert len(recs) == 3 and all(r.linktype == 147 and r.data == f for r in recs)


def test_make_install_puts_the_extcap_where_tshark_finds_it(tmp_path):
    env = dict(os.environ, HOME=str(tmp_path), XDG_CONFIG_HOME=str(tmp_path / ".config"))
    env.pop("WIRESHARKCONFIGDIR", None)
    r = subprocess.run(["make", "-s", "install"], cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "sharedlink-serial extcap into" in r.stdout
    listed = subprocess.run([tu.TSHARK, "-D"], env=env, capture_output=True, text=True, timeout=60).stdout
    assert "sharedlink-serial (SharedLink serial" in listed


def test_capture_ends_cleanly_when_the_line_goes_away(tmp_path):
    m, path = pty_pair()
    out = tmp_path / "hangup.pcapng"
    proc = subprocess.Popen([*CLI, "serial", "capture", path, "--baud", "9600", "-o", str(out), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    f = encode_positional("A", "B", ["1"])
    try:
        wait_ready(proc)
        os.write(m, f)
        wait_captured(out, len(f))
    finally:
        os.close(m)  # the device disappears (a USB adapter pulled out)
    stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 0, stderr
    assert json.loads(stdout)["stopped_by"] in ("end of file", "read error: Input/output error")
    assert b"".join(r.data for r in read_records(out)) == f


#: a USB product string as a crafted device could give it: a line break and braces
CRAFTED = "Evil}{display=spoofed}\ninterface {value=sharedlink-serial-pwned}{display=pwned}\r\x00\x85tail"


def test_extcap_escapes_a_port_description(tmp_path):
    """Wireshark reads the extcap's answer one sentence per line, a field up to `}` before `{`:
    a port's description with a line break added an interface of its own. Listed by the real
    tshark (-D), the port is one interface and its description one display text."""
    conf = tmp_path / "conf"
    env = _install_extcap(conf)
    launcher = conf / "wireshark" / "extcap" / "sharedlink-serial"
    launcher.write_text(  # the installed extcap, with pyserial's listing replaced by a crafted port
        f"#!{sys.executable}\nimport sys\nsys.path.insert(0, {str(REPO / 'pytools')!r})\nimport sharedlink.extcap as e\n"
        f"e.list_ports = lambda: [('/dev/ttyFAKE0', {CRAFTED!r})]\nsys.exit(e.main())\n")
    r = subprocess.run([str(launcher), "--extcap-interfaces"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == 3 and lines[2].startswith("interface {value=sharedlink-serial-ttyFAKE0}{display=")
    assert "{" not in lines[2].split("{display=", 1)[1].rstrip("}")
    listed = subprocess.run([tu.TSHARK, "-D"], env=env, capture_output=True, text=True, timeout=60).stdout
    assert "sharedlink-serial-ttyFAKE0 (SharedLink serial: /dev/ttyFAKE0 (Evil)(display=spoofed)" in listed, listed
    assert "pwned" not in listed.replace("(value=sharedlink-serial-pwned)(display=pwned)", "")
    assert [ln for ln in listed.splitlines() if "sharedlink-serial" in ln and "pwned" in ln.split(" (", 1)[0]] == []
