"""Examples in the docs run: the serial-writer snippet of docs/serial-capture-format.md, the
doctests of the package, and the package docstrings are there."""

from __future__ import annotations

import doctest
import importlib
import pkgutil
import re
from pathlib import Path

import pytest

import sharedlink
from sharedlink.capture.serial_format import read_capture

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = Path(sharedlink.__file__).parent


def _python_blocks(md: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", md.read_text(), flags=re.S)


def test_serial_writer_example_decodes(tmp_path, monkeypatch):
    blocks = [b for b in _python_blocks(ROOT / "docs" / "serial-capture-format.md") if "SerialCaptureWriter" in b]
    assert len(blocks) == 1
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[0], "serial-capture-format.md", "exec"), {})
    pieces = [(d, p) for _, d, p in read_capture(tmp_path / "line.pcapng")]
    frames = [p.frame for _, p in pieces if p.is_frame]
    assert len(frames) == 2 and len(pieces) == 2, pieces  # no noise: both checksums right
    assert all(f.checksum is not None and f.checksum.ok for f in frames), frames


def _modules_with_doctests() -> list[str]:
    return sorted(
        "sharedlink." + str(p.relative_to(PACKAGE).with_suffix("")).replace("/", ".").replace(".__init__", "")
        for p in PACKAGE.rglob("*.py") if ">>> " in p.read_text()
    )


def test_the_package_has_doctests():
    assert "sharedlink.scapy_layer" in _modules_with_doctests()


@pytest.mark.parametrize("name", _modules_with_doctests())
def test_doctests(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0, result


def test_every_subpackage_has_a_docstring():
    names = [m.name for m in pkgutil.walk_packages(sharedlink.__path__, "sharedlink.") if m.ispkg]
    assert {"sharedlink.analysis", "sharedlink.capture", "sharedlink.protocols"} <= set(names)
    missing = [n for n in names if not (importlib.import_module(n).__doc__ or "").strip()]
    assert not missing, missing
