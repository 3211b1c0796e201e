"""`sharedlink replay --side` of a TCP capture (issue 42): `server` plays the robot (a recorded
Pioneer session's SIPs to a client that connects, as MobileSim would), `both` the whole
conversation over loopback (both sides' bytes, for a sniffer to see again), `client` as before. The
bytes expected are read from the capture by tshark (its TCP analysis marks retransmissions), not
by the replay code; everything goes over real TCP sockets on loopback."""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys

import pytest
from sl_cli import run_cli

CLI = [sys.executable, "-m", "sharedlink"]


def _gen(path, *args: str) -> None:
    r = run_cli("gen", "-o", str(path), "-q", *args, timeout=60)
    assert r.returncode == 0, r.stderr


def _bytes(path, side: str, port: int = 8101) -> bytes:
    field = "tcp.dstport" if side == "client" else "tcp.srcport"
    out = subprocess.run(
        ["tshark", "-r", str(path), "-Y", f"{field}=={port} && tcp.len>0 && !tcp.analysis.retransmission",
         "-T", "fields", "-e", "tcp.payload"], capture_output=True, text=True, timeout=60, check=True).stdout
    return bytes.fromhex("".join(out.split()))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    p = tmp_path_factory.mktemp("sides") / "p2os.pcap"
    _gen(p, "--protocol", "p2os", "--duration", "5")
    return p


def test_side_server_plays_the_robot_to_a_client(session):
    """The replay listens, says where on stderr; a client connects, sends its commands (read and
    dropped) and gets the robot's bytes, every one, then the end of the stream."""
    r = subprocess.Popen([*CLI, "replay", str(session), "--side", "server", "--bind", "127.0.0.1:0", "--topspeed",
                          "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = r.stderr.readline()  # type: ignore[union-attr]
        m = re.search(r"tcp 127\.0\.0\.1:(\d+)", line)
        assert m, line
        got = b""
        with socket.create_connection(("127.0.0.1", int(m.group(1))), timeout=30) as c:
            c.sendall(_bytes(session, "client"))  # what ARIA would send: SYNC0, ..., OPEN, commands
            while data := c.recv(65536):
                got += data
        out, err = r.communicate(timeout=60)
    finally:
        if r.poll() is None:
            r.kill()
    assert r.returncode == 0, err
    want = _bytes(session, "server")
    assert want[:2] == b"\xfa\xfb" and got == want
    summary = json.loads(out)
    assert summary["bytes"] == len(want) and summary["destination"].startswith(f"tcp server 127.0.0.1:{m.group(1)} ")


def test_side_both_replays_the_conversation(session):
    port = _free_port()
    r = run_cli("replay", str(session), "--side", "both", "--to", f"127.0.0.1:{port}", "--topspeed", "--json", timeout=60)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["destination"] == f"tcp both sides over 127.0.0.1:{port}"
    assert summary["bytes"] == len(_bytes(session, "client")) + len(_bytes(session, "server"))
    assert summary["send_errors"] == 0


def test_side_is_for_tcp_captures(tmp_path):
    cap = tmp_path / "b.pcap"
    _gen(cap, "--duration", "1")
    r = run_cli("replay", str(cap), "--side", "server", timeout=60)
    assert r.returncode == 2 and "not a TCP capture" in r.stderr and "Traceback" not in r.stderr
    r = run_cli("replay", str(tmp_path / "x.pcap"), "--side", "both", timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr
