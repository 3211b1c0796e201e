"""Dates and partitions do not follow the machine's time zone: every command that writes a date
or a partition writes the same under ``TZ=America/Los_Angeles`` as under ``TZ=UTC``, on a capture
taken at 03:00 UTC on 1 January 2026 (19:00 on 31 December 2025 in Los Angeles, so a local date
would be another day and another year)."""

from __future__ import annotations

from pathlib import Path

import pytest
from sl_cli import in_zone, run_cli

import tshark_util as tu

ZONES = ("UTC", "America/Los_Angeles")
T0 = 1_767_236_400.0  # 2026-01-01T03:00:00Z


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    frames = [tu.frame("A", "B", "N0", "T2", "QAutoGpsLat", "D38.5", "T2", "QAutoGpsLon", "D-77.25"),
              tu.frame("A", "B", "N0", "T2", "QAutoGpsLat", "D38.6")]
    return tu.write_pcap(tmp_path_factory.mktemp("tz") / "tz.pcap",
                         [tu.Pkt(T0 + 0.2 * i, p, src="10.0.0.2", dst="10.0.0.1") for i, p in enumerate(frames)])


def run(tz: str, *args: object, cwd: Path | None = None) -> str:
    return run_cli(*args, check=True, cwd=cwd, env=in_zone(tz)).stdout


COMMANDS = {
    "export-jsonl": ["export", "{cap}", "--format", "jsonl", "-o", "-"],
    "export-jsonl-changes": ["export", "{cap}", "--format", "jsonl", "--changes", "-o", "-"],
    "export-csv": ["export", "{cap}", "--format", "csv", "-o", "-"],
    "export-csv-changes": ["export", "{cap}", "--format", "csv", "--changes", "-o", "-"],
    "export-geojson": ["export", "{cap}", "--format", "geojson", "-o", "-"],
    "export-kml": ["export", "{cap}", "--format", "kml", "-o", "-"],
    "stats": ["stats", "{cap}"],
    "stats-json": ["stats", "{cap}", "--json"],
    "diff": ["diff", "{cap}", "{cap}"],
    "diff-json": ["diff", "{cap}", "{cap}", "--json"],
    "watch-json": ["watch", "{cap}", "--json", "--speed", "100"],
}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_command_writes_the_same_in_every_time_zone(capture: Path, name: str) -> None:
    args = [capture if a == "{cap}" else a for a in COMMANDS[name]]
    outs = [run(tz, *args) for tz in ZONES]
    assert outs[0] == outs[1]
    assert "2025-12-31" not in outs[0]


def test_export_dates_are_utc(capture: Path) -> None:
    out = run("America/Los_Angeles", "export", capture, "--format", "jsonl", "-o", "-")
    assert '"time": "2026-01-01T03:00:00.000000000Z"' in out


def test_gen_writes_the_same_bytes_in_every_time_zone(tmp_path: Path) -> None:
    caps = []
    for tz in ZONES:
        out = tmp_path / f"{tz.replace('/', '-')}.pcap"
        run(tz, "gen", "-o", out, "--frames", "20", "--compress")
        caps.append(out.read_bytes())
    assert caps[0] == caps[1]


def test_ingest_partitions_and_query_times_by_utc_day(capture: Path, tmp_path: Path) -> None:
    seen = []
    for tz in ZONES:
        ds = tmp_path / tz.replace("/", "-")
        run(tz, "ingest", capture, "--to", ds)
        days = sorted(p.name for p in (ds / "frames").iterdir() if p.is_dir())
        assert days == ["day=2026-01-01"], days
        seen.append((days, run(tz, "query", ds, "select day, time, time_ns from frames order by time_ns",
                                "--format", "csv")))
    assert seen[0] == seen[1]
    assert "2026-01-01T03:00:00" in seen[0][1] and "2025-12-31" not in seen[0][1]
