"""`sharedlink watch -`: a capture through a real pipe gives what the same file given by name
gives (SharedLink frames, P2OS and blackboard messages; --json, the view, --foxglove), the
capture read once as it arrives (a live pipe from tcpdump never ends: nothing may wait for its end)."""

from __future__ import annotations

import json
import select
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from sl_cli import run_cli

CLI = [sys.executable, "-m", "sharedlink"]
ROOT = Path(__file__).resolve().parents[1]
REAL = [  # real or hand-made captures of the three protocols (serial, TCP, UDP)
    ROOT / "dissector/golden/inputs/vector-real-vehicle-frames-with-no-list.pcap",
    ROOT / "dissector/golden_small/p2os-serial.pcapng",
    ROOT / "dissector/golden_small/bb-tcp.pcap",
    ROOT / "dissector/golden_small/mut1-p2os-tcp.pcap",
]


def by_name(path: Path, *args: str) -> subprocess.CompletedProcess:
    return run_cli("watch", str(path), "--speed", "1e6", "-q", *args, timeout=120)


def piped(path: Path, *args: str) -> subprocess.CompletedProcess:
    """The capture written into the command's standard input, a pipe (not a file it could seek)."""
    return run_cli("watch", "-", "--speed", "1e6", "-q", *args, text=False, timeout=120, input=path.read_bytes())


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("gen")
    out = {}
    for proto in ("sharedlink", "p2os", "blackboard"):
        out[proto] = d / f"{proto}.pcap"
        run_cli("gen", "-o", str(out[proto]), "-q", "--protocol", proto, "--duration", "20", text=False, check=True, timeout=120)
    return out


@pytest.mark.parametrize("proto", ["sharedlink", "p2os", "blackboard"])
def test_json_through_a_pipe_is_the_by_name_run(generated, proto):
    want = by_name(generated[proto], "--json", "--outages")
    assert want.returncode == 0, want.stderr
    got = piped(generated[proto], "--json", "--outages")
    assert got.returncode == 0, got.stderr
    lines = want.stdout.splitlines()
    assert got.stdout.decode().splitlines() == lines
    kinds = {json.loads(line).get("protocol", "sharedlink") for line in lines}
    assert proto in kinds  # (the robot captures: their packets, not only the link lines)


@pytest.mark.parametrize("path", REAL, ids=[p.name for p in REAL])
def test_real_captures_through_a_pipe(path):
    want = by_name(path, "--json")
    assert want.returncode == 0, want.stderr
    assert want.stdout
    got = piped(path, "--json")
    assert (got.returncode, got.stdout.decode()) == (0, want.stdout)


def test_damaged_capture_through_a_pipe(generated, tmp_path):
    cut = tmp_path / "cut.pcap"
    data = generated["p2os"].read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3 + 5])  # (mid-record)
    want = by_name(cut, "--json")
    got = piped(cut, "--json")
    assert want.returncode == got.returncode == 2
    assert want.stdout and got.stdout.decode() == want.stdout
    assert "Traceback" not in got.stderr.decode()


def test_view_through_a_pipe_shows_the_robot_session(generated):
    """The view (no --json) of a piped P2OS capture has the session panel the file has."""
    want = by_name(generated["p2os"]).stdout.splitlines()
    got = piped(generated["p2os"]).stdout.decode().splitlines()

    def panel(lines: list[str]) -> list[str]:  # from the session's line on (the header names the
        return lines[next(i for i, x in enumerate(lines) if x.startswith("p2os session")):]  # path: wraps)

    assert len(panel(got)) == len(panel(want))

    def sip(lines: list[str]) -> str:  # the last SIP's values (its age depends on the clock)
        line = next(x for x in lines if x.strip().startswith("SIP ("))
        return line.split("ago):", 1)[1]

    assert "mm" in sip(want) and sip(got) == sip(want)


def test_a_live_pipe_is_read_as_it_arrives(generated, tmp_path):
    """Lines come out before standard input ends (it is not read whole first); the rest then
    follows, all of it the by-name run's."""
    data = generated["p2os"].read_bytes()
    want = by_name(generated["p2os"], "--json").stdout.splitlines()
    errors = (tmp_path / "err").open("w+b")
    p = subprocess.Popen([*CLI, "watch", "-", "--json", "--speed", "1e6", "-q"], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, stderr=errors)
    try:
        p.stdin.write(data[: len(data) // 2])  # type: ignore[union-attr]
        p.stdin.flush()  # type: ignore[union-attr]
        ready, _, _ = select.select([p.stdout], [], [], 60)  # (a guard: the line comes at once)
        assert ready, "no line while the pipe is open"
        first = p.stdout.readline().decode().rstrip("\n")  # type: ignore[union-attr]

        def rest() -> None:  # (a thread: the watch writes while it reads)
            p.stdin.write(data[len(data) // 2:])  # type: ignore[union-attr]
            p.stdin.close()  # type: ignore[union-attr]

        writer = threading.Thread(target=rest)
        writer.start()
        out = p.stdout.read()  # type: ignore[union-attr]  (the buffered reader: after its line)
        writer.join()
        p.wait(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    errors.seek(0)
    assert p.returncode == 0, errors.read()
    assert [first, *out.decode().splitlines()] == want


def _write(p: subprocess.Popen, data: bytes) -> None:
    p.stdin.write(data)  # type: ignore[union-attr]
    p.stdin.close()  # type: ignore[union-attr]


@pytest.mark.live
def test_foxglove_through_a_pipe(tmp_path):
    """`watch - --foxglove`: the P2OS poses reach a client, the last SIP of the capture included."""
    if sys.version_info < (3, 10):
        pytest.skip("foxglove-schemas-protobuf needs Python 3.10+")
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from sl_foxglove import advertised, subscribed, wait_for_channel
    from websockets.sync.client import connect

    cap = tmp_path / "p.pcap"
    run_cli("gen", "-o", str(cap), "-q", "--protocol", "p2os", "--duration", "4", text=False, check=True, timeout=120)
    rows = [json.loads(x) for x in by_name(cap, "--json").stdout.splitlines()]
    sips = {r["ts_ns"]: r for r in rows if "x_mm" in r and r["checksum"] == "good"}
    data = cap.read_bytes()
    p = subprocess.Popen([*CLI, "watch", "-", "--json", "--foxglove", "--foxglove-port", "0"], stdin=subprocess.PIPE,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=False)
    try:
        p.stdin.write(data[: len(data) // 2])  # type: ignore[union-attr]
        p.stdin.flush()  # type: ignore[union-attr]
        while True:
            line = p.stderr.readline().decode()  # type: ignore[union-attr]
            assert line, f"watch ended early: rc={p.poll()}"
            if "Foxglove WebSocket server on ws://" in line:
                port = int(line.strip().rsplit(":", 1)[1])
                break
        wait_for_channel(port, "/p2os/1/pose")
        with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.websocket.v1"]) as ws:
            pose = advertised(ws, {"/p2os/1/pose"})["/p2os/1/pose"]
            writer = threading.Thread(target=_write, args=(p, data[len(data) // 2:]))
            writer.start()  # the second half, played at its pace (2 s) while the client subscribes
            try:
                got = subscribed(ws, pose)
            finally:
                writer.join()
        err = p.stderr.read()  # type: ignore[union-attr]  (the capture ended: the watch ends)
        p.wait(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, err
    assert b"Traceback" not in err
    poses = [(t, PoseInFrame.FromString(m)) for t, m in got]
    assert len(poses) > 5
    for t, m in poses:
        assert m.pose.position.x == pytest.approx(sips[t]["x_mm"] / 1000)
    assert poses[-1][0] == max(sips)  # (the second half, written once the client was there, came through)
