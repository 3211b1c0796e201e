"""Issue 42: `sharedlink watch --port N --interface lo` (sniffing, as dumpcap) of a live blackboard
link over UDP shows every message and answer of both sides, two identical consecutive datagrams
as two rows (a master repeating a set message whose acknowledgement was lost: records 15 and 16
of BlackboardGenOptions(duration=3, seed=8), reported as one row by the last session). The
session's datagrams are sent over real UDP on loopback from a master socket to a slave socket and
back, as the post office and its client would; the rows are export's. Needs root or CAP_NET_RAW."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys

import pytest
from sl_cli import run_cli
from sl_pipes import read_lines

from sharedlink.capture.pcapio import read_records
from sharedlink.generators.blackboard import BlackboardGenOptions, generate_blackboard_file
from sharedlink.replay import udp_fields

CLI = [sys.executable, "-m", "sharedlink"]


def _can_sniff() -> bool:
    try:
        socket.socket(socket.AF_PACKET, socket.SOCK_DGRAM, 0).close()
    except (OSError, AttributeError):
        return False
    return True


@pytest.mark.skipif(not _can_sniff(), reason="sniffing needs root or CAP_NET_RAW")
def test_sniffed_blackboard_keeps_identical_consecutive_datagrams(tmp_path):
    cap = tmp_path / "b.pcap"
    generate_blackboard_file(BlackboardGenOptions(duration=3, seed=8), cap)
    records = [udp_fields(r.linktype, r.data) for r in read_records(cap)]
    assert records[14] == records[15] and records[14][2] == 7100  # the repeat: the same set message twice
    want = [json.loads(x) for x in run_cli("export", "--format", "jsonl", "-o", "-", str(cap), check=True, timeout=120).stdout.splitlines()]
    master = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    slave = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        master.bind(("127.0.0.1", 0))
        slave.bind(("127.0.0.1", 0))
        mport, sport = master.getsockname()[1], slave.getsockname()[1]
        w = subprocess.Popen([*CLI, "watch", "--port", str(sport), "--interface", "lo", "--json"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            while "udp port" not in (line := w.stderr.readline()):  # type: ignore[union-attr]
                assert line, f"watch ended early: rc={w.poll()}"
            for _src, src_port, _dst, payload in records:
                if src_port == 40100:
                    master.sendto(payload, ("127.0.0.1", sport))
                else:
                    slave.sendto(payload, ("127.0.0.1", mport))
            lines = read_lines(w.stdout.fileno(), len(want)).decode().splitlines()  # type: ignore[union-attr]
        finally:
            w.send_signal(signal.SIGINT)
            w.communicate(timeout=60)
    finally:
        master.close()
        slave.close()
    rows = [json.loads(x) for x in lines]
    key = [(r["side"], r["type"], r.get("address"), r.get("data")) for r in rows]
    assert key == [(r["side"], r["type"], r.get("address"), r.get("data")) for r in want]
    repeats = [r for r in rows if r["side"] == "master" and r["type"] == "set"]
    assert any(a.get("data") == b.get("data") and a["number"] + 1 == b["number"] for a, b in zip(repeats, repeats[1:]))


def test_backlog_keeps_both_directions_in_arrival_order():
    """The cause: the backlog served each direction as a conversation of its own, in turn, so a
    slave's answer could come out after the master's next message. Both directions now share a
    queue while both wait; another conversation is still served in turn."""
    from sharedlink.watch import Backlog, RawDatagram

    ab, ba = ("udp", "127.0.0.1", 40100, "127.0.0.1", 7100), ("udp", "127.0.0.1", 7100, "127.0.0.1", 40100)
    other = ("udp", "127.0.0.1", 5, "127.0.0.1", 7100)
    b = Backlog()
    for n, conv in enumerate([ab, ab, ab, ba, other], 1):
        b.put(RawDatagram(n, n, conv, b"x"))
    first = [d.number for d in b.take(3, now_ns=100)]  # (served apart: 1, 4 and 5, the answer before 2 and 3)
    assert first == [1, 2, 5]  # one from each conversation in turn; the answer after what came before it
    assert [d.number for d in b.take(100, now_ns=100)] == [3, 4]
