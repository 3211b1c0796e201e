"""The checked-in sample captures are what `make captures` makes, byte for byte."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from sl_cli import run_cli

ROOT = Path(__file__).resolve().parents[2]


def make_captures_commands() -> list[list[str]]:
    """The `sharedlink gen` lines of the Makefile's captures target."""
    text = (ROOT / "Makefile").read_text()
    block = text.split("\ncaptures:", 1)[1].split("\n\n", 1)[0]
    return [shlex.split(line.strip())[1:] for line in block.splitlines() if re.match(r"\s+\$\(CLI\) gen ", line)]


def _output(cmd: list[str]) -> str:
    """The capture a gen line writes: ``-o FILE`` (or the old positional ``gen FILE``)."""
    return cmd[cmd.index("-o") + 1] if "-o" in cmd else cmd[1]


def test_makefile_lists_every_capture():
    cmds = make_captures_commands()
    made = sorted(Path(_output(c)).name for c in cmds)
    assert made == sorted(p.name for p in (ROOT / "captures").glob("*.pcap*"))
    readme = (ROOT / "captures" / "README.md").read_text()
    for name in made:
        assert name in readme


@pytest.mark.parametrize("cmd", make_captures_commands(), ids=lambda c: Path(_output(c)).name)
def test_capture_is_byte_identical_when_remade(tmp_path, cmd):
    target = ROOT / _output(cmd)
    out = tmp_path / target.name
    args = [str(out) if a == _output(cmd) else a for a in cmd]
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes() == target.read_bytes()
