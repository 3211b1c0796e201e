"""`sharedlink replay` of P2OS and blackboard captures: a TCP capture (P2OS on TCP 8101) replayed as
its client over one real TCP connection on loopback, a serial one through a pty. The bytes expected
are read from the capture by tshark (its TCP analysis marks retransmissions), not by the replay code."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading

import pytest
from sl_cli import run_cli

CLI = [sys.executable, "-m", "sharedlink"]


def _gen(path, *args: str) -> None:
    r = run_cli("gen", "-o", str(path), "-q", *args, timeout=60)
    assert r.returncode == 0, r.stderr


def _client_bytes(path, port: int) -> bytes:
    out = subprocess.run(
        ["tshark", "-r", str(path), "-Y", f"tcp.dstport=={port} && tcp.len>0 && !tcp.analysis.retransmission",
         "-T", "fields", "-e", "tcp.payload"], capture_output=True, text=True, timeout=60, check=True).stdout
    return bytes.fromhex("".join(out.split()))


class _Server:
    """A TCP listener on 127.0.0.1: everything one client sends until it closes."""

    def __init__(self) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.got = b""
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        self.sock.settimeout(30)
        conn, _ = self.sock.accept()
        with conn:
            conn.settimeout(30)
            while data := conn.recv(65536):
                self.got += data

    def close(self) -> bytes:
        self.thread.join(30)
        self.sock.close()
        return self.got


@pytest.mark.parametrize("protocol", ["p2os", "blackboard"])
def test_tcp_capture_replays_its_client_side_over_tcp(tmp_path, protocol):
    cap = tmp_path / f"{protocol}.pcap"
    _gen(cap, "--protocol", protocol, "--transport", "tcp")
    srv = _Server()
    r = run_cli("replay", str(cap), "--to", f"127.0.0.1:{srv.port}", "--topspeed", "--json", timeout=60)
    got = srv.close()
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["destination"] == f"tcp 127.0.0.1:{srv.port}"
    server_port = 8101 if protocol == "p2os" else None
    if server_port is None:  # the generator's blackboard port: the SYN's destination, read by tshark
        out = subprocess.run(["tshark", "-r", str(cap), "-Y", "tcp.flags.syn==1 && tcp.flags.ack==0", "-T", "fields",
                              "-e", "tcp.dstport"], capture_output=True, text=True, timeout=60, check=True).stdout
        server_port = int(out.split()[0])
    want = _client_bytes(cap, server_port)
    assert want and got == want
    assert summary["bytes"] == len(want) and summary["send_errors"] == 0


def test_tcp_replay_with_nothing_listening(tmp_path):
    cap = tmp_path / "p.pcap"
    _gen(cap, "--protocol", "p2os")
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    r = run_cli("replay", str(cap), "--to", f"127.0.0.1:{port}", timeout=60)
    assert r.returncode == 2 and "cannot connect over TCP" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("protocol", ["p2os", "blackboard"])
def test_serial_capture_replays_through_a_pty(tmp_path, protocol):
    from sharedlink.capture.pcapio import read_records

    cap = tmp_path / f"{protocol}.pcapng"
    _gen(cap, "--protocol", protocol, "--transport", "serial")
    recs = list(read_records(cap))
    out = b"".join(r.data for r in recs if r.flags & 3 == 2)
    both = {r.flags & 3 for r in recs}
    master, slave = os.openpty()
    try:
        import termios
        import tty

        tty.setraw(slave)
        name = os.ttyname(slave)
        args = [*CLI, "replay", str(cap), "--serial", name, "--baud", "115200", "--topspeed", "--json"]
        if both == {1, 2}:
            r = subprocess.run(args, capture_output=True, text=True, timeout=60)
            assert r.returncode == 2 and "--direction" in r.stderr
            args += ["--direction", "out"]
        else:
            out = b"".join(r.data for r in recs)
        got: list[bytes] = []
        t = threading.Thread(target=lambda: got.append(_read(master, len(out))), daemon=True)
        t.start()
        r = subprocess.run(args, capture_output=True, text=True, timeout=60)
        t.join(30)
        assert r.returncode == 0, r.stderr
        assert out and got[0] == out
        assert json.loads(r.stdout)["bytes"] == len(out)
        termios.tcflush(master, termios.TCIOFLUSH)
    finally:
        os.close(master)
        os.close(slave)


def _read(fd: int, n: int) -> bytes:
    import select

    buf = b""
    while len(buf) < n:
        r, _, _ = select.select([fd], [], [], 10)
        if not r:
            break
        buf += os.read(fd, 65536)
    return buf
