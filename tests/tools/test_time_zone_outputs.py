"""Dates and partitions do not follow the machine's time zone, for the outputs
test_time_zone.py leaves out: link health (its table, JSON, per-second rows and strip), export's
outage rows and MCAP, plot's clock-time axis, the P2OS and blackboard rows of every command
(export in each format, stats, health, watch), every table ingest partitions, and the
times a command reads (gen --start, serial import's log times and --start, naive: UTC).

Each command writes the same (its standard output, or the file it writes, byte for byte) under
``TZ=America/Los_Angeles`` as under ``TZ=UTC``, on captures taken at 03:00 UTC on 1 January
2026 (19:00 on 31 December 2025 in Los Angeles: a local date is another day and another year),
each with an outage (a silence of 2.6 s in the SharedLink capture, planted by ``gen --outage``
in the robot sessions)."""

from __future__ import annotations

from pathlib import Path

import pytest
from sl_cli import in_zone, run_cli

import tshark_util as tu
from sharedlink.capture.pcapio import NS, read_records

ZONES = ("UTC", "America/Los_Angeles")
T0 = 1_767_236_400  # 2026-01-01T03:00:00Z
START = "2026-01-01T03:00:00"  # (no zone: UTC)
ROBOT = ["--duration", "6", "--start", START + "Z", "--outage", "2:1.5"]


@pytest.fixture(scope="module")
def caps(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("tz_outputs")
    times = [0, 0.2, 0.4, 0.6, 3.2, 3.4, 3.6]  # (a silence of 2.6 s: an outage)
    frames = [tu.frame("A", "B", "N0", "T2", "QAutoGpsLat", f"D38.{k}", "T2", "QAutoGpsLon", "D-77.25")
              for k in range(len(times))]
    out = {"sl": tu.write_pcap(d / "sl.pcap", [tu.Pkt(T0 + t, f, src="10.0.0.2", dst="10.0.0.1")
                                               for t, f in zip(times, frames)])}
    for name, args in (("p2os", ["--protocol", "p2os"]), ("bb", ["--protocol", "blackboard"])):
        out[name] = d / f"{name}.pcap"
        run_cli("gen", "-o", out[name], "-q", *args, *ROBOT, check=True)
    return out


def run(tz: str, *args: object) -> str:
    return run_cli(*args, check=True, env=in_zone(tz)).stdout


#: name -> command ({sl}, {p2os}, {bb}: the captures; {out}: a file it writes, compared instead
#: of its standard output)
COMMANDS = {
    "health": ["health", "{sl}"],
    "health-json": ["health", "{sl}", "--json"],
    "health-rows-jsonl": ["health", "{sl}", "-o", "-"],
    "health-rows-csv": ["health", "{sl}", "-o", "{out}.csv"],
    "health-strip": ["health", "{sl}", "--plot", "{out}.png", "-q"],
    "export-outages-jsonl": ["export", "{sl}", "--format", "jsonl", "--outages", "-o", "-"],
    "export-outages-csv": ["export", "{sl}", "--format", "csv", "--outages", "-o", "-"],
    "export-mcap": ["export", "{sl}", "-o", "{out}.mcap", "-q"],
    "plot": ["plot", "{sl}", "-o", "{out}.png", "-q"],
    "watch-json-outages": ["watch", "{sl}", "--json", "--outages", "--speed", "100"],
    "p2os-export-jsonl": ["export", "{p2os}", "--format", "jsonl", "--outages", "-o", "-"],
    "p2os-export-csv": ["export", "{p2os}", "--format", "csv", "--outages", "-o", "-"],
    "p2os-export-geojson": ["export", "{p2os}", "--format", "geojson", "-o", "-"],
    "p2os-export-kml": ["export", "{p2os}", "--format", "kml", "-o", "-"],
    "p2os-export-mcap": ["export", "{p2os}", "-o", "{out}.mcap", "-q"],
    "p2os-stats-json": ["stats", "{p2os}", "--json"],
    "p2os-health": ["health", "{p2os}"],
    "p2os-health-json": ["health", "{p2os}", "--json"],
    "p2os-watch-json": ["watch", "{p2os}", "--json", "--outages", "--speed", "100"],
    "blackboard-export-jsonl": ["export", "{bb}", "--format", "jsonl", "--outages", "-o", "-"],
    "blackboard-export-csv": ["export", "{bb}", "--format", "csv", "--outages", "-o", "-"],
    "blackboard-health-json": ["health", "{bb}", "--json"],
}
#: the outputs that write a date (the UTC one, never the local one; the others write times as
#: seconds or ns since 1970)
DATED = {"health", "health-rows-jsonl", "health-rows-csv", "export-outages-jsonl",
         "export-outages-csv", "watch-json-outages", "p2os-export-jsonl", "p2os-export-csv", "p2os-export-geojson",
         "p2os-export-kml", "p2os-health", "p2os-watch-json", "blackboard-export-jsonl", "blackboard-export-csv"}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_command_writes_the_same_in_every_time_zone(caps: dict[str, Path], tmp_path: Path, name: str) -> None:
    outs = []
    for tz in ZONES:
        out = tmp_path / tz.replace("/", "-")
        args = [a.format(out=out, **caps) for a in COMMANDS[name]]
        text = run(tz, *args)
        written = [a for a in args if a.startswith(str(out))]
        outs.append(Path(written[0]).read_bytes() if written else text.encode())
    assert outs[0] == outs[1]
    assert b"2025-12-31" not in outs[0] and b"2025-Dec-31" not in outs[0]
    if name in DATED:
        assert b"2026-01-01T03:00:0" in outs[0], outs[0][:2000]


def test_ingest_partitions_every_table_by_utc_day(caps: dict[str, Path], tmp_path: Path) -> None:
    seen = []
    for tz in ZONES:
        ds = tmp_path / tz.replace("/", "-")
        run(tz, "ingest", "-o", ds, "-q", *caps.values())
        tables = sorted(p.name for p in ds.iterdir() if p.is_dir())
        assert {"frames", "values", "links", "outages", "packets"} <= set(tables), tables
        days = {t: sorted(p.name for p in (ds / t).iterdir() if p.is_dir()) for t in tables}
        assert all(d == ["day=2026-01-01"] for d in days.values()), days
        rows = {t: run(tz, "query", ds, f"select * exclude (capture) from {t} order by all", "--format", "csv")
                for t in ("links", "outages")}  # (the frames table's times: test_time_zone.py)
        seen.append((days, rows))
    assert seen[0] == seen[1]
    assert "2025-12-31" not in str(seen[0])


@pytest.mark.parametrize("args", [[], ["--transport", "serial"], ["--protocol", "p2os"],
                                  ["--protocol", "p2os", "--transport", "serial"], ["--protocol", "blackboard"],
                                  ["--protocol", "blackboard", "--transport", "tcp"]], ids=" ".join)
def test_gen_start_without_a_zone_is_utc(tmp_path: Path, args: list[str]) -> None:
    """gen --start with no zone: the UTC time, in every time zone, every protocol and transport
    (the sessions begin with their handshake a little after it)."""
    caps = []
    for tz in ZONES:
        out = tmp_path / (tz.replace("/", "-") + ".pcapng")
        run(tz, "gen", "-o", out, "-q", "--duration", "3", "--start", START, *args)
        caps.append(out.read_bytes())
        first = next(iter(read_records(out))).ts_ns
        assert T0 * NS <= first < (T0 + 1) * NS, (tz, first)
    assert caps[0] == caps[1]


def test_serial_import_reads_times_without_a_zone_as_utc(tmp_path: Path) -> None:
    """A text log's times and a raw dump's --start, with no zone: UTC in every time zone (a raw
    dump's record is stamped at its last byte, at the line's speed)."""
    frame = tu.frame("A", "B", "N0", "T2", "QAutoGpsLat", "D1.5")
    log = tmp_path / "serial.log"
    log.write_text("".join(f"2026-01-01 03:00:0{k}.250 RX {frame.hex()}\n" for k in range(3)))
    raw = tmp_path / "serial.bin"
    raw.write_bytes(frame * 3)
    for source, extra, first_ns in ((log, [], T0 * NS + NS // 4), (raw, ["--start", START, "--baud", "10000", "--chunk", str(len(frame))],
                                                   T0 * NS + len(frame) * NS // 1000)):
        caps = []
        for tz in ZONES:
            out = tmp_path / f"{source.stem}-{tz.replace('/', '-')}.pcapng"
            run(tz, "serial", "import", source, "-o", out, "-q", *extra)
            caps.append(out.read_bytes())
            assert next(iter(read_records(out))).ts_ns == first_ns, (source.name, tz)
        assert caps[0] == caps[1], source.name
