"""Expert infos on every pass (issue 27): whatever tree is (not) built, the same expert infos.

tshark's summary pass has no tree, a display filter gives a tree nobody sees, -V a shown one; the
GUI opens a capture with no tree as well, and Expert Information must not wait for a filter.
``-z expert`` alone (no filter, no -V) must count what it counts with ``-Y sharedlink`` and with
a shown tree, per severity and group.

Where the capture is a golden input with no preference of its own, the runs test_golden.py makes
of it give the report alone (its summary pass), with a shown tree (its PDML run) and with two
passes (its two-pass summary pass): tests/sl_golden.py; this file runs the filtered ones.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest
import sl_golden as sg

import tshark_util as tu

REPO = Path(__file__).resolve().parents[2]
INPUTS = REPO / "tests" / "dissector" / "golden" / "inputs"
SERIAL_LUA = REPO / "dissector" / "serial.lua"
# captures with bad checksums, late syncs, malformed frames, noise, odd fields and unmatched replies
CAPTURES = ["gen-faults.pcap", "gen-positional.pcap", "gen-late-sync.pcap", "gen-serial.pcapng",
            "vector-frame-kinds-other-and-malformed.pcap", "vector-crlf-inside-a-value-and-modem-noise.pcap",
            "vector-positional-typed-by-declaration.pcap", "vector-reply-to-a-declaration.pcap"]
FUZZ = sorted((REPO / "tests" / "fuzz" / "fuzz-regressions").glob("*.pcap"))

# one worker runs this file and test_golden.py, whose runs give most reports here
pytestmark = pytest.mark.xdist_group("golden")
_GOLDEN = {Path(e["path"]): (name, e) for name, e in sg.inputs().items() if not e["prefs"]}
#: -z expert's arguments whose report a golden run gives -> which (sl_golden.expert_report)
_OF_GOLDEN = {("-q",): "expert", ("-V",): "expert-shown", ("-q", "-2"): "expert-2"}

_HEAD = re.compile(r"^(Errors|Warns|Notes|Chats|Comments) \((\d+)\)$")
_ROW = re.compile(r"^\s+(\d+)\s+(\S+)\s+(\S+)\s+(.*)$")


def _counts(text: str) -> Counter:
    """(severity, group) -> count from -z expert's table."""
    out: Counter = Counter()
    sev = None
    for line in text.splitlines():
        m = _HEAD.match(line)
        if m:
            sev = m.group(1)
            continue
        m = _ROW.match(line)
        if m and sev and m.group(1).isdigit():
            out[(sev, m.group(2))] += int(m.group(1))
    return out


def _expert(cap: Path, *args: str) -> Counter:
    if cap in _GOLDEN and args in _OF_GOLDEN:   # (-V's shown tree in one pass: the PDML run's)
        return _counts(sg.expert_report(*_GOLDEN[cap], _OF_GOLDEN[args]))
    extra = ["-X", f"lua_script:{SERIAL_LUA}"] if cap.suffix == ".pcapng" else []
    return _counts(tu.tshark(cap, [*extra, "-z", "expert", *args]).stdout)


@pytest.mark.parametrize("cap", [INPUTS / c for c in CAPTURES] + FUZZ, ids=lambda p: p.stem)
def test_expert_alone_counts_what_a_filter_and_a_shown_tree_count(cap: Path) -> None:
    alone = _expert(cap, "-q")
    assert alone, "the capture has expert infos"
    assert _expert(cap, "-q", "-Y", "sharedlink") == alone
    assert _expert(cap, "-V") == alone
    # two passes (the GUI's way): the second pass's experts (-2 may decode a fuzzed capture's
    # heuristic conversations differently from one pass, so compared with itself)
    assert _expert(cap, "-q", "-2") == _expert(cap, "-q", "-2", "-Y", "sharedlink")


def test_gen_faults_counts_as_the_issue_says() -> None:
    """`sharedlink gen f.pcap --compress --drop 0.2 --bad-checksum 0.05 --seed 2`: 14 bad checksums
    and 31 late syncs, with no filter."""
    counts = _expert(INPUTS / "gen-faults.pcap", "-q")
    assert counts[("Errors", "Checksum")] == 14
    assert counts[("Warns", "Sequence")] == 31


def test_an_expert_quoting_control_bytes_keeps_its_packet_on_one_row(tmp_path: Path) -> None:
    """A bad checksum's expert quotes the checksum text as sent; bytes such as \\x1d, \\x0b or
    \\x85 in it must not split the packet's ``-T fields`` row (tshark ends a row at LF alone).
    Found by hypothesis in test_serial_dissector (a serial frame cut short by binary noise)."""
    from sharedlink.capture.packets import UdpBuilder
    from sharedlink.capture.pcapio import PcapWriter

    frames = [b"[:AB|N0|D1|C9\x1d\x0b\x85]\r\n", b"[:AB|N0|D2|C00]\r\n"]
    cap = tmp_path / "ctl.pcap"
    with open(cap, "wb") as fh:
        w = PcapWriter(fh)
        for i, f in enumerate(frames):
            w.write(1_767_268_800 * 10**9 + i * 10**6, UdpBuilder("10.0.0.2", "10.0.0.1", 7013, 4000).frame(f, i + 1))
    rows = tu.fields(cap, ["frame.number", "sharedlink.checksum.status"])
    assert [r["frame.number"] for r in rows] == [["1"], ["2"]]
    assert any(m.startswith("Bad checksum") for m in rows[0]["_ws.expert.message"]), rows[0]
