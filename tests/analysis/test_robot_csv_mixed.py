"""`export --format csv` of a capture holding SharedLink frames and P2OS packets: the CSV keeps
SharedLink's columns, and the P2OS rows it leaves out are named in a warning that points to jsonl
(which holds both). The count is the jsonl export's P2OS rows, read from the real files."""

from __future__ import annotations

import json
from pathlib import Path

from sl_cli import run_cli

from sharedlink.capture.pcapio import PcapWriter, read_records


def _mixed(tmp_path: Path) -> Path:
    sl, robot = tmp_path / "sl.pcap", tmp_path / "p2os.pcap"
    assert run_cli("gen", "-o", str(sl), "-q", "--frames", "30").returncode == 0
    assert run_cli("gen", "-o", str(robot), "-q", "--protocol", "p2os").returncode == 0
    recs = sorted([*read_records(sl), *read_records(robot)], key=lambda r: r.ts_ns)
    out = tmp_path / "mixed.pcap"
    with open(out, "wb") as fh:
        w = PcapWriter(fh)
        for r in recs:
            fh.write(w.record(r.ts_ns, r.data))
    return out


def test_mixed_csv_warns_about_the_robot_rows_it_leaves_out(tmp_path: Path) -> None:
    cap = _mixed(tmp_path)
    r = run_cli("export", str(cap), "-o", str(tmp_path / "m.jsonl"))
    assert r.returncode == 0, r.stderr
    rows = [json.loads(line) for line in (tmp_path / "m.jsonl").read_text().splitlines()]
    robot = sum(1 for row in rows if row.get("protocol") in ("p2os", "blackboard"))
    assert robot > 0 and len(rows) > robot  # both kinds in the jsonl
    r = run_cli("export", str(cap), "-o", str(tmp_path / "m.csv"))
    assert r.returncode == 0, r.stderr
    assert f"{robot:,} P2OS/blackboard packets left out of the CSV" in r.stderr
    assert "--format jsonl" in r.stderr
    header = (tmp_path / "m.csv").read_text().splitlines()[0].split(",")
    assert "protocol" not in header and "kind" in header
    # a capture of P2OS alone: its CSV is the robot rows, no warning
    r = run_cli("export", str(tmp_path / "p2os.pcap"), "-o", str(tmp_path / "p.csv"))
    assert r.returncode == 0 and "left out" not in r.stderr
