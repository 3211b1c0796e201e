"""Install as the README says: the lean core and its extras (sharedlink/extras.py).

- Fast: every command module imports without any extra; the core commands run without them;
  a command that needs one says which (exit 2, no traceback). A subprocess whose imports of the
  extras' modules are blocked (a ``sys.meta_path`` finder) stands for the lean install.
- The extras of pyproject.toml are the ones sharedlink/extras.py names.
- The README's install lines run: ``pipx install .`` (Debian's pipx when installed, else pipx from
  PyPI in a virtualenv of the test) into a temporary PIPX_HOME, then that sharedlink, which has the
  core only, runs gen and stats and names the extra plot needs.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sharedlink.extras import EXTRAS

ROOT = Path(__file__).resolve().parents[2]
BLOCKED = sorted({m for mods in EXTRAS.values() for m in mods} | {"dask"})

#: a Python that cannot import the extras' modules, then runs ``sharedlink`` with its arguments
LEAN = f"""
import sys
class Blocker:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {BLOCKED!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)
        return None
sys.meta_path.insert(0, Blocker())
from sharedlink.cli import main
sys.exit(main(sys.argv[1:]))
"""


def lean(*args: object, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", LEAN, *map(str, args)], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("lean") / "drive.pcap"
    r = lean("gen", "-o", path, "--frames", "40", "--compress")
    assert r.returncode == 0, r.stderr
    return path


def test_the_parser_and_every_command_module_load_without_the_extras():
    probe = LEAN.replace("from sharedlink.cli import main\nsys.exit(main(sys.argv[1:]))",
                         "from sharedlink.cli import build_parser\nbuild_parser()\n"
                         f"print(sorted(m for m in sys.modules if m.split('.')[0] in {BLOCKED!r}))")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "[]", (r.stdout, r.stderr)


CORE = [
    ["stats", "{d}"], ["stats", "{d}", "--json"], ["export", "{d}", "-o", "{t}/x.csv"],
    ["export", "{d}", "-o", "{t}/x.jsonl"], ["export", "{d}", "-o", "{t}/x.geojson"], ["diff", "{d}", "{d}"],
    ["compress", "{d}", "-o", "{t}/c.pcap"], ["expand", "{d}", "-o", "{t}/e.pcap"], ["lists", "{d}"],
    ["replay", "{d}", "--to", "127.0.0.1:9", "--topspeed", "--quiet"], ["watch", "{d}", "--speed", "1000"],
    ["plugins", "path"], ["completion", "bash"],
]


@pytest.mark.parametrize("argv", CORE, ids=[" ".join(a[:2]) for a in CORE])
def test_the_core_runs_without_the_extras(tmp_path, drive, argv):
    r = lean(*[a.format(d=drive, t=tmp_path) for a in argv])
    assert r.returncode == 0 and "Traceback" not in r.stderr and "extra" not in r.stderr, (argv, r.stderr)


NEEDS = [
    (["plot", "{d}", "-o", "{t}/p.png"], "sharedlink plot", "plot", "matplotlib"),
    (["ingest", "{d}", "-o", "{t}/ds"], "sharedlink ingest", "fleet", "pyarrow"),
    (["query", "{t}", "SELECT 1"], "sharedlink query", "fleet", "pyarrow"),
    (["export", "{d}", "-o", "{t}/x.mcap"], "sharedlink export --format mcap", "foxglove", "foxglove"),
    (["watch", "{d}", "--foxglove"], "sharedlink watch --foxglove", "foxglove", "foxglove"),
]


@pytest.mark.parametrize(("argv", "what", "extra", "module"), NEEDS, ids=[n[1] for n in NEEDS])
def test_a_missing_extra_is_named(tmp_path, drive, argv, what, extra, module):
    r = lean(*[a.format(d=drive, t=tmp_path) for a in argv])
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith(f"sharedlink: error: {what} needs the '{extra}' extra (no module {module}): "
                               f"pipx install --force 'sharedlink[{extra}]'"), r.stderr
    assert r.stderr.count("\n") == 1 and list(tmp_path.iterdir()) == [], r.stderr  # nothing written


def test_the_python_api_names_the_pyshark_extra(drive):
    probe = LEAN.replace("from sharedlink.cli import main\nsys.exit(main(sys.argv[1:]))",
                         "from sharedlink.extras import MissingExtra\nimport sharedlink.wireshark as w\n"
                         "try:\n    list(w.decode(sys.argv[1]))\nexcept MissingExtra as e:\n    print(e)\n")
    r = subprocess.run([sys.executable, "-c", probe, str(drive)], capture_output=True, text=True, timeout=120)
    assert r.stdout.startswith("sharedlink.wireshark.decode needs the 'pyshark' extra (no module pyshark)"), r


def test_pyproject_extras_are_the_ones_the_code_names():
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    named = set(EXTRAS) - {"dask"}  # dask is in [fleet]
    assert named <= set(extras) and extras["all"] == [f"sharedlink[{','.join(sorted(named, key=list(extras).index))}]"]
    core = " ".join(project["dependencies"]).lower()
    for dist in ("matplotlib", "pyarrow", "duckdb", "dask", "foxglove", "pyshark"):
        assert dist not in core, dist
    assert "dask[distributed]" in " ".join(extras["fleet"])


# -- the README's install lines, for real ---------------------------------------------------------


def install_lines() -> list[str]:
    block = re.search(r"## Installing `sharedlink`.*?```sh\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert block, "README.md: no install block"
    return [re.sub(r"\s{2,}#\s.*$", "", line).strip() for line in block.group(1).splitlines() if line.strip()]


def test_the_readme_installs_with_debian_pipx():
    lines = install_lines()
    assert lines[0] == "sudo apt install pipx" and "pipx install ." in lines, lines
    assert not any("pip install --user" in line for line in lines)  # refused by Debian 12's Python (PEP 668)


@pytest.fixture(scope="module")
def pipx(tmp_path_factory) -> list[str]:
    """Debian's pipx when it is installed, else pipx from PyPI in a virtualenv of its own."""
    found = shutil.which("pipx")
    if found:
        return [found]
    venv = tmp_path_factory.mktemp("pipx") / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    subprocess.run([str(venv / "bin" / "pip"), "install", "-q", "pipx"], check=True, capture_output=True, timeout=600)
    return [str(venv / "bin" / "pipx")]


@pytest.mark.install
def test_the_readme_pipx_lines_install_the_lean_core(tmp_path, pipx):
    src = tmp_path / "checkout"  # a copy: the build leaves nothing in the real checkout
    src.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for name in ("pytools", "dissector", "extcap"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    home, bin_dir = tmp_path / "home", tmp_path / "home" / ".local" / "bin"
    home.mkdir()
    env = dict(os.environ, HOME=str(home), PIPX_HOME=str(home / "pipx"), PIPX_BIN_DIR=str(bin_dir),
               PIPX_MAN_DIR=str(home / "man"), PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    env.pop("VIRTUAL_ENV", None)
    for line in install_lines():
        if line.startswith("pipx "):
            r = subprocess.run([*pipx, *shlex.split(line)[1:]], cwd=src, env=env, capture_output=True, text=True,
                               timeout=600)
            assert r.returncode == 0, (line, r.stdout[-2000:], r.stderr[-2000:])
    cli = str(bin_dir / "sharedlink")
    run = {"cwd": tmp_path, "env": env, "capture_output": True, "text": True, "timeout": 300}
    r = subprocess.run([cli, "gen", "-o", "d.pcap", "--frames", "20"], **run)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([cli, "stats", "d.pcap", "--json"], **run)
    assert r.returncode == 0 and '"frames": 20' in r.stdout, r.stderr
    r = subprocess.run([cli, "plot", "d.pcap", "-o", "p.png"], **run)
    assert r.returncode == 2 and "needs the 'plot' extra" in r.stderr and not (tmp_path / "p.png").exists()
    r = subprocess.run([cli, "plugins", "install"], **run)  # the README's last line, into the temporary HOME
    assert r.returncode == 0, r.stderr


@pytest.mark.install
def test_the_makefiles_editable_install_is_quiet(tmp_path):
    """make demo/test/install make .venv with the Makefile's PIP_EDITABLE line: pip -q, and
    setuptools' boxed "Editable installation" warning filtered, so nothing is printed."""
    line = re.search(r"^PIP_EDITABLE := (.*)$", (ROOT / "Makefile").read_text(), re.M)
    assert line, "Makefile: no PIP_EDITABLE"
    src = tmp_path / "checkout"
    src.mkdir()
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for name in ("pytools", "dissector", "extcap"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    subprocess.run([sys.executable, "-m", "venv", str(src / ".venv")], check=True, timeout=120)
    command = line.group(1).replace("$(BIN)", ".venv/bin") + " . --no-deps"  # (the dependencies: not the point)
    r = subprocess.run(command, shell=True, cwd=src, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "" and r.stderr == "", (r.stdout, r.stderr)
    r = subprocess.run([str(src / ".venv" / "bin" / "sharedlink"), "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.startswith("sharedlink ")
