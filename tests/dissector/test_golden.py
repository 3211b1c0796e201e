"""Golden output of the SharedLink dissector: every route a frame can take, compared byte for byte.

Every input -- the sample captures (captures/), the shared vectors (tests/vectors, written as
captures into tests/dissector/golden/inputs/), the fuzz regressions (tests/fuzz/fuzz-regressions)
and a few generated captures kept in golden/inputs/ -- goes through tshark in each of MODES:
the summary pass (no tree) in one and two passes, a tree nobody sees (-Y with every
``sharedlink.*`` field as a custom column), -V and -2 -V (a shown tree), PDML, ``-T fields`` of
every ``sharedlink.*`` field, and ``-z expert``.  The outputs are compared with the files in
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
import os
import re
import subprocess
from pathlib import Path

import pytest

import tshark_util as tu

REPO = Path(__file__).resolve().parents[2]
GOLDEN = Path(__file__).resolve().parent / "golden"
INPUTS = GOLDEN / "inputs"
MANIFEST = INPUTS / "manifest.json"
VERSION_DIR = GOLDEN / f"tshark-{tu.TSHARK_VERSION[0]}.{tu.TSHARK_VERSION[1]}"
UPDATE = os.environ.get("SHAREDLINK_GOLDEN_UPDATE") == "1"
SERIAL_LUA = REPO / "dissector" / "serial.lua"

# generated inputs kept in golden/inputs (sharedlink gen arguments, for the record; remade only by hand)
GENERATED = {
    "gen-faults": "gen --compress --drop 0.2 --bad-checksum 0.05 --seed 2",
    "gen-positional": "gen --frames 120 --compress --form positional --drop 0.1 --bad-checksum 0.05 --seed 3",
    "gen-late-sync": "gen --frames 150 --compress --sync-interval 3 --seed 4",
    "gen-serial": "gen --frames 80 --compress --transport serial --noise 0.05 --seed 5",
}


def _sharedlink_fields() -> list[str]:
    tu.ensure_loaded()
    out = subprocess.run([*tu.TSHARK_CMD, "-G", "fields", "-X", f"lua_script:{tu.DISSECTOR}"], capture_output=True,
                         text=True, env=tu._clean_env(), timeout=120).stdout
    names = [cols[2] for cols in (line.split("\t") for line in out.splitlines())
             if len(cols) > 3 and cols[0] == "F" and cols[2].startswith("sharedlink.")]
    assert "sharedlink.var.name" in names, "tshark -G fields did not list the dissector's fields"
    return sorted(names)


def _modes(fields: list[str]) -> dict[str, tuple[bool, list[str]]]:
    """mode -> (two passes, tshark arguments)."""
    cols = ['"No.","%m","Info","%i"'] + [f'"{f}","%Cus:{f}"' for f in fields]
    fargs = ["-T", "fields", "-E", "occurrence=a", "-E", "aggregator=|", "-E", "quote=n",
             "-e", "frame.number", "-e", tu.INFO_FIELD, "-e", "_ws.expert.message"]
    for f in fields:
        fargs += ["-e", f]
    return {
        "summary": (False, []),
        "summary-2": (True, []),
        "hidden": (False, ["-Y", "sharedlink", "-o", "gui.column.format:" + ",".join(cols)]),
        "V": (False, ["-V"]),
        "2V": (True, ["-V"]),
        "pdml": (False, ["-T", "pdml"]),
        "fields": (True, fargs),
        "expert": (False, ["-q", "-z", "expert"]),
    }


def _inputs() -> dict[str, dict]:
    """input name -> {"path", "prefs", "serial"}."""
    out: dict[str, dict] = {}
    for p in sorted((REPO / "captures").glob("*.pcap")):
        out[f"capture-{p.stem}"] = {"path": str(p), "prefs": {}, "serial": False}
    for p in sorted((REPO / "tests" / "fuzz" / "fuzz-regressions").glob("*.pcap*")):
        out[f"fuzz-{p.stem}"] = {"path": str(p), "prefs": {}, "serial": False}
    if MANIFEST.exists():
        for name, entry in json.loads(MANIFEST.read_text()).items():
            out[name] = {"path": str(INPUTS / entry["file"]), "prefs": entry.get("prefs", {}),
                         "serial": entry.get("serial", False)}
    return out


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
INPUT_SET = _inputs()
_PDML_HEAD = re.compile(r'^<pdml .*>$', re.M)


#: the modes taken from one run: the summary lines, then -z expert's report (the report starts with
#: an empty line, which no summary line is; the tap needs no tree, so the pass is the summary's)
_SUMMARY_AND_EXPERT = ("summary", "expert")
_REPORT_START = re.compile(r"^$", re.M)


def _run(name: str, entry: dict, fields: list[str]) -> str:
    parts = []
    extra = ["-X", f"lua_script:{SERIAL_LUA}"] if entry["serial"] else []
    both = tu.tshark(entry["path"], [*extra, "-z", "expert"], prefs=entry["prefs"]).stdout
    cut = _REPORT_START.search(both).start()  # type: ignore[union-attr]  (the end at least)
    shared = dict(zip(_SUMMARY_AND_EXPERT, (both[:cut], both[cut:])))
    for mode, (two_pass, args) in _modes(fields).items():
        out = shared.get(mode)
        if out is None:
            out = tu.tshark(entry["path"], [*extra, *args], prefs=entry["prefs"], two_pass=two_pass).stdout
        if mode == "pdml":   # the header names the file and the time of the run
            out = _PDML_HEAD.sub("<pdml>", out)
        parts.append(f"===== {name}: {mode} =====\n{out}")
    return "".join(parts)


@pytest.fixture(scope="module")
def fields() -> list[str]:
    return _sharedlink_fields()


@pytest.mark.parametrize("name", sorted(INPUT_SET))
def test_golden_output(name: str, fields: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TZ", "UTC")
    entry = INPUT_SET[name]
    golden = VERSION_DIR / f"{name}.txt.xz"
    if not UPDATE and not VERSION_DIR.is_dir():
        pytest.skip(f"no golden output for tshark {tu.TSHARK_VERSION[0]}.{tu.TSHARK_VERSION[1]}")
    actual = _run(name, entry, fields)
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
