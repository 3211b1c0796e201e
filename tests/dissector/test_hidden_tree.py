"""A tree nobody sees filters as a shown one (issue 27): the same frames match a display filter.

One builder (dissector/sharedlink/tree.lua) makes the shown tree (``-V``: every item with its range
and label) and the hidden one (``-Y`` alone, coloring rules, taps: values only, and a field nobody
references is not added at all, as Wireshark tells: TreeItem:referenced).  For each display filter
below, over every capture of captures/, the golden inputs, the fuzz regressions and freshly
generated fault captures (concatenated into one file), the frames ``-Y F`` matches with a hidden
tree must be the frames ``-V -Y F`` matches with a shown one: in one pass (the answers kept over
the first pass), with the fields asked again each frame (``SHAREDLINK_PROBE_EACH_FRAME=1``) and
with two passes (``-2``: the second pass asks each dissection).
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest
from sl_cli import run_cli

import tshark_util as tu

REPO = Path(__file__).resolve().parents[2]
SERIAL_LUA = REPO / "dissector" / "serial.lua"
INPUTS = sorted((REPO / "captures").glob("*.pcap")) + sorted(
    p for p in (REPO / "tests" / "dissector" / "golden" / "inputs").iterdir() if p.suffix in (".pcap", ".pcapng")
) + sorted((REPO / "tests" / "fuzz" / "fuzz-regressions").glob("*.pcap"))

# its module fixtures' tshark runs (shared by every test here) made once: one pytest-xdist worker
# (make test: --dist loadgroup)
pytestmark = pytest.mark.xdist_group("hidden_tree")
# generated fault captures: sharedlink gen options
GENERATED = {
    "named-faults": ["--frames", "400", "--compress", "--drop", "0.2", "--bad-checksum", "0.05", "--seed", "5"],
    "positional-faults": ["--frames", "300", "--form", "positional", "--compress", "--bad-checksum", "0.05",
                          "--drop", "0.1", "--seed", "6"],
    "serial-noise": ["--frames", "200", "--transport", "serial", "--noise", "0.05", "--bad-checksum", "0.05",
                     "--compress", "--seed", "8", "--format", "pcapng"],
}
# positional values typed (doubles, a string, a long), so the typed fields and var.badvalue occur
PREFS = {"sharedlink.variables": "AutoGpsLat:2,AutoGpsLon:2,AutoGpsHead:2,AutoGpsVel:2,Mode:4,Count:0"}

# Every filter must match at least one frame of the merged capture (else it would test nothing).
FILTERS = [
    "sharedlink",
    "sharedlink.checksum.status == 0",
    "sharedlink.checksum.status == 1 && sharedlink.kind == \"delta\"",
    "sharedlink.checksum < 0x40",
    "sharedlink.checksum.calculated > 0x80",
    "sharedlink.checksum.text",
    "sharedlink.kind == \"full\"",
    "sharedlink.kind == \"query\" || sharedlink.kind == \"reply\" || sharedlink.kind == \"declaration\"",
    "sharedlink.dst == \"A\" && sharedlink.src.node == 2",
    "sharedlink.ordinal > 0",
    "sharedlink.inbound_ordinal",
    "sharedlink.type == 2",
    "count(sharedlink.var) >= 4",
    "sharedlink.var.name == \"AutoGpsLat\"",
    "sharedlink.var.name contains \"Head\" && sharedlink.var.value contains \"9\"",
    "sharedlink.var.index == 2",
    "sharedlink.var.double > 30",
    "sharedlink.var.double < 0",
    "sharedlink.var.long",
    "sharedlink.var.string",
    "sharedlink.var.carried",
    "sharedlink.var.carried_from > 100",
    "sharedlink.var.carried && sharedlink.var.name == \"AutoGpsVel\"",
    "!sharedlink.var.carried && sharedlink.kind == \"delta\"",
    "sharedlink.sync.is_late",
    "sharedlink.query",
    "sharedlink.response",
    "sharedlink.response_in || sharedlink.response_to",
    "sharedlink.response_time >= 0",
    "sharedlink.command || sharedlink.mode || sharedlink.ping || sharedlink.pong",
    "sharedlink.command.arg",
    "sharedlink.field.letter || sharedlink.field.text",
    "sharedlink.noise",
    "sharedlink.malformed",
    "sharedlink.checksum.bad",
    "sharedlink.checksum.format",
    "sharedlink.var.badvalue",
    "sharedlink.var.unknown",
    "sharedlink.crlf.missing",
    "sharedlink.sync.late && sharedlink.var.double",
    "sharedlink.reply.unmatched",
]
# asked with two passes too (the first primes the filter)
TWO_PASS = FILTERS[:3] + ["sharedlink.var.carried_from > 100", "sharedlink.response_in || sharedlink.response_to",
                          "sharedlink.var.double > 30", "sharedlink.sync.is_late", "sharedlink.var.badvalue",
                          # fields a calm frame's hidden tree asks after the head's (tree.lua calm_unseen) and
                          # an index, which needs the direction a later pass finds for the tree alone
                          "sharedlink.value.AutoGpsVel > 12", "sharedlink.var.long", "sharedlink.var.carried",
                          "sharedlink.var.index == 2"]

_FRAME = re.compile(r"^Frame (\d+):", re.M)


@pytest.fixture(scope="module")
def merged(tmp_path_factory: pytest.TempPathFactory) -> Path:
    work = tmp_path_factory.mktemp("hidden-tree")
    caps = list(INPUTS)
    for name, opts in GENERATED.items():
        cap = work / f"{name}.{'pcapng' if '--format' in opts else 'pcap'}"
        run_cli("gen", *opts, str(cap), text=False, check=True)
        caps.append(cap)
    out = work / "merged.pcapng"
    subprocess.run(["mergecap", "-a", "-F", "pcapng", "-w", str(out), *map(str, caps)], check=True,
                   capture_output=True)
    return out


@pytest.fixture(scope="module")
def shown(merged: Path) -> dict[str, list[int]]:
    """The frames each filter matches with a shown tree (-V), one pass: one tshark run for all."""
    return tu.shown_matches(merged, FILTERS, prefs=PREFS, extra=["-X", f"lua_script:{SERIAL_LUA}"], timeout=300)


@pytest.fixture(scope="module")
def shown_two_pass(merged: Path) -> dict[str, list[int]]:
    """The same with two passes (-2 -V): the second pass's matches."""
    return tu.shown_matches(merged, TWO_PASS, prefs=PREFS, two_pass=True, extra=["-X", f"lua_script:{SERIAL_LUA}"],
                            timeout=300)


def _hidden(cap: Path, flt: str, two_pass: bool = False) -> list[int]:
    # the summary line holds the frame number alone: no column references a field
    out = tu.tshark(cap, ["-X", f"lua_script:{SERIAL_LUA}", "-o", 'gui.column.format:"No.","%m"', "-Y", flt],
                    prefs=PREFS, two_pass=two_pass, timeout=300).stdout
    return [int(line) for line in out.split()]


def test_shown_matches_are_what_minus_v_minus_y_prints(merged: Path, shown: dict[str, list[int]],
                                                        shown_two_pass: dict[str, list[int]]) -> None:
    """The shared shown-tree run (one Lua tap a filter) gives the frames ``-V -Y F`` prints, in
    one pass and in two, for a few filters of each kind."""
    for flt in (FILTERS[0], "sharedlink.var.carried_from > 100", "sharedlink.noise", "sharedlink.reply.unmatched"):
        out = tu.tshark(merged, ["-X", f"lua_script:{SERIAL_LUA}", "-V", "-O", "frame", "-Y", flt], prefs=PREFS,
                        timeout=300).stdout
        assert [int(n) for n in _FRAME.findall(out)] == shown[flt], flt
    flt = "sharedlink.response_in || sharedlink.response_to"
    out = tu.tshark(merged, ["-X", f"lua_script:{SERIAL_LUA}", "-V", "-O", "frame", "-Y", flt], prefs=PREFS,
                    two_pass=True, timeout=300).stdout
    assert [int(n) for n in _FRAME.findall(out)] == shown_two_pass[flt], flt


@pytest.mark.parametrize("flt", FILTERS)
def test_hidden_tree_matches_the_frames_a_shown_one_matches(flt: str, merged: Path, shown: dict[str, list[int]],
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    assert shown[flt], f"{flt!r} matches no frame: it tests nothing"
    assert _hidden(merged, flt) == shown[flt], flt
    with monkeypatch.context() as m:   # referenced fields asked again each frame
        m.setenv("SHAREDLINK_PROBE_EACH_FRAME", "1")
        assert _hidden(merged, flt) == shown[flt], f"{flt} (probe each frame)"


@pytest.mark.parametrize("flt", TWO_PASS)
def test_hidden_tree_matches_with_two_passes(flt: str, merged: Path, shown_two_pass: dict[str, list[int]]) -> None:
    assert shown_two_pass[flt], f"{flt!r} matches no frame: it tests nothing"
    assert _hidden(merged, flt, two_pass=True) == shown_two_pass[flt], flt
