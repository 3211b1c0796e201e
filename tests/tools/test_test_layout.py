"""The test suite's own layout (docs/testing.md): no test file imports another test file; what
several test files share lives in the helper modules (``tests/tshark_util.py``, ``sl_*.py``,
``analysis/core_streams.py``, ``fuzz/scaling*.py``, ``fuzz/fuzz_*.py``) and fixtures in
``tests/conftest.py``."""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]


def imported_modules(path: Path) -> set[str]:
    """The top-level module names a file imports, deferred imports included."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out


def test_no_test_file_imports_another() -> None:
    test_modules = {p.stem for p in TESTS.rglob("test_*.py")}
    assert "test_agreement" in test_modules
    bad = sorted(f"{p.relative_to(TESTS)} imports {m}" for p in TESTS.rglob("*.py")
                 for m in imported_modules(p) & test_modules)
    assert not bad, "a test file is imported (move what is shared to a helper module):\n" + "\n".join(bad)
