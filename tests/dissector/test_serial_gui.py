"""What the GUI shows of serial captures and of P2OS/blackboard, in the real tshark with every
dissector/*.lua loaded (as `make install` leaves them), on a second pass as the GUI does:
Source/Destination name the direction, a record that only holds bytes says so in one clear
Info line and one tree row, the record completing a frame names the protocol and shows
Wireshark's fragment subtree ("[N Reassembled fragments (L bytes): #a(n), ...]"), P2OS says
its direction in words, a blackboard message's terminator is its last field."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from sl_cli import run_cli

import tshark_util as tu

REPO = Path(__file__).resolve().parents[2]
OTHERS = [a for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua"
          for a in ("-X", f"lua_script:{s}")]
COLS = (["_ws.col.def_src", "_ws.col.def_dst", "_ws.col.info"] if tu.TSHARK_VERSION >= (4, 2)
        else ["_ws.col.Source", "_ws.col.Destination", "_ws.col.Info"])
ENDS = {"1": ("device", "host"), "0": ("host", "device")}
LABELS = {"sharedlink": "SharedLink", "p2os": "P2OS", "blackboard": "Blackboard"}


def generate(path: Path, protocol: str, duration: float, seed: int) -> Path:
    """A serial session written by `sharedlink gen --transport serial`."""
    r = run_cli("gen", str(path), "--protocol", protocol, "--transport", "serial", "--duration", str(duration), "--seed", str(seed), timeout=120)
    assert r.returncode == 0, r.stderr
    return path


@pytest.fixture(scope="module", params=["sharedlink", "p2os", "blackboard"])
def serial_capture(request, tmp_path_factory) -> tuple[str, Path]:
    path = tmp_path_factory.mktemp("serialgui") / f"{request.param}.pcapng"
    return request.param, generate(path, request.param, 4.0, 2)


def rows(path: Path, extra: list[str]) -> list[dict[str, list[str]]]:
    return tu.fields(path, ["frame.number", "frame.p2p_dir", *COLS, *extra], extra=OTHERS, two_pass=True)


def test_columns_held_records_and_fragments(serial_capture):
    proto, path = serial_capture
    rs = rows(path, ["slserial.held", "slserial.fragment", "slserial.fragment.count", "slserial.reassembled.length",
                     "slserial.frames"])
    src, dst, info = COLS
    by_num = {int(r["frame.number"][0]): r for r in rs}
    held = 0
    for r in rs:
        assert (r[src][0], r[dst][0]) == ENDS[r["frame.p2p_dir"][0]], r
        if r["slserial.held"] and not int(r["slserial.frames"][0]):
            held += 1
            # one clear line: how many bytes, of which protocol's frame, completed where
            m = re.fullmatch(rf"\[(\d+) bytes? held, part of a {LABELS[proto]} frame completed in record (\d+)\]",
                             r[info][0])
            assert m, r[info]
            done = by_num[int(m.group(2))]
            assert int(r["frame.number"][0]) in [int(x) for x in done["slserial.fragment"]]
        if r["slserial.fragment"]:
            frags = [int(x) for x in r["slserial.fragment"]]
            assert int(r["slserial.fragment.count"][0]) == len(frags) and frags[-1] == int(r["frame.number"][0])
    assert held, "the capture has records that only hold bytes"


def test_completing_record_tree(serial_capture):
    proto, path = serial_capture
    text = tu.verbose(path, extra=[*OTHERS, "-O", "slserial"])
    reassembled = re.findall(
        r"^Serial link, \w+, \d+ bytes?, completes (\d+) (\w+) frames? \((\d+) bytes reassembled from (\d+) records?\)\n"
        r"(?:    .*\n)*?    \[(\d+) Reassembled fragments \((\d+) bytes\): ((?:#\d+\(\d+\)(?:, )?)+)\]\n"
        r"((?:        \[Frame: \d+, payload: \d+-\d+ \(\d+ bytes?\)\]\n)+)", text, re.M)
    assert reassembled, text[:3000]
    for _n, label, total, nrec, nfrag, total2, summary, frame_rows in reassembled:
        assert label == LABELS[proto]
        sizes = [int(x) for x in re.findall(r"#\d+\((\d+)\)", summary)]
        assert int(total) == int(total2) == sum(sizes) and int(nrec) == int(nfrag) == len(sizes)
        # the rows cover the reassembled bytes in order, without gap
        spans = [(int(a), int(b)) for a, b in re.findall(r"payload: (\d+)-(\d+)", frame_rows)]
        assert spans[0][0] == 0 and spans[-1][1] == int(total) - 1
        assert all(b + 1 == c for (_, b), (c, _) in zip(spans, spans[1:]))


def test_p2os_direction_in_words(tmp_path):
    path = generate(tmp_path / "p2os.pcapng", "p2os", 2.0, 4)
    rs = rows(path, ["p2os.direction"])
    info = COLS[2]
    seen = set()
    for r in rs:
        if r["p2os.direction"]:
            first = r["p2os.direction"][0]
            prefix = "Client\u2192Robot " if first == "0" else "Robot\u2192Client "
            assert r[info][0].startswith(prefix), r
            assert "> " not in r[info][0] and "< " not in r[info][0]
            seen.add(first)
    assert seen == {"0", "1"}
    text = tu.verbose(path, extra=[*OTHERS, "-O", "p2os"])
    assert "[Direction: client to robot (command) (0), from the capture (sent by the client's side)]" in text
    assert "[Direction: robot to client (server packet) (1), from the capture (received by the client's side)]" in text


def test_blackboard_terminator_last(tmp_path):
    path = generate(tmp_path / "bb.pcapng", "blackboard", 2.0, 4)
    text = tu.verbose(path, extra=[*OTHERS, "-O", "blackboard"])
    blocks = re.findall(r"^Blackboard message \(Holland\), (?:set|request)[^\n]*\n((?:    .*\n)+)", text, re.M)
    assert blocks
    for block in blocks:
        lines = block.splitlines()
        assert lines[-1].startswith("    Terminator: "), block
        assert lines[0].startswith("    Message type: ")
