"""`make install` / `make uninstall` against a temporary HOME, checked with the real tshark: the
plugins are listed by `tshark -G plugins` (each with its version), the extcap by `tshark -D`,
then all gone, and the coloring rules removed so that no rule names a field nobody registers."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tshark_util import REPO, TSHARK_CMD, check_stderr, env_for

pytestmark = pytest.mark.skipif(shutil.which("make") is None or TSHARK_CMD != [shutil.which("tshark") or "/usr/bin/tshark"],
                                reason="needs make and the machine's own tshark")
LUA = sorted(p.name for p in (REPO / "dissector").glob("*.lua"))
RULES = (REPO / "dissector" / "sharedlink.colorfilters").read_text()


def make(target: str, home: Path) -> str:
    r = subprocess.run(["make", "-s", target], cwd=REPO, capture_output=True, text=True, env=env_for(home), timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


def tshark(home: Path, *args: str) -> subprocess.CompletedProcess:
    r = subprocess.run([*TSHARK_CMD, *args], capture_output=True, text=True, env=env_for(home), timeout=120)
    assert r.returncode == 0, r.stderr
    check_stderr(r.stderr)
    return r


def lua_plugins(home: Path) -> dict[str, str]:
    """`tshark -G plugins`: Lua plugin file name -> version."""
    out = tshark(home, "-G", "plugins").stdout
    return {cols[0]: cols[1] for cols in (ln.split("\t") for ln in out.splitlines()) if len(cols) >= 3 and "lua" in cols[-2]}


def test_install_then_uninstall(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    theirs = "@My rule@udp.port == 9@[0,0,0][65535,65535,65535]\n"
    cf = home / ".config" / "wireshark" / "colorfilters"
    cf.parent.mkdir(parents=True)
    cf.write_text(theirs)

    make("install", home)
    plugins = lua_plugins(home)
    assert set(LUA) <= set(plugins), plugins
    # every plugin reports its version (set_plugin_info); sharedlink.lua's is added with the
    # issue 12/13 work in that file
    for name in LUA:
        if name != "sharedlink.lua" or plugins[name]:
            assert re.fullmatch(r"\d+\.\d+\.\d+", plugins[name]), (name, plugins[name])
    assert "sharedlink-serial" in tshark(home, "-D").stdout
    assert cf.read_text() == RULES + theirs
    extcap = home / ".config" / "wireshark" / "extcap" / "sharedlink-serial"
    interpreter = extcap.read_text().splitlines()[0][2:]
    assert os.access(interpreter, os.X_OK), interpreter

    # sharedlink.lua's modules are installed beside it, and run by nobody but it (Wireshark runs
    # them as plugins of their own too: they must do nothing then, and say nothing)
    plugin_dir = Path(re.search(r"^Personal Lua Plugins:\s*(.+)$", tshark(home, "-G", "folders").stdout, re.M)
                      .group(1).strip())
    assert (plugin_dir / "sharedlink" / "wsapi.lua").is_file()
    assert any(ln.split("\t")[2:3] == ["sharedlink"] for ln in tshark(home, "-G", "protocols").stdout.splitlines())

    make("uninstall", home)
    assert not set(LUA) & set(lua_plugins(home))
    assert not (plugin_dir / "sharedlink").exists()
    assert "sharedlink-serial" not in tshark(home, "-D").stdout
    assert not extcap.exists()
    assert cf.read_text() == theirs
    # a second uninstall finds nothing to do and fails on nothing
    make("uninstall", home)
    assert cf.read_text() == theirs


def test_uninstall_restores_no_personal_colorfilters(tmp_path, tiny_capture):
    home = tmp_path / "home"
    home.mkdir()
    make("install", home)
    cf = home / ".config" / "wireshark" / "colorfilters"
    assert cf.read_text().startswith(RULES)
    make("uninstall", home)
    # install made the file from the global default; uninstall leaves no personal file, and
    # Wireshark (tshark --color reads the rules) starts without "Could not compile"
    assert not cf.exists()
    r = tshark(home, "-r", str(tiny_capture), "--color", "-c", "1")
    assert "Could not compile" not in r.stderr + r.stdout


@pytest.fixture
def tiny_capture(tmp_path) -> Path:
    from tshark_util import frame, write_pcap

    return write_pcap(tmp_path / "one.pcap", [(0.0, frame("A", "B", "N0", "D1"))])
