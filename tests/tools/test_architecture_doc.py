"""docs/architecture.md stays true to the tree: every file path and every function, class or
variable name it writes in backquotes exists, checked against the tree as it is when the test
runs (Python by its syntax tree, Lua by its definitions).

What counts: a span with a ``/`` or a file suffix is a path (from the repository, ``dissector/``,
``pytools/sharedlink/``, ``tests/`` or ``docs/``; a bare file name anywhere in the tree; ``*`` a
glob that must match; ``FILE::test`` a test defined in FILE). A span that is a name (dotted, a
call's arguments or an index dropped) is looked up: a Python module path (``analysis.decode``,
``codec``) and then a name defined at its top level and the members of that class; a Python
class or function and its members; else a Lua name (its last part defined in ``dissector/``: a
function, a local, a table key or field). Anything else in backquotes (options, field
abbreviations, frame text, shell commands) is not a name and is not checked. A thing that is
gone is written without backquotes (the history of the speed devices names some).
"""

from __future__ import annotations

import ast
import fnmatch
import re
from functools import lru_cache
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "architecture.md"
PACKAGE = REPO / "pytools" / "sharedlink"
PATH_ROOTS = (REPO, REPO / "dissector", REPO / "pytools", PACKAGE, REPO / "tests", REPO / "docs")
SKIP_DIRS = {".git", ".venv", "out", "__pycache__", ".hypothesis", ".pytest_cache", ".ruff_cache"}
#: names from outside the tree the doc names: Lua, Python and Wireshark APIs, the protocol's letters
EXTERNAL = {
    "tonumber", "tostring", "load", "floor", "string.byte", "string.find", "debug.getinfo", "ByteArray", "Proto",
    "TreeItem.add", "Tvb.raw", "pinfo.number", "pinfo.visited", "pinfo.port_type", "obj.name", "__index",
    "__getters", "visited", "zlib.adler32", "itertools.compress", "operator", "findall", "ValueError",
    "N0", "N", "T", "C",
}
#: files of other projects the doc points at as models (dpkt's dpkt.py, twine's exceptions.py)
EXTERNAL_FILES = {"dpkt.py", "exceptions.py"}
_NAME = re.compile(r"[A-Za-z_*][\w*]*(?:\.[A-Za-z_*][\w*]*)*")
_SUFFIX = re.compile(r"\.(py|lua|md|json|txt|toml|cfg|sh)$")


def spans(text: str) -> list[str]:
    """The backquoted spans of a Markdown text, outside fenced blocks."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    return re.findall(r"`([^`\n]+)`", text)


# -- the tree -------------------------------------------------------------------------------------


def _files() -> list[Path]:
    out = []
    for p in REPO.rglob("*"):
        if p.is_file() and not SKIP_DIRS.intersection(p.relative_to(REPO).parts):
            out.append(p)
    return out


@lru_cache(maxsize=1)
def tree_files() -> tuple[Path, ...]:
    return tuple(_files())


def path_exists(span: str) -> bool:
    rel = span.rstrip("/")
    for root in PATH_ROOTS:
        if any(root.glob(rel)) if "*" in rel else (root / rel).exists():
            return True
    if "/" not in rel:
        return any(fnmatch.fnmatch(p.name, rel) for p in tree_files())
    # package data: a path setup.py maps (sharedlink/dissector, sharedlink/extcap_launcher)
    return rel in (REPO / "setup.py").read_text()


class PyIndex:
    """Modules, their top-level names and each class's members, from the syntax trees."""

    def __init__(self) -> None:
        self.modules: dict[str, set[str]] = {}  # dotted path under sharedlink -> top-level names
        self.classes: dict[str, set[str]] = {}  # class name -> members (all classes of that name)
        self.bases: dict[str, set[str]] = {}
        self.functions: set[str] = set()
        self.top: set[str] = set()  # every module's top-level names
        for path in PACKAGE.rglob("*.py"):
            parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            tree = ast.parse(path.read_text(), str(path))
            self.modules[".".join(parts)] = self._top(tree)
            self.top |= self.modules[".".join(parts)]
            for node in ast.walk(tree):
                if isinstance(node, ast.ClassDef):
                    self.classes.setdefault(node.name, set()).update(self._members(node))
                    self.bases.setdefault(node.name, set()).update(b.id for b in node.bases if isinstance(b, ast.Name))
                elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    self.functions.add(node.name)
        for parts in [m.split(".") for m in list(self.modules) if m]:  # a package's modules are its names
            self.modules.setdefault(".".join(parts[:-1]), set()).add(parts[-1])

    @staticmethod
    def _targets(node: ast.AST) -> list[str]:
        if isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            return [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            return [node.name]
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            return [(a.asname or a.name).split(".")[0] for a in node.names]
        return []

    def _top(self, tree: ast.Module) -> set[str]:
        names: set[str] = set()
        for node in tree.body:
            for sub in [node, *(getattr(node, "body", []) if isinstance(node, (ast.If, ast.Try)) else [])]:
                names.update(self._targets(sub))
        return names

    def _members(self, cls: ast.ClassDef) -> set[str]:
        names: set[str] = set()
        for node in cls.body:
            names.update(self._targets(node))
        for node in ast.walk(cls):  # self.x = ... in its methods
            if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                if isinstance(node.value, ast.Name) and node.value.id == "self":
                    names.add(node.attr)
        return names

    def members(self, cls: str, seen: frozenset[str] = frozenset()) -> set[str]:
        out = set(self.classes.get(cls, ()))
        for base in self.bases.get(cls, ()):
            if base not in seen:
                out |= self.members(base, seen | {cls})
        return out

    def module_of(self, parts: list[str]) -> tuple[str, int] | None:
        """The longest leading run of ``parts`` naming a module (from the package root, or the
        module's own trailing path: ``codec``, ``decode``), and how many parts it took."""
        if parts and parts[0] == "sharedlink":
            found = self.module_of(parts[1:]) if len(parts) > 1 else None
            return (found[0], found[1] + 1) if found else ("", 1)
        for k in range(len(parts), 0, -1):
            want = ".".join(parts[:k])
            hits = [m for m in self.modules if m == want or m.endswith("." + want)]
            if hits:
                return sorted(hits, key=len)[0], k
        return None

    def resolve(self, parts: list[str]) -> bool | None:
        """True/False when ``parts`` start with a Python module or class or function name; None
        when Python does not know the first part."""
        found = self.module_of(parts)
        if found is not None:
            mod, k = found
            rest = parts[k:]
            if not rest:
                return True
            if not _match(rest[0], self.modules[mod]):
                return False
            return all(_match(p, self.members(rest[0])) for p in rest[1:]) if rest[0] in self.classes else len(rest) == 1
        if parts[0] in self.classes:
            return all(_match(p, self.members(parts[0])) for p in parts[1:2]) and len(parts) <= 2
        if len(parts) == 1 and (_match(parts[0], self.functions) or _match(parts[0], self.top)):
            return True
        return None


def _match(pattern: str, names: set[str]) -> bool:
    return any(fnmatch.fnmatchcase(n, pattern) for n in names) if "*" in pattern else pattern in names


@lru_cache(maxsize=1)
def lua_names() -> frozenset[str]:
    """Every name the Lua files define: functions, locals, assigned names, fields and keys."""
    names: set[str] = set()
    for path in (REPO / "dissector").rglob("*.lua"):
        text = re.sub(r"--\[(=*)\[.*?\]\1\]|--[^\n]*", "", path.read_text(encoding="utf-8", errors="replace"), flags=re.S)
        names.update(re.findall(r"\bfunction\s+(?:[\w.]+[.:])?(\w+)", text))
        for group in re.findall(r"\blocal\s+(?!function)([\w\s,]+?)\s*(?:=|\n|$)", text):
            names.update(n for n in re.split(r"[\s,]+", group) if n)
        names.update(re.findall(r"(?:^|[\s{,;(.])([A-Za-z_]\w*)\s*=(?!=)", text, flags=re.M))
        for targets in re.findall(r"^\s*((?:local\s+)?[\w.]+(?:\s*,\s*[\w.]+)+)\s*=(?!=)", text, flags=re.M):
            names.update(t.split(".")[-1] for t in re.split(r"[\s,]+", targets.replace("local ", "")) if t)
        names.update(re.findall(r"\[\s*\"(\w+)\"\s*\]\s*=", text))
    return frozenset(names)


@lru_cache(maxsize=1)
def py_index() -> PyIndex:
    return PyIndex()


def defines_test(node_id: str) -> bool:
    """``FILE::test`` (``*`` allowed in the test's name): FILE exists and defines the test."""
    file, _, name = node_id.partition("::")
    paths = [p for root in PATH_ROOTS for p in ([root / file] if "/" in file else root.rglob(file)) if p.is_file()]
    return any(_match(name, {n.name for n in ast.walk(ast.parse(p.read_text())) if isinstance(n, ast.FunctionDef)})
               for p in paths)


def name_exists(name: str) -> bool:
    if name in EXTERNAL:
        return True
    parts = name.split(".")
    python = py_index().resolve(parts)
    if python is not None:
        return python
    return _match(parts[-1], set(lua_names()))


def problem(span: str) -> str | None:
    """Why the span names something the tree does not have (None: it does, or it is no name)."""
    s = span.strip()
    if "::" in s and _SUFFIX.search(s.split("::")[0]):
        return None if defines_test(s) else "no such test"
    if " " in s or s.startswith(("-", ".", "%")) or "=" in s.split("(")[0] or '"' in s:
        return None
    if s in EXTERNAL_FILES:
        return None
    if "/" in s or _SUFFIX.search(s):
        return None if path_exists(s) else "no such file"
    m = _NAME.fullmatch(re.sub(r"\(.*\)$|\[.*\]$", "", s))
    if not m or s.endswith("."):
        return None
    return None if name_exists(m.group(0)) else "no such name"


def test_every_path_and_name_the_architecture_doc_writes_exists() -> None:
    bad = sorted({f"`{s}`: {why}" for s in spans(DOC.read_text()) if (why := problem(s))})
    assert not bad, "docs/architecture.md names what the tree does not have:\n" + "\n".join(bad)


def test_the_checker_finds_what_is_missing() -> None:
    """The checker is no test that cannot fail: made-up names and paths are found missing, real
    ones of each kind are found."""
    for real in ("analysis/malformed.py", "dissector/*.lua", "tshark_util.py", "analysis.decode.Decoder",
                 "protocols.codec.parse_frame", "LinkState.apply", "Decoder.capture(counts=True)", "get_dir",
                 "P.filled", "parse_*", "tests/tools/test_replay.py::test_topspeed_tier_and_reference_path_agree"):
        assert problem(real) is None, real
    for made_up in ("analysis/nothing.py", "nothing_here.lua", "analysis.decode.NoSuchClass", "LinkState.no_such",
                    "protocols.codec.no_such_function", "no_such_lua_function", "sh.no_such_field",
                    "tests/tools/test_replay.py::test_no_such_test"):
        assert problem(made_up) is not None, made_up
