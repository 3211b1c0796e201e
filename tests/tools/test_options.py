"""Number options: one validator for all of them. NaN, infinities, huge and tiny values end in
exit 2 with a message naming the option, never a traceback and never a file."""

from __future__ import annotations

import sys

import pytest
from sl_cli import run_cli

CLI = [sys.executable, "-m", "sharedlink"]

BAD = [
    ("gen", "--rate", "nan"),
    ("gen", "--duration", "inf"),
    ("gen", "--sync-interval", "1e300"),
    ("gen", "--jitter", "1e15"),
    ("gen", "--rate", "1e10"),  # five frames in one nanosecond
    ("gen", "--frames", "0"),
    ("gen", "--drop", "-0.5"),
    ("gen", "--port", "70000"),
    ("gen", "--transport", "serial", "--frames", "10", "--rate", "0"),  # the option named is the last
    ("replay", "--speed", "1e-300"),
    ("replay", "--loop-delay", "nan"),
    ("replay", "--pps", "-1"),
    ("stats", "--sync-interval", "0"),
    ("diff", "--window", "nan"),
    ("compress", "--sync-interval", "-inf"),
    ("plot", "--max-points", "1e3"),
    ("serial", "import", "--start", "-1"),
    ("serial", "import", "--start", "nan"),
]


@pytest.mark.parametrize("args", BAD, ids=[" ".join(a) for a in BAD])
def test_bad_numbers_exit_2_with_a_message(tmp_path, args):
    cap = tmp_path / "in.pcap"
    cap.write_bytes(b"")
    out = tmp_path / "out.pcap"
    place = {"gen": [out], "replay": [cap], "stats": [cap], "diff": [cap, cap], "compress": [cap, out],
             "plot": [cap, "-o", tmp_path / "p.png"], "serial": [cap, "--out", out]}[args[0]]
    r = run_cli(*args, *map(str, place), timeout=120)
    assert r.returncode == 2, r.stderr
    option = [a for a in args if a.startswith("--")][-1]
    assert f"argument {option}" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.pcap"]


def test_gen_says_what_it_would_write(tmp_path):
    out = tmp_path / "huge.pcap"
    r = run_cli("gen", "--rate", "1e9", "--duration", "1e6", str(out), timeout=120)
    assert r.returncode == 2 and "would write 1,000,000,000,000,000 frames" in r.stderr, r.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["late.pcap", "late.pcapng"])
def test_gen_start_past_what_the_format_holds(tmp_path, name):
    out = tmp_path / name
    start = "2200-01-01T00:00:00Z" if name.endswith(".pcap") else "9999-12-31T00:00:00Z"
    r = run_cli("gen", "--start", start, "--frames", "5", str(out), timeout=120)
    assert r.returncode == 2 and "do not fit" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []
