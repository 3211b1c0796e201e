"""Wireshark's internals only through sharedlink.lua's adapter (issue 27): every trick that reaches
past the documented wslua API sits in the ``wsapi`` block, the collector is left alone, and every
environment switch the file reads is documented in docs/architecture.md."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
LUA = REPO / "dissector" / "sharedlink.lua"
ARCH = REPO / "docs" / "architecture.md"
INTERNALS = re.compile(r"__getters|rawget\(\s*(Tvb|TreeItem|Pinfo)|TreeItem\.\w+|Tvb\.\w+|tostring\(t(ree)?\)|os\.getenv")


def _code(text: str) -> list[tuple[int, str]]:
    return [(i, line.split("--", 1)[0]) for i, line in enumerate(text.splitlines(), 1)]


def test_internals_only_in_the_adapter() -> None:
    text = LUA.read_text()
    lines = _code(text)
    start = next(i for i, c in lines if c.startswith("local wsapi = "))
    end = next(i for i, c in lines if i > start and c.startswith("end"))
    outside = [(i, c.strip()) for i, c in lines if INTERNALS.search(c) and not start <= i <= end]
    assert not outside, f"Wireshark internals outside wsapi: {outside}"


def test_no_collector_tuning() -> None:
    assert not any("collectgarbage" in c for _, c in _code(LUA.read_text()))


def test_environment_switches_documented() -> None:
    code = "\n".join(c for _, c in _code(LUA.read_text()))
    switches = set(re.findall(r"SHAREDLINK_\w+", code)) | {"SHAREDLINK_" + n for n in re.findall(r'env\("(\w+)"\)', code)}
    switches.discard("SHAREDLINK_")
    doc = ARCH.read_text()
    missing = sorted(s for s in switches if s not in doc)
    assert len(switches) == 5 and not missing, f"switches {sorted(switches)}; not in docs/architecture.md: {missing}"
