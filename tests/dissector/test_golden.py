"""Golden output of the SharedLink dissector: every route a frame can take, compared byte for byte.

Every input -- the sample captures (captures/), the shared vectors (tests/vectors, written as
captures into tests/dissector/golden/inputs/), the fuzz regressions (tests/fuzz/fuzz-regressions)
and a few generated captures kept in golden/inputs/ -- goes through tshark in each of the modes
of tests/sl_golden.py: the summary pass (no tree) in one and two passes, a tree nobody sees (-Y
with every ``sharedlink.*`` field as a custom column), -V and -2 -V (a shown tree), PDML,
``-T fields`` of every ``sharedlink.*`` field, and ``-z expert`` (its report taken from the
summary pass's run; test_experts.py reads the reports of that run, the two-pass one and PDML's).  The outputs are compared with the files in
golden/tshark-<major>.<minor>/ (xz-compressed, one per input) and any difference fails.

The golden files were made with the dissector as it was at ff41cb3; a change of output is made on
purpose, explained in the commit that updates them.  To make them again (after such a change,
or when an input is added):

    SHAREDLINK_GOLDEN_UPDATE=1 .venv/bin/pytest -n 2 tests/dissector/test_golden.py

which also writes the vector streams' captures again (docs/testing.md).  Only sharedlink.lua is
loaded (and serial.lua for serial captures), so that changes to the other dissectors do not
show here.  A tshark release with no golden folder is skipped (its -V and PDML differ from 4.0's
in Wireshark's own lines).
"""

from __future__ import annotations

import difflib
import json
import lzma

import pytest
import sl_golden as sg

import tshark_util as tu

GOLDEN = sg.GOLDEN
INPUTS = sg.INPUTS
MANIFEST = sg.MANIFEST
VERSION_DIR = sg.VERSION_DIR
UPDATE = sg.UPDATE

# one worker runs this file and test_experts.py, which reads the expert reports of these runs
pytestmark = pytest.mark.xdist_group("golden")

# generated inputs kept in golden/inputs (sharedlink gen arguments, for the record; remade only by hand)
GENERATED = {
    "gen-faults": "gen --compress --drop 0.2 --bad-checksum 0.05 --seed 2",
    "gen-positional": "gen --frames 120 --compress --form positional --drop 0.1 --bad-checksum 0.05 --seed 3",
    "gen-late-sync": "gen --frames 150 --compress --sync-interval 3 --seed 4",
    "gen-serial": "gen --frames 80 --compress --transport serial --noise 0.05 --seed 5",
}


def _write_vector_inputs() -> None:
    """Write the vector streams as captures into golden/inputs and list every kept input in the manifest."""
    from sl_vectors import load_streams, write_stream

    INPUTS.mkdir(parents=True, exist_ok=True)
    manifest: dict[str, dict] = {}
    for stream in load_streams():
        serial = stream.get("transport") == "serial"
        name = f"vector-{stream['name']}"
        path = write_stream(stream, INPUTS / f"{name}.{'pcapng' if serial else 'pcap'}")
        entry: dict = {"file": path.name, "serial": serial}
        if "variables" in stream:
            entry["prefs"] = {"sharedlink.variables": stream["variables"]}
        manifest[name] = entry
    for name in GENERATED:
        for ext, serial in (("pcap", False), ("pcapng", True)):
            if (INPUTS / f"{name}.{ext}").exists():
                manifest[name] = {"file": f"{name}.{ext}", "serial": serial}
    MANIFEST.write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")


if UPDATE:
    _write_vector_inputs()
INPUT_SET = sg.inputs()


def _run(name: str, entry: dict) -> str:
    return "".join(f"===== {name}: {mode} =====\n{out}" for mode, out in sg.outputs(name, entry).items())


@pytest.mark.parametrize("name", sorted(INPUT_SET))
def test_golden_output(name: str) -> None:
    entry = INPUT_SET[name]
    golden = VERSION_DIR / f"{name}.txt.xz"
    if not UPDATE and not VERSION_DIR.is_dir():
        pytest.skip(f"no golden output for tshark {tu.TSHARK_VERSION[0]}.{tu.TSHARK_VERSION[1]}")
    actual = _run(name, entry)
    if UPDATE:
        VERSION_DIR.mkdir(parents=True, exist_ok=True)
        golden.write_bytes(lzma.compress(actual.encode("utf-8"), preset=9 | lzma.PRESET_EXTREME))
        return
    assert golden.exists(), f"no golden file {golden.name}: make it with SHAREDLINK_GOLDEN_UPDATE=1"
    expected = lzma.decompress(golden.read_bytes()).decode("utf-8")
    if actual != expected:
        diff = list(difflib.unified_diff(expected.splitlines(), actual.splitlines(), "golden", "now",
                                         lineterm="", n=2))
        pytest.fail(f"{name}: output differs from {golden.name} ({len(diff)} diff lines):\n"
                    + "\n".join(diff[:80]))


def test_golden_files_have_inputs() -> None:
    """Every golden file belongs to an input (a removed input leaves no stale file behind)."""
    if not VERSION_DIR.is_dir():
        pytest.skip("no golden output for this tshark")
    stale = sorted(p.name for p in VERSION_DIR.glob("*.txt.xz") if p.name[:-7] not in INPUT_SET)
    assert not stale, f"golden files without an input: {stale}"
