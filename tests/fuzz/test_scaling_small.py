"""Issue 31: p2os.lua, blackboard.lua and serial.lua take linear time and memory on the patterns
that were quadratic (tests/fuzz/scaling_small.py writes them): time and peak memory from N to 4N
grow at most 5x beyond tshark's start-up. ``make fuzz`` runs them at bigger sizes."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import scaling_small as ss
from scaling import check_scaling

import tshark_util as tu


@pytest.mark.long
@pytest.mark.parametrize("name", sorted(ss.PATTERNS))
def test_linear(name: str, tmp_path: Path):
    make, n, _big, limit = ss.PATTERNS[name]
    report = check_scaling(make, n, tmp_path, limit=limit, env=ss.env())
    print(name, report)


# --- the limits themselves: an expert info "Limit exceeded: ..." where input is dropped ----------


def _fields(cmd: list[str], *names: str) -> list[dict[str, list[str]]]:
    p = subprocess.run([*cmd, "-T", "fields", "-E", "occurrence=a", "-E", "aggregator=|",
                        *[a for n in ("_ws.lua.error", *names) for a in ("-e", n)]],
                       capture_output=True, text=True, env=ss.env(), timeout=120)
    assert p.returncode == 0, p.stderr
    tu.check_stderr(p.stderr)
    rows = []
    for line in p.stdout.splitlines():
        cols = line.split("\t")
        assert not cols[0], f"Lua error: {cols[0]}"
        rows.append({n: (c.split("|") if c else []) for n, c in zip(names, cols[1:])})
    return rows


def _limited(rows: list[dict[str, list[str]]]) -> list[int]:
    return [i + 1 for i, r in enumerate(rows) if any(m.startswith("Limit exceeded:") for m in r["_ws.expert.message"])]


@pytest.mark.parametrize("two_pass", [False, True])
def test_blackboard_max_pending(tmp_path: Path, two_pass: bool):
    cap = tmp_path / "endpoints.pcap"
    ss.write_bb_endpoints(cap, 6)
    cmd = ss.tshark_command(cap, "-o", "blackboard.udp_port:7100", "-o", "blackboard.max_pending:4",
                            *(["-2"] if two_pass else []))
    rows = _fields(cmd, "blackboard.type", "_ws.expert.message")
    assert [r["blackboard.type"] for r in rows] == [["set"]] * 6
    assert _limited(rows) == [5, 6]


def test_blackboard_tcp_max_held_bytes(tmp_path: Path):
    cap = tmp_path / "no-cr.pcap"
    ss.write_bb_tcp_no_cr(cap, 4000, segment=500)
    rows = _fields(ss.tshark_command(cap, "-o", "blackboard.tcp_port:7100", "-o", "blackboard.max_held_bytes:1000"),
                   "blackboard.type", "blackboard.junk", "_ws.expert.message")
    limited = _limited(rows)
    assert len(limited) == 1, limited
    # the message is shown unended where it passed the limit; the bytes after it are outside any message
    assert rows[limited[0] - 1]["blackboard.type"] == ["set"]
    assert any(r["blackboard.junk"] for r in rows[limited[0]:])


@pytest.mark.parametrize("protocol", ["sharedlink", "blackboard"])
def test_serial_max_held_bytes(tmp_path: Path, protocol: str):
    make = ss.make_serial_unterminated(protocol, "-o", "slserial.max_held_bytes:50")
    rows = _fields(make(120, tmp_path), "slserial.noise", "slserial.held", "_ws.expert.message")
    limited = _limited(rows)
    # 1 + 5 or 1 + 1 bytes at the start, one a record: the 51st held byte gives the frame up
    start = 5 if protocol == "sharedlink" else 1
    assert limited == [51 - start + 1], limited
    assert rows[limited[0] - 1]["slserial.noise"]
    assert all(r["slserial.held"] for r in rows[: limited[0] - 1])
