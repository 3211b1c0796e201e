"""dissector/sharedlink_stats.lua in the real tshark: its counts agree with Expert Information,
pairs are written as the packet list writes them (``B→A``), the tables are aligned, and the tap
costs nothing until asked for (no tree is built in a pass that does not ask for the statistic).
Every run is checked for Lua errors (tshark_util)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.generators.beacon import GenOptions, generate_file

REPO = Path(__file__).resolve().parents[2]
STATS = REPO / "dissector" / "sharedlink_stats.lua"
OTHERS = [s for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua"]
ARROW = "\u2192"

# A postdissector that writes into the Info column whether the packet was dissected with a
# tree: Wireshark builds one only when something (a filter, a tap, a Field extractor) wants it.
# Lua always gets a TreeItem; its text says whether a tree is behind it ("has subtree=true").
PROBE = """
local probe = Proto("treeprobe", "Tree probe")
function probe.dissector(tvb, pinfo, tree)
    local has_tree = tostring(tree):find("has subtree=true", 1, true) ~= nil
    pinfo.cols.info:append(has_tree and " [tree]" or " [no tree]")
end
register_postdissector(probe)
"""


def plugins(*extra: Path) -> list[str]:
    """-X options for every dissector/*.lua besides sharedlink.lua (as `make install` leaves
    them), then ``extra``."""
    return [a for s in [*OTHERS, *extra] for a in ("-X", f"lua_script:{s}")]


_reports: dict[tuple[Path, tuple[str, ...]], str] = {}


def report(capture: Path, *extra: str) -> tuple[dict, str]:
    """Run ``-z sharedlink,stats`` and ``-z expert``; the tap's tables and the expert text (one
    run a capture for the tests that read it)."""
    if (capture, extra) not in _reports:
        _reports[capture, extra] = tu.tshark(capture, ["-q", *plugins(), "-z", "sharedlink,stats", "-z", "expert",
                                                       *extra]).stdout
    text = _reports[capture, extra]
    assert "SharedLink statistics" in text, text
    start = text.index("=" * 20)
    return parse(text[start:]), text[:start]


def parse(text: str) -> dict:
    out: dict = {"pairs": {}, "kinds": {}, "vars": {}, "tables": {}}
    section = None
    for line in text.splitlines():
        if m := re.match(r"(Frames|Checksum failures|Sync late): (\d+)$", line):
            out[m.group(1)] = int(m.group(2))
        elif line in ("Frames per kind", "Frames per node pair", "Variables"):
            section = line
            out["tables"][section] = []
        elif line.startswith("  ") and section:
            out["tables"][section].append(line)
            cols = re.split(r"\s{2,}", line.strip())
            if cols[0] in ("Pair", "Kind"):
                header = cols
            elif section == "Frames per node pair":
                out["pairs"][cols[0]] = dict(zip(header[1:], map(int, cols[1:])))
            elif section == "Frames per kind":
                out["kinds"][cols[0]] = int(cols[1])
        elif not line.startswith("  "):  # (a section of its own: link health, test_health_tap.py)
            section = None
    return out


def expert_counts(text: str) -> dict[str, int]:
    """Expert Information (``-z expert``) of SharedLink: summary prefix -> frequency, added up."""
    counts: dict[str, int] = {}
    for m in re.finditer(r"^\s+(\d+)\s+\S+\s+SHAREDLINK\s+(.+)$", text, re.M):
        key = "late" if m.group(2).startswith("No full frame") else m.group(2).split(":")[0]
        counts[key] = counts.get(key, 0) + int(m.group(1))
    return counts


@pytest.fixture(scope="module")
def lossy(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("tap") / "lossy.pcap"
    generate_file(GenOptions(duration=60, seed=5, compress=True, drop=0.12, bad_checksum=0.06), p)
    return p


@pytest.fixture(scope="module")
def mixed(tmp_path_factory) -> Path:
    """Two pairs; a late frame with a bad checksum; a packet holding two late frames."""
    a = tu.frame("A", "B", "N0", "T2", "QAutoGpsLat", "D38.5", "T2", "QAutoGpsLon", "D-77.1")
    d = tu.frame("A", "B", "N1", "D38.6")
    bad = tu.frame("A", "B", "N1", "D38.7", cs="00")
    decl = tu.frame("C", "D", "N0", "T0", "QCount", "T2", "QLevel")
    pos = tu.frame("C", "D", "N0", "D1", "D0.5")
    pos2 = tu.frame("C", "D", "N0", "D", "D0.75")
    pkts = [
        tu.Pkt(0.0, a), tu.Pkt(0.2, d), tu.Pkt(3.0, bad), tu.Pkt(5.0, d + d),
        tu.Pkt(1.0, decl, 4000, 4001), tu.Pkt(1.1, pos, 4000, 4001), tu.Pkt(4.0, pos2 + pos2, 4000, 4001),
        tu.Pkt(4.1, tu.frame("D", "C", "QLevel"), 4001, 4000),
    ]
    pkts.sort(key=lambda p: p.ts)
    return tu.write_pcap(tmp_path_factory.mktemp("tap") / "mixed.pcap", pkts)


@pytest.mark.parametrize("name", ["lossy", "mixed"])
def test_counts_match_expert_information(request, name):
    tap, expert = report(request.getfixturevalue(name))
    counts = expert_counts(expert)
    assert counts.get("late", 0) > 0 and counts.get("Bad checksum", 0) > 0, expert
    assert tap["Sync late"] == counts["late"]
    assert tap["Checksum failures"] == counts["Bad checksum"]
    assert sum(p["Sync late"] for p in tap["pairs"].values()) == tap["Sync late"]
    assert sum(p["Bad checksum"] for p in tap["pairs"].values()) == tap["Checksum failures"]
    assert sum(p["Frames"] for p in tap["pairs"].values()) == tap["Frames"] == sum(tap["kinds"].values())


def test_mixed_counts(mixed):
    tap, _ = report(mixed)
    # the bad frame at 3.0 s is late (counted, as Expert Information does); both frames of the
    # packet at 5.0 s are late; D→C's query at 4.1 s is not a data frame
    assert tap["pairs"][f"B{ARROW}A"]["Sync late"] == 3
    assert tap["pairs"][f"B{ARROW}A"]["Bad checksum"] == 1
    assert tap["pairs"][f"D{ARROW}C"]["Sync late"] == 2
    assert tap["pairs"][f"C{ARROW}D"] == {"Frames": 1, "Bad checksum": 0, "Sync late": 0, "query": 1,
                                          **{k: 0 for k in tap["kinds"] if k != "query"}}


def test_pairs_written_as_in_the_packet_list(mixed):
    tap, _ = report(mixed)
    lines = tu.summary(mixed, extra=plugins())
    listed = {m.group(1) for ln in lines for m in re.finditer(rf"\b([A-P]{ARROW}[A-P])\b", ln)}
    assert set(tap["pairs"]) == listed == {f"B{ARROW}A", f"D{ARROW}C", f"C{ARROW}D"}


def test_columns_are_aligned(mixed):
    tap, _ = report(mixed)
    for title, rows in tap["tables"].items():
        header, body = rows[0], rows[1:]
        assert body, title
        # every right-aligned number column ends where its header ends (widths in characters)
        for m in re.finditer(r"(Frames|Bad checksum|Sync late|Count|query|full|delta|declaration)", header):
            end = m.end()
            for row in body:
                assert row[end - 1].isdigit() and (end == len(row) or row[end] == " "), (title, header, row)
        # left-aligned text columns start where their header starts
        for m in re.finditer(r"(Variable|Last value)", header):
            for row in body:
                assert row[m.start() - 1] == " " and row[m.start()] != " ", (title, header, row)


def test_the_tap_costs_nothing_until_asked(tmp_path, mixed):
    probe = tmp_path / "treeprobe.lua"
    probe.write_text(PROBE)
    # the statistic not asked for: no packet is dissected with a tree
    lines = tu.summary(mixed, extra=plugins(probe))
    assert lines and all(ln.endswith("[no tree]") for ln in lines), lines
    # asked for: the tap's listener exists (it wants its fields, hence a tree)
    res = tu.tshark(mixed, [*plugins(probe), "-z", "sharedlink,stats"])
    assert "SharedLink statistics" in res.stdout
    assert all(ln.endswith("[tree]") for ln in res.stdout.splitlines() if ln.startswith("    "))


def test_filter_argument_keeps_counting_right(lossy):
    tap, _ = report(lossy)
    part = parse(tu.tshark(lossy, ["-q", *plugins(), "-z", "sharedlink,stats,sharedlink.kind == \"full\""]).stdout)
    assert part["Frames"] == part["kinds"]["full"] == tap["kinds"]["full"]
    assert set(part["kinds"]) == {"full"}
