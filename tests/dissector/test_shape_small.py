"""Issue 27's shape for p2os.lua, blackboard.lua and serial.lua, and the dissection modules they
run on their first packet (robots/*_dissect.lua; sharedlink.lua has its own check): no function over 80 lines, each main chunk declaring at most 150 locals as
``luac5.4 -l -l`` counts them (do blocks included), luacheck clean with the per-file entries of
.luacheckrc (cyclomatic complexity at most 20; no global set or read but Wireshark's), and no
Wireshark internals (metatables, rawget, the debug library, the collector): of the debug library
only ``debug.getinfo(1, "S").source``, the folder the file was loaded from, where p2os.lua and
serial.lua find robots/p2os_rules.lua (as sharedlink.lua finds its modules)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
# and the dissection modules they run on their first packet
FILES = ["p2os.lua", "blackboard.lua", "serial.lua", "robots/p2os_dissect.lua", "robots/blackboard_dissect.lua",
         "robots/serial_dissect.lua"]
MAX_LINES, MAX_LOCALS, MAX_COMPLEXITY = 80, 150, 20
INTERNALS = re.compile(r"__getters|__setters|\brawget\b|\brawset\b|\bgetmetatable\b|\bsetmetatable\b"
                       r'|\bdebug\.(?!getinfo\(1, "S"\)\.source\b)|\bcollectgarbage\b')

needs_luac = pytest.mark.skipif(shutil.which("luac5.4") is None, reason="luac5.4 not installed")
needs_luacheck = pytest.mark.skipif(shutil.which("luacheck") is None, reason="luacheck not installed")


def listing(name: str) -> str:
    p = subprocess.run(["luac5.4", "-p", "-l", "-l", str(REPO / "dissector" / name)],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    return p.stdout


def function_lengths(text: str) -> list[tuple[int, int]]:
    """(lines, first line) of every function but the main chunk."""
    spans = re.findall(r"^function <[^>]*:(\d+),(\d+)>", text, re.M)
    return sorted(((int(b) - int(a) + 1, int(a)) for a, b in spans), reverse=True)


def main_locals(text: str) -> int:
    m = re.search(r"^main <.*?^locals \((\d+)\)", text, re.M | re.S)
    assert m, "no main chunk in the listing"
    return int(m.group(1))


@needs_luac
@pytest.mark.parametrize("name", FILES)
def test_no_function_over_80_lines(name: str):
    lengths = function_lengths(listing(name))
    assert lengths, name
    over = [f"line {first}: {n} lines" for n, first in lengths if n > MAX_LINES]
    assert not over, f"{name}: functions over {MAX_LINES} lines: {over}"


@needs_luac
@pytest.mark.parametrize("name", FILES)
def test_main_chunk_locals(name: str):
    n = main_locals(listing(name))
    assert 0 < n <= MAX_LOCALS, f"{name}: the main chunk declares {n} locals"


@needs_luacheck
def test_luacheck_with_the_per_file_complexity_limit():
    cfg = (REPO / ".luacheckrc").read_text()
    for name in FILES:
        assert re.search(rf'files\["dissector/{re.escape(name)}"\]\s*=\s*{{\s*max_cyclomatic_complexity\s*=\s*'
                         rf"{MAX_COMPLEXITY}\s*}}", cfg), f".luacheckrc has no complexity entry for {name}"
    p = subprocess.run(["luacheck", "--no-color", "--codes", *(f"dissector/{n}" for n in FILES)],
                       capture_output=True, text=True, cwd=REPO, timeout=120)
    assert p.returncode == 0, p.stdout + p.stderr


@needs_luacheck
def test_the_complexity_limit_bites(tmp_path: Path):
    """A function with 21 branches in one of the files fails luacheck with the repo's config."""
    body = "\n".join(f"    if x == {i} then return {i} end" for i in range(21))
    (tmp_path / "dissector").mkdir()
    (tmp_path / "dissector" / "p2os.lua").write_text(f"local function f(x)\n{body}\nend\nreturn f\n")
    shutil.copy(REPO / ".luacheckrc", tmp_path / ".luacheckrc")
    p = subprocess.run(["luacheck", "--no-color", "dissector/p2os.lua"], capture_output=True, text=True,
                       cwd=tmp_path, timeout=60)
    assert p.returncode != 0 and "cyclomatic complexity" in p.stdout, p.stdout


@pytest.mark.parametrize("name", FILES)
def test_documented_api_only(name: str):
    code = "\n".join(ln.split("--", 1)[0] for ln in (REPO / "dissector" / name).read_text().splitlines())
    found = sorted(set(INTERNALS.findall(code)))
    assert not found, f"{name} uses {found}"
