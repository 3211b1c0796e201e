"""Shared test set-up. The test folders mirror the package (protocols/, capture/, generators/,
analysis/, dissector/ for the Lua side, tools/, fuzz/); helpers live in ``tshark_util`` (tshark
runs, each checked for Lua errors), ``sl_captures`` (test data builders), ``sl_vectors`` (the
shared vector tables), ``sl_pipes`` (a standard output whose reader lags, for Ctrl-C tests;
reading lines as they come), ``sl_agreement`` (the two decoders' frames side by side),
``sl_checks`` (the tap's report, MCAP read back, change records against the reference, odd
captures), ``sl_cli`` (the ``sharedlink`` command as a process; ``sl_zygote`` forks its runs from a
loaded interpreter), ``sl_golden`` (the golden inputs' runs), ``sl_groups`` (which xdist worker
runs a test) and ``sl_cpu_probe`` (CPU a test, on with ``SHAREDLINK_TEST_CPU``), importable from every test
file because this folder is on ``sys.path``. No test file imports another
(tests/tools/test_test_layout.py)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
if str(TESTS) not in sys.path:
    sys.path.insert(0, str(TESTS))

REPO = TESTS.parent

# which xdist worker runs a test (sl_groups: a module or an xdist_group to one worker), and the
# per-test CPU probe (docs/testing.md, "Where the suite's CPU goes"), only when asked
pytest_plugins = ["sl_groups"] + (["sl_cpu_probe"] if os.environ.get("SHAREDLINK_TEST_CPU") else [])


@pytest.fixture(scope="session")
def repo() -> Path:
    """The repository root."""
    return REPO


@pytest.fixture
def tiers(monkeypatch: pytest.MonkeyPatch) -> dict[str, int]:
    """Frames the decoder's fast tiers take, counted by tier (``sl_checks.count_tiers``)."""
    from sl_checks import count_tiers

    return count_tiers(monkeypatch)


def pytest_configure(config: pytest.Config) -> None:
    """The markers that sort the long tests out of `make test` into their own targets (the
    Makefile; docs/testing.md says which and why; `.ci/run` runs them all)."""
    config.addinivalue_line("markers", "install: builds a package or a virtualenv (pipx, pip, a wheel): `make test-install`")
    config.addinivalue_line("markers", "long: long by nature (live floods, scaling and memory patterns at size): `make test-long`")
    config.addinivalue_line("markers", "live: waits on the clock (real-time playback to a live client, a pty, a serial "
                            "timeout), using little CPU: `make test` runs these in a process of their own beside the rest")
