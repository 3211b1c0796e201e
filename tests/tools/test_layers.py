"""The layer rule of docs/architecture.md: a module imports only from its own or a lower layer
(and no cycles can run back up). Walks every module's imports, deferred ones included."""

from __future__ import annotations

import ast
from pathlib import Path

import sharedlink

PACKAGE = Path(sharedlink.__file__).resolve().parent

#: the layers, lowest first; a module's layer is that of its first name part under sharedlink
LAYERS = [
    {"errors", "_interrupt", "defaults", "extras", "problems"},
    {"protocols"},
    {"capture"},
    {"generators"},
    {"analysis", "present"},
    {"replay", "replay_sinks", "replay_tcp", "pacing", "extcap", "wireshark", "plugins", "scapy_layer", "fleet", "watch", "watch_json", "watch_capture", "sniffer", "robot_watch",
     "foxglove_server"},
    {"commands"},
    {"cli", "__main__"},
]


def layer_of(part: str) -> int:
    if not (PACKAGE / f"{part}.py").exists() and not (PACKAGE / part).is_dir():
        # a name of the package root: its version (no layer) or the codec it re-exports
        return 0 if part == "__version__" else layer_of("protocols")
    for i, names in enumerate(LAYERS):
        if part in names:
            return i
    raise AssertionError(f"sharedlink.{part} is in no layer: add it to LAYERS and docs/architecture.md")


def module_parts(path: Path) -> list[str]:
    rel = path.relative_to(PACKAGE).with_suffix("")
    parts = list(rel.parts)
    return parts[:-1] if parts[-1] == "__init__" else parts


def imported(path: Path) -> list[tuple[int, str]]:
    """(line, dotted name under sharedlink) of every sharedlink import in the file."""
    tree = ast.parse(path.read_text(), str(path))
    here = module_parts(path)
    package = here if path.name == "__init__.py" else here[:-1]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.startswith("sharedlink.")]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                mod = ".".join(["sharedlink", *base, *([node.module] if node.module else [])])
            else:
                mod = node.module or ""
            if mod == "sharedlink":  # from sharedlink import x: x is a module or a name of the root
                out += [(node.lineno, f"sharedlink.{a.name}") for a in node.names]
            elif mod.startswith("sharedlink."):
                out.append((node.lineno, mod))
    return out


def test_no_module_imports_from_a_higher_layer():
    bad = []
    checked = 0
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = module_parts(path)
        if not parts:  # the package root: re-exports the codec
            continue
        mine = layer_of(parts[0])
        for line, name in imported(path):
            target = name.split(".")[1]
            checked += 1
            if layer_of(target) > mine:
                bad.append(f"{path.relative_to(PACKAGE)}:{line} imports {name}")
    assert checked > 50
    assert not bad, "imports from a higher layer:\n" + "\n".join(bad)


def test_no_command_imports_another():
    commands = PACKAGE / "commands"
    names = {p.stem for p in commands.glob("*.py") if p.stem != "__init__"}
    bad = [
        f"{path.name}:{line} imports {name}"
        for path in commands.glob("*.py")
        for line, name in imported(path)
        if name.startswith("sharedlink.commands.") and name.split(".")[2] in names
    ]
    assert not bad, bad


def test_shared_constants_have_one_home():
    """NS, the SharedLink type codes and the generators' start time are defined once and
    imported elsewhere."""
    homes = {
        "NS": "capture/pcapio.py",
        "TYPE_LONG": "protocols/codec.py",
        "TYPE_DOUBLE": "protocols/codec.py",
        "TYPE_STRING": "protocols/codec.py",
        "DEFAULT_START_NS": "generators/beacon.py",
    }
    found: dict[str, list[str]] = {name: [] for name in homes}
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.parse(path.read_text(), str(path)).body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
            for t in targets:
                for name in [e.id for e in (t.elts if isinstance(t, ast.Tuple) else [t]) if isinstance(e, ast.Name)]:
                    if name in found:
                        found[name].append(str(path.relative_to(PACKAGE)))
    assert found == {name: [home] for name, home in homes.items()}
