"""One command-line vocabulary (docs/cli.md), held by reading every sub-command's parser; the
old spellings still work with a note; names and types checked; one wording for a missing file;
tables that fit the terminal."""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import subprocess
from functools import partial
from pathlib import Path

import pytest
from sl_cli import CLI, run_cli
from sl_pipes import on_pty

from sharedlink.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
DOC = (ROOT / "docs" / "cli.md").read_text()
OUTPUT_DESTS = {"output", "out", "dataset"}
#: old spellings: visible in no parser
OLD = {"--out", "--vars", "--limit", "--from"}


def _parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    found: list[tuple[str, argparse.ArgumentParser]] = []

    def walk(name: str, p: argparse.ArgumentParser) -> None:
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs and name:
            found.append((name, p))
        for s in subs:
            for sub_name, sub in s.choices.items():
                walk(f"{name} {sub_name}".strip(), sub)

    walk("", build_parser())
    return found


PARSERS = _parsers()


def _visible(p: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in p._actions if a.help is not argparse.SUPPRESS and not isinstance(a, argparse._HelpAction)]


def test_the_walk_finds_every_command():
    names = {n for n, _ in PARSERS}
    assert {"gen", "replay", "compress", "expand", "diff", "stats", "export", "plot", "watch", "ingest", "query",
            "serial capture", "serial import", "serial ports"} <= names


@pytest.mark.parametrize(("name", "parser"), PARSERS, ids=[n for n, _ in PARSERS])
def test_outputs_are_dash_o_and_every_command_has_json(name, parser):
    for a in _visible(parser):
        if a.dest in OUTPUT_DESTS and (a.option_strings or a.dest != "dataset"):  # query DATASET is its input
            assert a.option_strings == ["-o", "--output"], (name, a.option_strings or a.dest)
        assert not set(a.option_strings) & OLD, (name, a.option_strings)
        if "--to" in a.option_strings:
            assert name == "replay" and a.metavar == "HOST[:PORT]"
    assert any("--json" in a.option_strings for a in parser._actions), name


def _signature(a: argparse.Action) -> tuple:
    return (a.metavar, getattr(a.type, "__name__", a.type), type(a).__name__, a.nargs)


#: options whose signature differs between commands, and why (docs/cli.md says the same)
SAME_WORD_DIFFERENT_FORM = {
    "--json": "query's --json is --format json",
    "--format": "the choices are each command's formats",
    "--protocol": "the choices differ (serial import adds auto)",
    "--output": "ingest's metavar is DATASET (a directory)",
}


def test_one_name_one_meaning():
    seen: dict[str, dict[tuple, list[str]]] = {}
    for name, p in PARSERS:
        for a in _visible(p):
            for opt in a.option_strings:
                if opt.startswith("--"):
                    seen.setdefault(opt, {}).setdefault(_signature(a), []).append(name)
    clashes = {opt: forms for opt, forms in seen.items() if len(forms) > 1 and opt not in SAME_WORD_DIFFERENT_FORM}
    assert not clashes, clashes


def test_every_option_is_in_docs_cli_md():
    missing = sorted({f"{name}: {opt}" for name, p in PARSERS for a in _visible(p) for opt in a.option_strings
                      if opt.startswith("--") and f"`{opt}" not in DOC and f" {opt}" not in DOC and opt != "--help"})
    assert not missing, missing


def _parse(argv: list[str]) -> tuple[dict, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        ns = build_parser().parse_args(argv)
    return {k: v for k, v in vars(ns).items() if not k.startswith("old_") and k != "func"}, err.getvalue()


RENAMED = [
    (["gen", "x.pcap"], ["gen", "-o", "x.pcap"]),
    (["compress", "a.pcap", "b.pcap"], ["compress", "a.pcap", "-o", "b.pcap"]),
    (["expand", "a.pcap", "b.pcap"], ["expand", "a.pcap", "--output", "b.pcap"]),
    (["serial", "capture", "/dev/null", "--baud", "9600", "--out", "c.pcapng"],
     ["serial", "capture", "/dev/null", "--baud", "9600", "-o", "c.pcapng"]),
    (["serial", "import", "l.txt", "--out", "c.pcapng", "--format", "hex"],
     ["serial", "import", "l.txt", "-o", "c.pcapng", "--log-format", "hex"]),
    (["serial", "import", "l.txt", "-o", "c.pcapng", "--start", "1772438400"],
     ["serial", "import", "l.txt", "-o", "c.pcapng", "--start", "2026-03-02T08:00:00Z"]),
    (["ingest", "d", "--to", "ds"], ["ingest", "d", "-o", "ds"]),
    (["export", "a.pcap", "--vars", "A,B"], ["export", "a.pcap", "--select", "A,B"]),
    (["plot", "a.pcap", "-o", "p.png", "--vars", "A", "--speed", "V"],
     ["plot", "a.pcap", "-o", "p.png", "--select", "A", "--velocity", "V"]),
    (["replay", "a.pcap", "--limit", "3"], ["replay", "a.pcap", "--count", "3"]),
    (["watch", "--from", "a.pcap"], ["watch", "a.pcap"]),
]


@pytest.mark.parametrize(("old", "new"), RENAMED, ids=[" ".join(o) for o, _ in RENAMED])
def test_old_spellings_still_work_with_a_note(old, new):
    old_ns, old_err = _parse(old)
    new_ns, new_err = _parse(new)
    if old[0] in ("gen", "compress", "expand"):  # the positional output lands in -o's place when run
        key = "out" if old[0] == "gen" else "output"
        assert old_ns[key] is None and new_ns[key] == Path(old[-1] if old[0] == "gen" else old[2])
        old_ns[key] = new_ns[key]
    assert old_ns == new_ns
    assert new_err == "" and old_err.count("is deprecated, use") >= 1, old_err
    assert old_err.startswith("sharedlink: warning: ") and old_err.endswith("(the old spelling goes in the next release)\n")


#: `sharedlink ARGS` (``stdin``, ``cwd``, ``env`` as subprocess.run's)
_run = partial(run_cli, timeout=300)


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("drive")
    r = _run("gen", "-o", d / "drive.pcap", "--frames", "50")
    assert r.returncode == 0, r.stderr
    return d / "drive.pcap"


def test_old_positional_output_runs_with_the_note(tmp_path, drive):
    r = _run("compress", drive, tmp_path / "c.pcap")
    assert r.returncode == 0 and (tmp_path / "c.pcap").exists()
    assert r.stderr.startswith("sharedlink: warning: 'sharedlink compress OUT' is deprecated, use 'sharedlink compress -o OUT'")
    r = _run("compress", drive, tmp_path / "d.pcap", "-o", tmp_path / "e.pcap")
    assert r.returncode == 2 and "two outputs" in r.stderr and not (tmp_path / "e.pcap").exists()
    r = _run("gen", "--frames", "3")
    assert r.returncode == 2 and "no output: give -o FILE" in r.stderr


@pytest.mark.parametrize("command", ["stats", "export", "diff", "compress", "plot", "ingest"])
def test_impossible_variable_types_are_refused(tmp_path, drive, command):
    args = {"stats": [drive], "export": [drive], "diff": [drive, drive], "compress": [drive, "-o", tmp_path / "o.pcap"],
            "plot": [drive, "-o", tmp_path / "p.png"], "ingest": [drive, "-o", tmp_path / "ds"]}[command]
    r = _run(command, *args, "--variables", "A:9")
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "sharedlink: error: --variables: bad type '9' for A (types are 0 long, 2 double, 4 string)"], r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_unknown_names_are_refused_once_the_capture_is_read(tmp_path, drive):
    out = tmp_path / "x.csv"
    r = _run("export", drive, "--select", "AutoGpsLat,NoSuchVar", "-o", out)
    assert r.returncode == 2 and "no variable NoSuchVar in" in r.stderr and "AutoGpsLat" in r.stderr, r.stderr
    assert not out.exists()
    r = _run("export", drive, "--format", "geojson", "--lat", "Nope", "-o", tmp_path / "t.geojson")
    assert r.returncode == 2 and "no variable Nope" in r.stderr and not (tmp_path / "t.geojson").exists()
    for opt in ("--lat", "--lon", "--heading", "--velocity"):  # MCAP's LocationFix too, no file left behind
        r = _run("export", drive, opt, "Nope", "-o", tmp_path / "t.mcap")
        assert r.returncode == 2 and "no variable Nope" in r.stderr and not (tmp_path / "t.mcap").exists(), r.stderr
    r = _run("export", drive, "--velocity", "AutoGpsVel", "-o", tmp_path / "t.mcap")
    assert r.returncode == 0 and (tmp_path / "t.mcap").exists(), r.stderr
    for opt in ("--lat", "--lon", "--velocity", "--select"):
        r = _run("plot", drive, "-o", tmp_path / "p.png", opt, "Nope")
        assert r.returncode == 2 and "Nope" in r.stderr and r.stderr.count("\n") == 1, (opt, r.stderr)
        assert not (tmp_path / "p.png").exists()
    r = _run("export", drive, "--select", "AutoGpsLat", "-o", out)  # a known one is fine
    assert r.returncode == 0 and out.read_text().splitlines()[0].endswith(",AutoGpsLat")


def test_ingest_of_an_empty_folder_is_an_error(tmp_path):
    (tmp_path / "empty").mkdir()
    r = _run("ingest", tmp_path / "empty", "-o", tmp_path / "ds")
    assert r.returncode == 2 and r.stderr.strip() == f"sharedlink: error: {tmp_path / 'empty'}: no captures in this " \
        "directory (*.pcap, *.pcapng, *.cap)"


MISSING = [
    ["stats", "{m}"], ["export", "{m}"], ["plot", "{m}", "-o", "{t}/p.png"], ["compress", "{m}", "-o", "{t}/o.pcap"],
    ["expand", "{m}", "-o", "{t}/o.pcap"], ["diff", "{m}", "{m}"], ["replay", "{m}"], ["watch", "{m}"],
    ["serial", "import", "{m}", "-o", "{t}/o.pcapng"], ["ingest", "{m}", "-o", "{t}/ds"], ["query", "{m}", "SELECT 1"],
]


@pytest.mark.parametrize("argv", MISSING, ids=[a[0] if a[0] != "serial" else "serial import" for a in MISSING])
def test_a_missing_file_has_one_message(tmp_path, argv):
    missing = tmp_path / "missing.pcap"
    r = _run(*[a.format(m=missing, t=tmp_path) for a in argv])
    assert r.returncode == 2 and r.stderr == f"sharedlink: error: {missing}: no such file\n", r.stderr


def test_dash_reads_standard_input(tmp_path, drive):
    with open(drive, "rb") as fh:
        r = _run("stats", "-", "--json", stdin=fh)
    assert r.returncode == 0 and '"frames": 50' in r.stdout, r.stderr
    with open(drive, "rb") as fh:
        r = _run("diff", drive, "-", stdin=fh)
    assert r.returncode == 0 and "AGREE" in r.stdout, r.stderr
    r = _run("diff", "-", "-", stdin=subprocess.DEVNULL)
    assert r.returncode == 2 and "only one of the two" in r.stderr


def test_json_goes_to_standard_output(tmp_path, drive):
    r = _run("export", drive, "-o", tmp_path / "x.csv", "--json")
    assert r.returncode == 0 and r.stdout.startswith("{") and '"rows": 50' in r.stdout and r.stderr == ""
    r = _run("query", tmp_path / "nowhere", "SELECT 1", "--json")
    assert "--json" not in r.stderr  # the option exists (the dataset's absence is another matter)


def test_text_reads_right(tmp_path, drive):
    log = tmp_path / "one.txt"
    log.write_text("00000000  5b 3a 41 42 7c 4e 30 7c 44 31 7c 44 32 7c 43 35  |[:AB|N0|D1|D2|C5|\n"
                   "00000010  39 5d 0d 0a                                       |9]..|\n")
    r = _run("serial", "import", log, "-o", tmp_path / "one.pcapng", "--log-format", "hex", "--frame", "--chunk", "100")
    assert r.returncode == 0 and r.stderr.strip().endswith(": 1 record from a hex log (1 frame)"), r.stderr
    r = _run("compress", drive, "-o", tmp_path / "c.pcap")
    r = _run("diff", tmp_path / "c.pcap", drive)
    assert "B takes " in r.stdout and "more SharedLink bytes than A" in r.stdout and "saves -" not in r.stdout, r.stdout
    r = _run("watch", drive, "--speed", "1000")  # the view, redirected: its last line ends
    assert r.returncode == 0 and r.stdout.endswith("\n") and "AutoGpsLat" in r.stdout, (r.stdout[-200:], r.stderr)
    r = _run("plot", drive, "-o", tmp_path / "p.png", "--select", "AutoGpsVel")
    assert r.returncode == 0 and "track and 1 variable panel from 50 frames" in r.stderr, r.stderr


def _on_terminal(columns: int, *args) -> str:
    """The command's output on a pseudo-terminal ``columns`` wide, escapes removed."""
    env = dict(os.environ, COLUMNS=str(columns), LINES="60", TERM="xterm")
    code, out = on_pty([*CLI, *map(str, args)], env, timeout=300)
    assert code == 0
    return re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", out)


@pytest.fixture(scope="module")
def busy(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("busy")
    r = _run("gen", "-o", d / "busy.pcap", "--frames", "20000", "--compress", "--drop", "0.01", "--bad-checksum", "0.01",
             "--jitter", "50")
    assert r.returncode == 0, r.stderr
    return d / "busy.pcap"


@pytest.mark.parametrize("columns", [80, 50])
def test_stats_tables_fit_the_terminal(busy, columns):
    import json

    st = json.loads(_run("stats", busy, "--json").stdout)
    text = _on_terminal(columns, "stats", busy)
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= columns, text
    assert "…" not in text or "cut to fit: last" in text, text  # only the values as sent are cut, and said so
    for number in (st["frames"], st["bytes"], st["checksum_failures"]):  # counts: thousands separators
        assert re.search(rf"(?<![\d.,]){number:,}(?![\d.,])", text), (number, text)
    for v in st["variables"].values() if isinstance(st["variables"], dict) else st["variables"]:
        for key in ("min", "max"):  # the doubles of the beacon: every digit
            assert re.search(rf"(?<![\d.]){re.escape(repr(v[key]))}(?![\d])", text), (v, text)


@pytest.mark.parametrize("columns", [80, 50])
def test_diff_tables_fit_the_terminal(busy, tmp_path, columns):
    assert _run("compress", busy, "-o", tmp_path / "c.pcap").returncode == 0
    text = _on_terminal(columns, "diff", busy, tmp_path / "c.pcap")
    assert "…" not in text and max(len(line) for line in text.splitlines()) <= columns, text
    for name in ("AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel"):
        assert name in text, text  # never split across lines
    assert "19,8" in text or "19,7" in text  # the sample counts whole


def test_empty_inputs_are_reported(tmp_path):
    import struct

    empty = tmp_path / "empty.pcap"
    empty.write_bytes(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))  # a header, no record
    for argv, what in ((["stats", empty], "no SharedLink frames"), (["export", empty], "no SharedLink frames"),
                       (["plot", empty, "-o", tmp_path / "e.png"], "no SharedLink frames"),
                       (["diff", empty, empty], "no SharedLink frames"),
                       (["compress", empty, "-o", tmp_path / "c.pcap"], "no records")):
        r = _run(*argv)
        assert f"sharedlink: warning: {empty}: {what}\n" in r.stderr, (argv, r.stderr)


def test_plot_capture_select_and_the_old_variables(tmp_path, drive):
    import warnings

    pytest.importorskip("matplotlib")
    from sharedlink.analysis.plot import plot_capture

    data = plot_capture(drive, tmp_path / "a.png", select=["AutoGpsVel"], variables=[("AutoGpsVel", 2)])
    assert data.frames == 50 and (tmp_path / "a.png").stat().st_size > 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        plot_capture(drive, tmp_path / "b.png", variables=["AutoGpsVel"])
    assert any(issubclass(w.category, DeprecationWarning) and "select=" in str(w.message) for w in caught)
