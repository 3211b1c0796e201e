"""Issue 41, item 6: one expert summary per problem, the values in fields of their own.

``tshark -z expert`` groups expert infos by their summary: a summary that quotes a value ("Bad
checksum: E5, calculated CF") made one row per value instead of one per problem. Every expert of
sharedlink.lua, p2os.lua and blackboard.lua now has a summary with no value of the packet in it
(the values are in the items the expert sits on: sharedlink.checksum and .calculated, .sync.gap,
.var.value, .field.letter, .noise; p2os.checksum and .calculated, p2os.count, p2os.arg.length;
blackboard.checksum and .calculated, .non_hex.char, .ack.expected, .repeat_of, .unanswered_in).
A "Limit exceeded: ..." summary names a preference's value, the same all capture long: one row.

Checked on the golden inputs (faults, late syncs, noise, odd fields, malformed frames, replies),
the fuzz regressions and the P2OS/blackboard captures with damage, each run once through tshark.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import tshark_util as tu

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = ("p2os.lua", "blackboard.lua", "serial.lua")
EXTRA = [a for s in SCRIPTS for a in ("-X", f"lua_script:{REPO / 'dissector' / s}")]
CAPTURES = sorted((REPO / "tests" / "dissector" / "golden" / "inputs").glob("*.pcap*")) + sorted(
    (REPO / "tests" / "fuzz" / "fuzz-regressions").glob("*.pcap")) + sorted(
    (REPO / "tests" / "dissector" / "golden_small").glob("*.pcap*"))
#: summaries with a digit that is no value of a packet (fixed texts of the dissectors)
FIXED = {"Byte count over 200: P2OS ignores this packet", "Byte count below 2 leaves no room for the checksum",
         "Not a long (int64)", "Non-hex characters past the first 8"}
OURS = {"SHAREDLINK", "P2OS", "BLACKBOARD"}
_ROW = re.compile(r"^\s+(\d+)\s+(\S+)\s+(\S+)\s+(.*)$")


def summaries(cap: Path) -> list[tuple[str, str]]:
    """(protocol, summary) of every row of -z expert."""
    out = tu.tshark(cap, [*EXTRA, "-q", "-z", "expert"]).stdout
    return [(m.group(3), m.group(4)) for m in map(_ROW.match, out.splitlines()) if m and m.group(1).isdigit()]


@pytest.mark.parametrize("cap", CAPTURES, ids=lambda p: p.name)
def test_every_summary_names_a_problem_not_a_value(cap: Path) -> None:
    rows = [(p, s) for p, s in summaries(cap) if p in OURS]
    for proto, text in rows:
        if text.startswith("Limit exceeded") or text in FIXED:
            continue
        assert not re.search(r"\d|\"|\\x|0x", text.replace("P2OS", "")), (proto, text)
        assert text.isprintable(), (proto, text)
    assert len(rows) == len(set(rows)), rows


def test_bad_checksums_of_many_values_make_one_row(tmp_path: Path) -> None:
    """Twelve bad checksums, each its own received and calculated value, and late frames of
    different gaps: one row each in -z expert; the values in their fields."""
    pk = []
    for i in range(12):
        right = int(tu.checksum(f":AB|N0|D{i}|D1|C"), 16)
        pk.append((i * 0.1, tu.frame("A", "B", "N0", f"D{i}", "D1", cs="%02X" % ((right + 0x80) % 256))))
    for k, t in enumerate((5.0, 7.5, 11.0)):
        pk.append((t, tu.frame("A", "B", "N1", f"D{k}")))
    cap = tu.write_pcap(tmp_path / "bad.pcap", pk)
    rows = [(p, s) for p, s in summaries(cap) if p == "SHAREDLINK"]
    assert sorted(rows) == [("SHAREDLINK", "Bad checksum"), ("SHAREDLINK", "Link silent"),  # (the silences: outages)
                            ("SHAREDLINK", "No full frame within the sync interval")]
    got = tu.fields(cap, ["sharedlink.checksum", "sharedlink.checksum.calculated", "sharedlink.sync.gap"],
                    two_pass=False)
    assert len({r["sharedlink.checksum"][0] for r in got[:12]}) >= 10
    assert all(r["sharedlink.checksum.calculated"] for r in got[:12])
    gaps = [float(r["sharedlink.sync.gap"][0]) for r in got[12:]]
    assert len(set(gaps)) == 3 and all(g > 1.5 for g in gaps)
