"""The golden inputs' tshark runs (tests/dissector/test_golden.py), shared with the tests that ask
the same runs for something else (tests/dissector/test_experts.py: ``-z expert``'s report).

Every input goes through tshark in each of :func:`modes` (the docstring of test_golden.py says
which and why). Three runs carry ``-z expert`` too, its report cut off after their output: the
summary pass (the report starts with an empty line, which no summary line is), the two-pass
summary pass (the same) and the PDML run (a shown tree in one pass; the report follows
``</pdml>``). The expert tap needs no tree, and adds none to a pass that has none: each pass is
the one its mode names. :func:`outputs` runs an input once a process; the expert reports stay
for :func:`expert_report`, the outputs until test_golden.py takes them (both test files are in
the xdist group "golden", so one worker runs them)."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import pytest

import tshark_util as tu

REPO = Path(__file__).resolve().parents[1]
GOLDEN = REPO / "tests" / "dissector" / "golden"
INPUTS = GOLDEN / "inputs"
MANIFEST = INPUTS / "manifest.json"
#: the golden files of the tshark that runs (none: test_golden.py skips, and keeps no outputs here)
VERSION_DIR = GOLDEN / f"tshark-{tu.TSHARK_VERSION[0]}.{tu.TSHARK_VERSION[1]}"
UPDATE = os.environ.get("SHAREDLINK_GOLDEN_UPDATE") == "1"
SERIAL_LUA = REPO / "dissector" / "serial.lua"
_PDML_HEAD = re.compile(r"^<pdml .*>$", re.M)
_FIRST_EMPTY_LINE = re.compile(r"^$", re.M)
_PDML_END = "</pdml>\n"

#: mode -> the expert report of its run (the tap's name for test_experts: alone, two passes, shown)
EXPERT_OF = {"summary": "expert", "summary-2": "expert-2", "pdml": "expert-shown"}

_fields: list[str] | None = None
_outputs: dict[str, dict[str, str]] = {}
_reports: dict[str, dict[str, str]] = {}


def sharedlink_fields() -> list[str]:
    """Every ``sharedlink.*`` field tshark lists (``-G fields``), once a process."""
    global _fields
    if _fields is None:
        tu.ensure_loaded()
        out = subprocess.run([*tu.TSHARK_CMD, "-G", "fields", "-X", f"lua_script:{tu.DISSECTOR}"],
                             capture_output=True, text=True, env=tu._clean_env(), timeout=120).stdout
        names = [cols[2] for cols in (line.split("\t") for line in out.splitlines())
                 if len(cols) > 3 and cols[0] == "F" and cols[2].startswith("sharedlink.")]
        assert "sharedlink.var.name" in names, "tshark -G fields did not list the dissector's fields"
        _fields = sorted(names)
    return _fields


def modes(fields: list[str]) -> dict[str, tuple[bool, list[str]]]:
    """mode -> (two passes, tshark arguments); the expert report's mode is made from EXPERT_OF's."""
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
    }


def inputs() -> dict[str, dict]:
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


def _split(mode: str, out: str) -> tuple[str, str]:
    """A run's output and the expert report after it."""
    if mode == "pdml":
        cut = out.index(_PDML_END) + len(_PDML_END)
    else:
        cut = _FIRST_EMPTY_LINE.search(out).start()  # type: ignore[union-attr]  (the report's at least)
    return out[:cut], out[cut:]


def _run(entry: dict) -> tuple[dict[str, str], dict[str, str]]:
    extra = ["-X", f"lua_script:{SERIAL_LUA}"] if entry["serial"] else []
    outs: dict[str, str] = {}
    reports: dict[str, str] = {}
    with pytest.MonkeyPatch.context() as m:
        m.setenv("TZ", "UTC")   # (the golden files' times)
        for mode, (two_pass, args) in modes(sharedlink_fields()).items():
            tap = ["-z", "expert"] if mode in EXPERT_OF else []
            out = tu.tshark(entry["path"], [*extra, *args, *tap], prefs=entry["prefs"], two_pass=two_pass).stdout
            if tap:
                out, reports[EXPERT_OF[mode]] = _split(mode, out)
            if mode == "pdml":   # the header names the file and the time of the run
                out = _PDML_HEAD.sub("<pdml>", out)
            outs[mode] = out
    outs["expert"] = reports["expert"]
    return outs, reports


def outputs(name: str, entry: dict) -> dict[str, str]:
    """The input's output in each mode, the summary pass's expert report as mode "expert" (made
    now, or taken from the run an earlier :func:`expert_report` made)."""
    if name not in _outputs:
        _outputs[name], _reports[name] = _run(entry)
    return _outputs.pop(name)


def expert_report(name: str, entry: dict, which: str) -> str:
    """``-z expert``'s report of the input's golden run: "expert" (the summary pass), "expert-2"
    (two passes) or "expert-shown" (a shown tree in one pass: the PDML run)."""
    if name not in _reports:
        outs, _reports[name] = _run(entry)
        if UPDATE or VERSION_DIR.is_dir():   # (for test_golden.py to take)
            _outputs[name] = outs
    return _reports[name][which]
