"""Wireshark's internals only through sharedlink.lua's adapter (issue 27): every trick that reaches
past the documented wslua API sits in the ``wsapi`` module (dissector/sharedlink/wsapi.lua), the
collector is left alone, and every environment switch is documented in docs/architecture.md."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
LUA = REPO / "dissector" / "sharedlink.lua"
WSAPI = REPO / "dissector" / "sharedlink" / "wsapi.lua"
OTHERS = [LUA, REPO / "dissector" / "sharedlink_stats.lua",
          *sorted(p for p in WSAPI.parent.glob("*.lua") if p != WSAPI)]
ARCH = REPO / "docs" / "architecture.md"
INTERNALS = re.compile(r"__getters|rawget\(\s*(Tvb|TreeItem|Pinfo)|TreeItem\.\w+|Tvb\.\w+|tostring\(t(ree)?\)|os\.getenv")


def _code(text: str) -> list[tuple[int, str]]:
    return [(i, line.split("--", 1)[0]) for i, line in enumerate(text.splitlines(), 1)]


def test_internals_only_in_the_adapter() -> None:
    outside = [(p.name, i, c.strip()) for p in OTHERS for i, c in _code(p.read_text()) if INTERNALS.search(c)]
    assert not outside, f"Wireshark internals outside wsapi: {outside}"
    assert INTERNALS.search(WSAPI.read_text()), "the adapter holds the tricks"


def test_no_collector_tuning() -> None:
    assert not any("collectgarbage" in c for p in [*OTHERS, WSAPI] for _, c in _code(p.read_text()))


def test_environment_switches_documented() -> None:
    code = "\n".join(c for p in [*OTHERS, WSAPI] for _, c in _code(p.read_text()))
    switches = set(re.findall(r"SHAREDLINK_\w+", code)) | {"SHAREDLINK_" + n for n in re.findall(r'env\("(\w+)"\)', code)}
    switches.discard("SHAREDLINK_")
    doc = ARCH.read_text()
    missing = sorted(s for s in switches if s not in doc)
    assert len(switches) == 3 and not missing, f"switches {sorted(switches)}; not in docs/architecture.md: {missing}"


def _protocols(args: list[str], env: dict[str, str]) -> str:
    import subprocess

    import tshark_util as tu

    r = subprocess.run([*tu.TSHARK_CMD, "-G", "protocols", *args], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    tu.check_stderr(r.stderr)
    return r.stdout


def _sharedlink_count(out: str) -> int:
    return sum(1 for line in out.splitlines() if line.split("\t")[2:3] == ["sharedlink"])


def test_loaded_twice_registers_once() -> None:
    """The load guard: the file named twice (as when installed and named with -X lua_script:)."""
    import tshark_util as tu

    out = _protocols(["-X", f"lua_script:{LUA}", "-X", f"lua_script:{LUA}"], tu._clean_env())
    assert _sharedlink_count(out) == 1


def test_plugin_folder_layout(tmp_path: Path) -> None:
    """As make install leaves it: sharedlink.lua and its module folder in the personal plugin
    folder, where Wireshark also runs each module as a plugin of its own (they must do nothing)."""
    import shutil
    import subprocess

    import tshark_util as tu

    env = dict(tu._clean_env(), HOME=str(tmp_path), XDG_CONFIG_HOME=str(tmp_path / ".config"))
    env.pop("WIRESHARKCONFIGDIR", None)
    folders = subprocess.run([*tu.TSHARK_CMD, "-G", "folders"], capture_output=True, text=True, env=env).stdout
    plugins = Path(re.search(r"^Personal Lua Plugins:\s*(.+)$", folders, re.M).group(1).strip())
    plugins.mkdir(parents=True, exist_ok=True)
    shutil.copy(LUA, plugins / LUA.name)
    shutil.copytree(WSAPI.parent, plugins / WSAPI.parent.name)
    out = _protocols([], env)
    assert _sharedlink_count(out) == 1
