"""Golden outputs of p2os.lua, blackboard.lua and serial.lua: every input in golden_small/ (generated
sessions, hand-made edge cases, editcap mutations; made by golden_small/make_inputs.py) through
tshark -V, -2 -V and -T pdml with those three dissectors loaded (not sharedlink.lua, so its own
changes do not move these files), compared with golden_small/golden.json.xz.

Recorded on Wireshark 4.0 (the framework's own lines differ between releases): skipped on others.
A change that is meant to move the output rewrites the file with SHAREDLINK_GOLDEN_UPDATE=1 and
says in its commit which outputs moved and why."""

from __future__ import annotations

import json
import lzma
import os
import re
import subprocess
from pathlib import Path

import pytest

import tshark_util as tu

HERE = Path(__file__).resolve().parent / "golden_small"
REPO = HERE.parents[2]
SCRIPTS = [REPO / "dissector" / n for n in ("p2os.lua", "blackboard.lua", "serial.lua")]
GOLDEN = HERE / "golden.json.xz"
RECORDED_ON = (4, 0)
INPUTS = sorted(p.name for p in HERE.iterdir() if p.suffix in (".pcap", ".pcapng"))
MODES = {"V": ["-V"], "2V": ["-2", "-V"], "pdml": ["-T", "pdml"]}
PREFS = {"bb-edge.pcap": ["-o", "blackboard.udp_port:7100"]}
UPDATE = os.environ.get("SHAREDLINK_GOLDEN_UPDATE") == "1"


def run(name: str, mode: str) -> str:
    cmd = [*tu.TSHARK_CMD, "-n"] + [a for s in SCRIPTS for a in ("-X", f"lua_script:{s}")]
    cmd += ["-r", str(HERE / name), *PREFS.get(name, []), *MODES[mode]]
    env = dict(tu._clean_env(), TZ="UTC")
    p = subprocess.run(cmd, capture_output=True, env=env, timeout=120, encoding="utf-8", errors="replace")
    assert p.returncode == 0, p.stderr
    tu.check_stderr(p.stderr)
    assert "_ws.lua.error" not in p.stdout and "Lua Error" not in p.stdout, name
    # the PDML header names the time of the run
    return "\n".join(ln for ln in p.stdout.splitlines() if not ln.startswith("<pdml "))


def load() -> dict[str, str]:
    if not GOLDEN.exists():
        return {}
    with lzma.open(GOLDEN, "rt", encoding="utf-8") as f:
        return json.load(f)


def test_the_three_dissectors_load():
    cmd = [*tu.TSHARK_CMD, "-G", "protocols"] + [a for s in SCRIPTS for a in ("-X", f"lua_script:{s}")]
    p = subprocess.run(cmd, capture_output=True, text=True, env=tu._clean_env(), timeout=60)
    tu.check_stderr(p.stderr)
    names = {ln.split("\t")[2] for ln in p.stdout.splitlines() if ln.count("\t") >= 2}
    assert {"p2os", "blackboard", "slserial"} <= names


@pytest.mark.skipif(tu.TSHARK_VERSION[:2] != RECORDED_ON, reason="golden outputs recorded on Wireshark 4.0")
@pytest.mark.skipif(UPDATE, reason="rewriting the golden file (test_update_golden)")
@pytest.mark.parametrize("name", INPUTS)
def test_output_unchanged(name: str):
    golden = load()
    for mode in MODES:
        key = f"{name} {mode}"
        got = run(name, mode)
        want = golden.get(key)
        assert want is not None, f"no golden output for {key}: SHAREDLINK_GOLDEN_UPDATE=1 records it"
        if got != want:
            g, w = got.splitlines(), want.splitlines()
            i = next((k for k in range(min(len(g), len(w))) if g[k] != w[k]), min(len(g), len(w)))
            ctx = "\n".join(f"  want: {a!r}\n  got:  {b!r}" for a, b in zip(w[i:i + 5], g[i:i + 5]))
            pytest.fail(f"{key}: output differs from line {i + 1} (lines {len(w)} -> {len(g)}):\n{ctx}")


@pytest.mark.skipif(not UPDATE, reason="SHAREDLINK_GOLDEN_UPDATE=1 rewrites the golden file")
def test_update_golden():
    out = {f"{n} {m}": run(n, m) for n in INPUTS for m in MODES}
    with lzma.open(GOLDEN, "wt", encoding="utf-8", preset=9 | lzma.PRESET_EXTREME) as f:
        json.dump(out, f, indent=0, sort_keys=True)


EXPERT_INPUTS = ["bb-edge.pcap", "p2os-edge.pcap", "serial-edge.pcapng", "bb-serial.pcapng"]


def _expert_counts(name: str, *extra: str) -> dict[str, int]:
    cmd = [*tu.TSHARK_CMD, "-n"] + [a for s in SCRIPTS for a in ("-X", f"lua_script:{s}")]
    cmd += ["-r", str(HERE / name), *PREFS.get(name, []), "-q", "-z", "expert", *extra]
    p = subprocess.run(cmd, capture_output=True, text=True, env=tu._clean_env(), timeout=120)
    assert p.returncode == 0, p.stderr
    tu.check_stderr(p.stderr)
    return {m.group(1): int(m.group(2)) for m in re.finditer(r"^(Errors|Warns|Notes|Chats) \((\d+)\)", p.stdout, re.M)}


@pytest.mark.parametrize("name", EXPERT_INPUTS)
def test_expert_infos_without_a_filter(name: str):
    """Issue 27: `-z expert` alone counts what it counts with a display filter on the protocols
    (expert infos are there on every pass, whatever tree is built)."""
    alone = _expert_counts(name)
    assert alone, f"{name}: no expert infos at all"
    assert alone == _expert_counts(name, "-Y", "p2os or blackboard or slserial")
