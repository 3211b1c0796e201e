"""tests/vectors/robot-streams.json, record by record, in tshark (p2os.lua, blackboard.lua,
serial.lua; two passes), the Python session reader and the decoding core's robot links: a serial
line carrying P2OS one way and blackboard the other (docs/serial-capture-format.md, "Protocol
per direction"), and blackboard text a TCP stream still holds at the capture's end, a malformed
message (no CR) of the last segment that brought its bytes (docs/fields-p2os-blackboard.md,
"Malformed messages"; before, neither decoder showed it)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from sl_robot_frames import core_frames, lua_frames, python_frames
from sl_robots import write_serial, write_tcp

from sharedlink.capture.packets import decode_packet
from sharedlink.capture.pcapio import read_records
from sharedlink.capture.serial_format import DIR_IN, DIR_OUT

REPO = Path(__file__).resolve().parents[2]
TABLE = json.loads((REPO / "tests" / "vectors" / "robot-streams.json").read_text())
VECTORS = TABLE["vectors"]
SERIAL_DIRS = {"out": DIR_OUT, "in": DIR_IN}


def _capture(v: dict, tmp_path: Path) -> tuple[Path, list[int]]:
    """The vector's capture and the frame number of each of its records."""
    recs = v["records"]
    if v["transport"] == "serial":
        path = write_serial(tmp_path / "v.pcapng", [(bytes.fromhex(r["hex"]), SERIAL_DIRS[r["dir"]]) for r in recs])
        return path, list(range(1, len(recs) + 1))
    path = tmp_path / "v.pcap"
    write_tcp(path, [(r["from"] == "client", bytes.fromhex(r["hex"])) for r in recs], v["port"])
    numbers = [rec.number for rec in read_records(path) if decode_packet(rec.linktype, rec.data).payload]  # type: ignore[union-attr]
    assert len(numbers) == len(recs)
    return path, numbers


def test_the_table_covers_both_rules() -> None:
    kinds = {m[1] for v in VECTORS for r in v["records"] for m in r["messages"]}
    assert {v["transport"] for v in VECTORS} == {"serial", "tcp"}
    assert "request malformed" in kinds and {"client", "robot", "set", "ack", "response"} <= kinds


@pytest.mark.parametrize("v", VECTORS, ids=[v["name"] for v in VECTORS])
def test_both_decoders_give_each_records_messages(v: dict, tmp_path: Path) -> None:
    path, numbers = _capture(v, tmp_path)
    want = {n: [tuple(m) for m in r["messages"]] for n, r in zip(numbers, v["records"]) if r["messages"]}
    assert python_frames(path) == want
    assert core_frames(path) == want
    assert lua_frames(path) == want
