"""The pip package: one version number, the Wireshark files as package data, and
`sharedlink plugins install|uninstall|path` (what `make install` does) against a temporary HOME
with the real tshark.

The wheel test builds the sdist from a copy of the package's sources, the wheel from the sdist,
installs it with
``--no-deps`` into a fresh virtualenv (no system site-packages), and gives that venv the
dependencies by a ``.pth`` line naming the test venv's site-packages *after* its own (the
project's editable install there is a ``.pth`` hook that a path added this way does not run):
``sharedlink`` then imports from the wheel only, from a folder outside the checkout, and so does
every Wireshark file it uses.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from importlib import metadata
from pathlib import Path

import pytest

import sharedlink
from tshark_util import REPO, TSHARK_CMD, check_stderr, frame, write_pcap

pytestmark = pytest.mark.skipif(TSHARK_CMD != [shutil.which("tshark") or "/usr/bin/tshark"],
                                reason="needs the machine's own tshark")
LUA = sorted(p.name for p in (REPO / "dissector").glob("*.lua"))
RULES = (REPO / "dissector" / "sharedlink.colorfilters").read_text()
THEIRS = "@My rule@udp.port == 9@[0,0,0][65535,65535,65535]\n"


def env_for(home: Path) -> dict[str, str]:
    env = dict(os.environ, HOME=str(home), XDG_CONFIG_HOME=str(home / ".config"), LC_ALL="C.UTF-8")
    for name in ("WIRESHARKCONFIGDIR", "WIRESHARK_CONFIG_DIR", "PYTHONPATH"):
        env.pop(name, None)
    return env


def run(cmd: list[str], home: Path, cwd: Path | None = None, timeout: float = 300) -> str:
    r = subprocess.run(cmd, capture_output=True, text=True, env=env_for(home), cwd=cwd, timeout=timeout)
    assert r.returncode == 0, f"{cmd}: {r.stdout}{r.stderr}"
    return r.stdout


def tshark(home: Path, *args: str) -> str:
    r = subprocess.run([*TSHARK_CMD, *args], capture_output=True, text=True, env=env_for(home), timeout=120)
    assert r.returncode == 0, r.stderr
    check_stderr(r.stderr)
    return r.stdout


def lua_plugins(home: Path) -> dict[str, str]:
    """`tshark -G plugins`: Lua plugin file name -> version."""
    out = tshark(home, "-G", "plugins")
    return {c[0]: c[1] for c in (ln.split("\t") for ln in out.splitlines()) if len(c) >= 3 and "lua" in c[-2]}


def plugin_info_version(path: Path) -> str | None:
    m = re.search(r"set_plugin_info\s*\(\s*\{[^}]*?version\s*=\s*\"([^\"]+)\"", path.read_text(), re.S)
    return m.group(1) if m else None


def home_with_rules(tmp_path: Path) -> tuple[Path, Path]:
    home = tmp_path / "home"
    cf = home / ".config" / "wireshark" / "colorfilters"
    cf.parent.mkdir(parents=True)
    cf.write_text(THEIRS)
    return home, cf


def disable_and_edit_rules(cf: Path) -> None:
    """What the GUI writes when the user unticks one of our rules and recolours another."""
    text = cf.read_text()
    assert "\n@SharedLink bad checksum@" in text and "\n@SharedLink late sync@" in text
    text = text.replace("\n@SharedLink bad checksum@", "\n!@SharedLink bad checksum@")
    text = re.sub(r"\n@SharedLink late sync@([^@]*)@.*", r"\n@SharedLink late sync@\1@[1,2,3][4,5,6]", text)
    cf.write_text(text)


# -- one version ---------------------------------------------------------------------------------


def test_one_version_for_the_package_the_cli_and_the_extcap():
    assert sharedlink.__version__ == "1.3.0"
    assert metadata.version("sharedlink") == sharedlink.__version__
    out = subprocess.run([sys.executable, "-m", "sharedlink", "--version"], capture_output=True, text=True, timeout=60)
    assert out.stdout.split() == ["sharedlink", sharedlink.__version__]
    ext = subprocess.run([sys.executable, str(REPO / "extcap" / "sharedlink-serial"), "--extcap-interfaces"],
                         capture_output=True, text=True, timeout=60)
    assert ext.returncode == 0, ext.stderr
    assert f"extcap {{version={sharedlink.__version__}}}" in ext.stdout


def test_every_lua_plugin_has_the_package_version():
    versions = {p.name: plugin_info_version(p) for p in sorted((REPO / "dissector").glob("*.lua"))}
    assert versions and versions == {name: sharedlink.__version__ for name in versions}


# -- plugins install / uninstall from the checkout ----------------------------------------------


def test_plugins_install_path_and_uninstall_with_rules_disabled_in_the_gui(tmp_path):
    home, cf = home_with_rules(tmp_path)
    cli = [sys.executable, "-m", "sharedlink", "plugins"]
    where = json.loads(run([*cli, "path", "--json"], home))
    assert where["plugins"].startswith(str(home)) and where["colorfilters"] == str(cf)
    run([*cli, "install"], home)
    assert cf.read_text() == RULES + THEIRS
    assert set(LUA) <= set(lua_plugins(home))
    extcap = Path(where["extcap"])
    assert extcap.read_text().splitlines()[0] == f"#!{sys.executable}" and os.access(extcap, os.X_OK)
    assert "sharedlink-serial" in tshark(home, "-D")
    # installing again adds nothing, also with a rule disabled
    disable_and_edit_rules(cf)
    edited = cf.read_text()
    assert "installed" in run([*cli, "install"], home) and cf.read_text() == edited
    run([*cli, "uninstall"], home)
    assert cf.read_text() == THEIRS
    assert not set(LUA) & set(lua_plugins(home)) and not extcap.exists()
    run([*cli, "uninstall"], home)  # nothing left to do, nothing fails
    assert cf.read_text() == THEIRS


def test_make_uninstall_removes_a_rule_the_user_disabled(tmp_path):
    if shutil.which("make") is None:
        pytest.skip("needs make")
    home, cf = home_with_rules(tmp_path)
    run(["make", "-s", "install"], home, cwd=REPO)
    disable_and_edit_rules(cf)
    run(["make", "-s", "uninstall"], home, cwd=REPO)
    assert cf.read_text() == THEIRS


def test_plugins_without_tshark_is_a_usage_error(tmp_path):
    r = subprocess.run([sys.executable, "-m", "sharedlink", "plugins", "install", "--tshark", str(tmp_path / "nope")],
                       capture_output=True, text=True, timeout=60, env=env_for(tmp_path))
    assert r.returncode == 2 and "sharedlink: error:" in r.stderr and "Traceback" not in r.stderr


# -- the wheel, in a fresh venv ---------------------------------------------------------------------


def build_wheel(tmp_path: Path) -> Path:
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy(REPO / name, src / name)
    for name in ("pytools", "dissector", "extcap"):
        shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    out = tmp_path / "dist"
    # the sdist (setuptools' build backend, as `python -m build --sdist` calls it) carries them...
    subprocess.run([sys.executable, "-c", f"from setuptools import build_meta; build_meta.build_sdist({str(out)!r})"],
                   cwd=src, check=True, capture_output=True, timeout=300)
    (sdist,) = out.glob("sharedlink-*.tar.gz")
    with tarfile.open(sdist) as tar:
        names = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
    assert {f"dissector/{n}" for n in LUA} | {"dissector/sharedlink.colorfilters", "extcap/sharedlink-serial"} <= names
    # ...and the wheel built from the sdist
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(sdist)],
                   check=True, capture_output=True, timeout=300)
    (wheel,) = out.glob("sharedlink-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
    assert {f"sharedlink/dissector/{n}" for n in LUA} | {"sharedlink/dissector/sharedlink.colorfilters",
                                                        "sharedlink/extcap_launcher/sharedlink-serial"} <= names
    return wheel


@pytest.mark.install
def test_the_wheel_carries_the_wireshark_files_and_works_from_a_fresh_venv(tmp_path):
    wheel = build_wheel(tmp_path)
    assert wheel.name == f"sharedlink-{sharedlink.__version__}-py3-none-any.whl"
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", str(wheel)],
                   check=True, capture_output=True, timeout=300)
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    (site / "zz_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    home = tmp_path / "home"
    home.mkdir()
    work = tmp_path / "elsewhere"  # not the checkout
    work.mkdir()

    # the Python API decodes through tshark with the wheel's dissector
    write_pcap(work / "one.pcap", [(0.0, frame("A", "B", "N0", "T2", "QSpeed", "D12.5")),
                                   (0.2, frame("A", "B", "N0", "T2", "QSpeed", "D13"))])
    probe = ("import json, sharedlink, sharedlink.wireshark as w\n"
             "fs = list(w.decode('one.pcap'))\n"
             "print(json.dumps({'file': sharedlink.__file__, 'dissector': str(w.DEFAULT_DISSECTOR),"
             " 'values': [[v.name, v.value] for f in fs for v in f.variables], 'kinds': [f.kind for f in fs]}))")
    got = json.loads(run([str(py), "-c", probe], home, cwd=work))
    assert got["file"].startswith(str(site)) and got["dissector"] == str(site / "sharedlink" / "dissector" / "sharedlink.lua")
    assert got["values"] == [["Speed", "12.5"], ["Speed", "13"]]

    # the console script: version, and plugins install / uninstall into the temporary HOME
    cli = str(venv / "bin" / "sharedlink")
    assert run([cli, "--version"], home, cwd=work).split() == ["sharedlink", sharedlink.__version__]
    where = json.loads(run([cli, "plugins", "path", "--json"], home, cwd=work))
    assert where["dissectors"] == str(site / "sharedlink" / "dissector")
    assert where["extcap_launcher"] == str(site / "sharedlink" / "extcap_launcher" / "sharedlink-serial")
    run([cli, "plugins", "install"], home, cwd=work)
    plugins = lua_plugins(home)
    assert set(LUA) <= set(plugins)
    for name in LUA:
        assert re.fullmatch(r"\d+\.\d+\.\d+", plugins[name]), (name, plugins[name])
    extcap = Path(where["extcap"])
    assert extcap.read_text().splitlines()[0] == f"#!{py}"
    assert "sharedlink-serial" in tshark(home, "-D")
    ext = run([str(extcap), "--extcap-interfaces"], home, cwd=work)
    assert f"extcap {{version={sharedlink.__version__}}}" in ext
    cf = home / ".config" / "wireshark" / "colorfilters"
    assert cf.read_text().startswith(RULES)
    run([cli, "plugins", "uninstall"], home, cwd=work)
    assert not set(LUA) & set(lua_plugins(home)) and not extcap.exists() and not cf.exists()
