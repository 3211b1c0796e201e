"""Threshold options at their exact boundary, where ``<`` and ``<=`` differ.

* The sync clock: a frame is late when the last full frame is *older than* the sync interval +
  0.5 s (docs/fields-sharedlink.md): a delta exactly 1.5 s after it (interval 1 s) is on time, one
  1 ns later is late; with the interval at 2 s both are on time. The Python decoder, ``stats
  --sync-interval`` and the dissector (``sharedlink.sync_interval``) alike.
* ``diff --tolerance X``: doubles within X of each other are equal: a difference of exactly X
  agrees (exit 0), with a tolerance just under it they diverge (exit 1).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from sl_captures import write_capture
from sl_cli import run_cli

import tshark_util as tu
from sharedlink.analysis.decode import Decoded, iter_decoded

CLI = [sys.executable, "-m", "sharedlink"]
T0 = 1_767_268_800 * 10**9
NS = 10**9


def _payloads() -> list[bytes]:
    return [tu.frame("A", "B", "N0", "D1", "D2", "D3", "D4"), tu.frame("A", "B", "N0", "D5", "D", "D", "D")]


@pytest.fixture(scope="module")
def boundary(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two captures: a full frame, then a delta exactly 1.5 s later ("at"), or 1.5 s + 1 ns ("past")."""
    folder = tmp_path_factory.mktemp("sync")
    full, delta = _payloads()
    return {name: write_capture(folder / f"{name}.pcap", [(T0, full), (T0 + 3 * NS // 2 + extra, delta)])
            for name, extra in (("at", 0), ("past", 1))}


CASES = [("at", 1.0, False), ("past", 1.0, True), ("at", 2.0, False), ("past", 2.0, False)]


@pytest.mark.parametrize("name,interval,late", CASES)
def test_python_sync_clock_at_its_boundary(boundary: dict[str, Path], name: str, interval: float, late: bool) -> None:
    decoded = [d for d in iter_decoded(boundary[name], sync_interval=interval) if isinstance(d, Decoded)]
    assert [(d.kind, d.late) for d in decoded] == [("full", False), ("delta", late)]


@pytest.mark.parametrize("name,interval,late", CASES)
def test_stats_sync_interval_at_its_boundary(boundary: dict[str, Path], name: str, interval: float, late: bool) -> None:
    r = run_cli("stats", str(boundary[name]), "--sync-interval", str(interval), "--json", timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["sync_late"] == int(late)


@pytest.mark.parametrize("name,interval,late", CASES)
def test_dissector_sync_interval_at_its_boundary(boundary: dict[str, Path], name: str, interval: float,
                                                 late: bool) -> None:
    rows = tu.fields(boundary[name], ["sharedlink.kind", "sharedlink.sync.is_late"],
                     prefs={"sharedlink.sync_interval": int(interval * 1000)}, two_pass=False)
    assert [(r["sharedlink.kind"], r["sharedlink.sync.is_late"] == ["1"]) for r in rows] == [
        (["full"], False), (["delta"], late)]


def test_diff_tolerance_at_its_boundary(tmp_path: Path) -> None:
    """Lat 1.5 against 1.75: a difference of 0.25, exactly representable."""
    caps = []
    for lat in ("1.5", "1.75"):
        caps.append(write_capture(tmp_path / f"{lat}.pcap", [
            (T0 + i * NS // 5, tu.frame("A", "B", "N0", "T2", "QLat", f"D{lat}", "T2", "QLon", "D2")) for i in range(5)]))
    codes = {}
    for tolerance in ("0.25", "0.2499999", "0"):
        r = run_cli("diff", str(caps[0]), str(caps[1]), "--tolerance", tolerance, timeout=120)
        codes[tolerance] = r.returncode
    assert codes == {"0.25": 0, "0.2499999": 1, "0": 1}, codes
