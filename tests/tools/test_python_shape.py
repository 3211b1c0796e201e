"""The shape limits of issue 39 for the Python package, as tests/dissector/test_shape.py sets them
for the SharedLink dissector: no file over 800 lines, no function over 80 lines, cyclomatic
complexity at most 15 a function.

A function's lines run from its ``def`` to its last line (a nested function counts in its
parent's lines too); its complexity is McCabe's over its statements, as mccabe and ruff's C901
count it: 1, plus 1 for each ``if``/``elif``, ``for``, ``while``, ``except`` handler and ``case``;
a nested function or class is its own unit (mccabe and ruff add it to its parent's).

Every file meets them today: DEBT is empty, and the test fails on any file or function over a
limit. DEBT stays for a debt that must be taken on knowingly: a listed item may only shrink (the
test fails when it grows, or when it is paid but still listed: then delete its line); the
decoding core (``analysis/core/``) and the modules issue 39 rewrote (``STRICT``) may never be in it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import sharedlink

PACKAGE = Path(sharedlink.__file__).resolve().parent
MAX_FILE_LINES, MAX_LINES, MAX_COMPLEXITY = 800, 80, 15
#: files (relative to the package) that may owe nothing
STRICT = ("analysis/core/", "analysis/decode.py", "analysis/changes.py", "analysis/lists.py",
          "capture/pcap_blocks.py", "capture/pcapio.py", "capture/serial_import.py", "protocols/codec.py",
          "commands/diff.py", "commands/watch.py", "analysis/compiled_blocks.py", "analysis/transform.py",
          "__init__.py")
#: (file, what) -> the size today: "file" (its lines), "lines NAME", "complexity NAME" (NAME:
#: Class.method, or outer.inner for a nested function)
DEBT: dict[tuple[str, str], int] = {}

_BRANCHES = (ast.If, ast.For, ast.AsyncFor, ast.While, ast.ExceptHandler, ast.match_case)
_UNITS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)


def complexity(fn: ast.AST) -> int:
    """McCabe's number of a function, its nested functions and classes left out (see the module doc)."""
    n = 1
    todo = list(ast.iter_child_nodes(fn))
    while todo:
        node = todo.pop()
        if isinstance(node, _UNITS):
            continue
        if isinstance(node, _BRANCHES):
            n += 1
        todo.extend(ast.iter_child_nodes(node))
    return n


def measure(path: Path) -> dict[str, int]:
    """What ``path`` is over the limits: ``{"file": lines, "lines NAME": n, "complexity NAME": n}``."""
    text = path.read_text()
    over: dict[str, int] = {}
    lines = len(text.splitlines())
    if lines > MAX_FILE_LINES:
        over["file"] = lines
    tree = ast.parse(text, str(path))

    def walk(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                size = child.end_lineno - child.lineno + 1  # type: ignore[operator]
                if size > MAX_LINES:
                    over[f"lines {name}"] = size
                cc = complexity(child)
                if cc > MAX_COMPLEXITY:
                    over[f"complexity {name}"] = cc
                walk(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                walk(child, prefix + child.name + ".")
            else:
                walk(child, prefix)

    walk(tree, "")
    return over


def _all() -> dict[tuple[str, str], int]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).as_posix()
        for what, n in measure(path).items():
            out[(rel, what)] = n
    return out


def test_complexity_counts_as_documented():
    src = ("def f(a, b):\n    if a and b:\n        return [x for x in a if x]\n    elif b:\n        pass\n"
           "    while b:\n        try:\n            b -= 1\n        except ValueError:\n            pass\n"
           "    def g():\n        if a:\n            pass\n    return 1 if a else 2\n")
    fn = ast.parse(src).body[0]
    assert complexity(fn) == 1 + 2 + 1 + 1  # if, elif, while, except (g is its own: 2)
    assert complexity(fn.body[-2]) == 2


def test_no_file_or_function_over_the_limits_but_the_listed_debts():
    now = _all()
    new = {k: v for k, v in now.items() if k not in DEBT}
    grown = {k: (DEBT[k], v) for k, v in now.items() if k in DEBT and v > DEBT[k]}
    paid = {k: v for k, v in DEBT.items() if k not in now}
    assert not new, "over the limits (file lines 800, function lines 80, complexity 15):\n" + "\n".join(
        f"{f}: {w} = {n}" for (f, w), n in sorted(new.items()))
    assert not grown, f"debts that grew (listed, now): {grown}"
    assert not paid, f"debts paid: delete them from DEBT: {sorted(paid)}"


def test_the_core_and_the_files_issue_39_changed_owe_nothing():
    owing = sorted(f"{f}: {w}" for f, w in DEBT if f.startswith(STRICT))
    assert not owing, f"STRICT files may not be in DEBT: {owing}"
    assert any((PACKAGE / "analysis" / "core").glob("*.py"))
