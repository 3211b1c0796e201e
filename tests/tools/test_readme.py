"""Every command the README shows is run: its code blocks line by line, and the whole commands
it quotes inline (``sharedlink ...``, ``tshark ...``), in a folder holding what they name. The
ones that cannot run here are listed with the reason. The README and docs use no old spelling
(docs/cli.md)."""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()
VENV_BIN = Path(sys.executable).parent

#: commands not run, and why
SKIP = {
    "make test": "the whole suite, this test included",
    "source .venv/bin/activate": "changes the calling shell only (a shell builtin, nothing to check)",
    "sudo apt install pipx": "a system package: test_lean_install.py runs the pipx lines with Debian's pipx, or with pipx from PyPI",
    "pipx install .": "run by tests/tools/test_lean_install.py into a temporary PIPX_HOME (the lean core, then its commands)",
    "pipx ensurepath": "run by tests/tools/test_lean_install.py with the install line (a temporary HOME)",
    "sharedlink watch --foxglove": None,  # run below until its server is up, then stopped (it serves until Ctrl-C)
}


def _strip_comment(line: str) -> str:
    return re.sub(r"\s{2,}#\s.*$", "", line).rstrip()


def _block_commands(block: str) -> list[str]:
    """One command per line; a quoted argument may continue on the next lines."""
    out: list[str] = []
    pending = ""
    for line in block.splitlines():
        line = _strip_comment(line)
        if not line.strip() and not pending:
            continue
        pending = f"{pending}\n{line}" if pending else line.strip()
        try:
            shlex.split(pending)
        except ValueError:  # an open quote: the command goes on
            continue
        out.append(pending)
        pending = ""
    assert not pending, pending
    return out


def readme_commands() -> list[str]:
    fenced = re.findall(r"```[a-z]*\n(.*?)```", README, flags=re.S)
    rest = re.sub(r"```.*?```", "", README, flags=re.S)
    indented = ["\n".join(x[4:] for x in m.group(0).strip("\n").splitlines())
                for m in re.finditer(r"(?:^ {4}\S.*\n)+", rest, flags=re.M)]
    commands = [c for b in fenced + indented for c in _block_commands(b)]
    for span in re.findall(r"`((?:\.venv/bin/)?(?:sharedlink|tshark) [^`]+)`", rest):
        words = span.split()
        if len(words) >= 3 and not any(re.fullmatch(r"[A-Z_]{2,}\S*", w) for w in words) and "|" not in span:
            commands.append(span)
    return list(dict.fromkeys(commands))


COMMANDS = readme_commands()


def test_the_readme_commands_are_found():
    assert any(c.startswith(".venv/bin/sharedlink gen") for c in COMMANDS)
    assert any(c.startswith("sharedlink query fleet.parquet") for c in COMMANDS)
    assert "tshark -X lua_script:dissector/sharedlink.lua -r captures/beacon-compressed.pcap" in COMMANDS
    assert "make demo" in COMMANDS and len(COMMANDS) >= 12, COMMANDS


@pytest.fixture(scope="module")
def place(tmp_path_factory) -> Path:
    """A folder with what the commands name: .venv, dissector/, captures/, drive.pcap, fleet/."""
    d = tmp_path_factory.mktemp("readme")
    (d / ".venv").symlink_to(VENV_BIN.parent)
    (d / "dissector").symlink_to(ROOT / "dissector")
    (d / "captures").symlink_to(ROOT / "captures")
    sl = str(VENV_BIN / "sharedlink")
    subprocess.run([sl, "gen", "-o", str(d / "drive.pcap"), "--duration", "20"], check=True, capture_output=True)
    for vehicle, seed in (("truck1", "1"), ("truck2", "2")):
        (d / "fleet" / vehicle).mkdir(parents=True)
        subprocess.run([sl, "gen", "-o", str(d / "fleet" / vehicle / "drive.pcap"), "--duration", "10", "--seed", seed],
                       check=True, capture_output=True)
    return d


def _env(place: Path) -> dict[str, str]:
    """PATH with the venv's sharedlink; a new HOME for each command, so that `plugins install` and
    `make install` write into it, never into the user's Wireshark folders (nor into the next
    command's: a tshark -X lua_script run beside installed plugins would load them twice)."""
    home = Path(tempfile.mkdtemp(prefix="home-", dir=place))
    return dict(os.environ, PATH=f"{VENV_BIN}{os.pathsep}{os.environ.get('PATH', '')}", HOME=str(home),
                XDG_CONFIG_HOME=str(home / ".config"))


@pytest.mark.parametrize("command", COMMANDS)
def test_readme_command_runs(place, command):
    if command in SKIP and SKIP[command]:
        pytest.skip(SKIP[command])
    cwd = ROOT if command.startswith("make ") else place
    if command.startswith("sharedlink query fleet.parquet") and not (place / "fleet.parquet").exists():
        # the README ingests first; under pytest -n 2 the ingest command may run on the other
        # worker (its own folder) or later: run it here (ingest is incremental, so a later run
        # of the ingest command still succeeds, finding the captures unchanged)
        (ingest,) = [c for c in COMMANDS if c.startswith("sharedlink ingest fleet/ -o fleet.parquet")]
        subprocess.run(ingest, shell=True, cwd=place, env=_env(place), check=True, capture_output=True, timeout=600)
    if command == "sharedlink watch --foxglove":
        return _run_until_serving(place, command)
    r = subprocess.run(command, shell=True, cwd=cwd, env=_env(place), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, (command, r.stdout[-2000:], r.stderr[-2000:])
    assert "Traceback" not in r.stderr and "deprecated" not in r.stderr, r.stderr
    if command.startswith("tshark"):
        assert "Lua" not in r.stderr and "_ws.lua.error" not in r.stdout, r.stderr


def _run_until_serving(place: Path, command: str) -> None:
    p = subprocess.Popen(shlex.split(command), cwd=place, env=_env(place), stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    try:
        line = p.stderr.readline() if p.stderr else ""
        if "8765" in line and "server on" not in line:
            pytest.skip(f"port 8765 is taken here: {line.strip()}")
        assert "Foxglove WebSocket server on ws://127.0.0.1:8765" in line, line
    finally:
        p.send_signal(signal.SIGINT)
        p.wait(timeout=60)
    assert p.returncode == 0  # Ctrl-C ends a watch, as it does tcpdump


#: old spellings (docs/cli.md) in a sharedlink command line of the README or docs
OLD = [
    (r"sharedlink (?:gen|compress|expand) (?!-)\S+(?: (?!-)\S+)?(?:\s|`|$)", "a positional output"),
    (r"--out\b", "--out"), (r"--vars\b", "--vars"), (r"--from\b", "--from"), (r"replay .*--limit\b", "--limit"),
    (r"ingest .*--to\b", "ingest --to"), (r"serial import .*--format\b", "serial import --format"),
]


@pytest.mark.parametrize("doc", ["README.md", *sorted(p.name for p in (ROOT / "docs").glob("*.md"))])
def test_docs_use_the_current_spellings(doc):
    if doc == "cli.md":
        pytest.skip("docs/cli.md lists the old spellings on purpose")
    path = ROOT / doc if doc == "README.md" else ROOT / "docs" / doc
    bad = [(n, line.strip(), why) for n, line in enumerate(path.read_text().splitlines(), 1) if "sharedlink" in line
           for pat, why in OLD if re.search(pat, line)]
    assert not bad, bad
