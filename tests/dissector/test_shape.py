"""The shape limits of issue 27 for the SharedLink dissector files: no function over 80 lines, a
main chunk declaring at most 150 locals (as ``luac5.4 -l -l`` counts them, do blocks included),
luacheck clean with cyclomatic complexity at most 20; and issue 39's: no function over 8
parameters (what a frame's functions share goes in the frame record, parse.lua's F).

The SharedLink dissector (sharedlink.lua and its modules in dissector/sharedlink/) meets them: DEBT,
the list of what a file owes, is empty and may only shrink (the test fails when a listed item
grows, when a new function breaks a limit, or when a debt is paid but still listed).
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
# the entry, the stats tap and every module of the entry's folder
FILES = ["sharedlink.lua", "sharedlink_stats.lua",
         *sorted(f"sharedlink/{p.name}" for p in (REPO / "dissector" / "sharedlink").glob("*.lua"))]
MAX_LINES, MAX_LOCALS, MAX_COMPLEXITY, MAX_PARAMS = 80, 150, 20, 8
# (file, what) -> the size today: function lines ("lines NAME"), main-chunk locals ("locals"),
# luacheck complexity ("complexity NAME"), parameters ("params NAME")
DEBT: dict[tuple[str, str], int] = {}
_FUNC = re.compile(r"^(?:main|function) <[^:]+:(\d+),(\d+)>")
_LOCALS = re.compile(r"^locals \((\d+)\)")
_PARAMS = re.compile(r"^(\d+)\+? params")
_NAME = re.compile(r"function\s+([\w.:]+)\s*\(|(\w+)\s*=\s*function\s*\(|^\s*function\s*\(")

pytestmark = pytest.mark.skipif(not shutil.which("luac5.4"), reason="luac5.4 not installed")


def _measure(name: str) -> dict[str, int]:
    path = REPO / "dissector" / name
    src = path.read_text().splitlines()
    out = subprocess.run(["luac5.4", "-l", "-l", "-p", str(path)], capture_output=True, text=True, check=True).stdout
    sizes: dict[str, int] = {}
    main_seen = False
    fname = ""
    for line in out.splitlines():
        m = _PARAMS.match(line)
        if m and fname:
            key = f"params {fname}"
            sizes[key] = max(sizes.get(key, 0), int(m.group(1)))
            fname = ""
            continue
        m = _FUNC.match(line)
        if m:
            start, end = int(m.group(1)), int(m.group(2))
            if start == 0:
                main_seen = True
                fname = ""
                continue
            main_seen = False
            n = _NAME.search(src[start - 1])
            fname = (n.group(1) or n.group(2)) if n and (n.group(1) or n.group(2)) else f"anonymous@{start}"
            fname = fname.split(".")[-1].split(":")[-1]
            key = f"lines {fname}"
            sizes[key] = max(sizes.get(key, 0), end - start + 1)
            continue
        m = _LOCALS.match(line)
        if m and main_seen:
            sizes["locals"] = int(m.group(1))
            main_seen = False
    cc = subprocess.run(["luacheck", "--no-color", "--no-config", "--std", "lua52+lua54", "--globals", "_", "--no-global",
                         "--no-unused", "--no-redefined", "--max-line-length", "200",
                         "--max-cyclomatic-complexity", str(MAX_COMPLEXITY), str(path)],
                        capture_output=True, text=True).stdout
    for m in re.finditer(r"cyclomatic complexity of (main chunk|function|method)\s*(\S*) is too high \((\d+)", cc):
        fname = (m.group(2) or m.group(1)).strip("'").split(".")[-1].split(":")[-1]
        key = f"complexity {fname}"
        sizes[key] = max(sizes.get(key, 0), int(m.group(3)))
    return sizes


def _over(what: str, size: int) -> bool:
    if what == "locals":
        return size > MAX_LOCALS
    if what.startswith("lines "):
        return size > MAX_LINES
    if what.startswith("params "):
        return size > MAX_PARAMS
    return True  # complexity entries are reported only past the limit


@pytest.mark.parametrize("name", FILES)
def test_shape_limits(name: str) -> None:
    sizes = _measure(name)
    assert "locals" in sizes, "luac5.4 -l -l gave no main chunk locals"
    problems = []
    for what, size in sorted(sizes.items()):
        if not _over(what, size):
            continue
        owed = DEBT.get((name, what))
        if owed is None:
            problems.append(f"{what} = {size}: over the limit")
        elif size > owed:
            problems.append(f"{what} = {size}: grew past its listed debt {owed}")
    paid = [what for (f, what), _ in DEBT.items() if f == name and not _over(what, sizes.get(what, 0))]
    problems += [f"{what}: within the limit now, remove it from DEBT" for what in paid]
    assert not problems, f"{name}:\n" + "\n".join(problems)
