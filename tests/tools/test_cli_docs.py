"""The CLI as one vocabulary, and what helps people find it (issue 41, items 4 and 5):
docs/cli.md's option tables against the parsers both ways, examples in every --help that parse,
the man page fresh, completion scripts; the conventions: a bare ``sharedlink``, the subcommand's
usage on an unknown option, exit codes (SIGTERM 143 in replay and watch), ``stats --fail-on``,
``--quiet``, output suffixes, binary output to a terminal, serial ports and ``replay
--direction``, ``ingest --reingest``."""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tty
from functools import partial
from pathlib import Path

import pytest
from sl_cli import CLI, run_cli
from sl_pipes import on_pty

from sharedlink.capture.pcapio import read_records
from sharedlink.cli import _leaves, build_parser
from sharedlink.commands.examples import EXAMPLES
from sharedlink.problems import PROBLEMS

ROOT = Path(__file__).resolve().parents[2]
DOC = (ROOT / "docs" / "cli.md").read_text()
PARSERS = dict(_leaves(build_parser()))


def _options(p: argparse.ArgumentParser) -> set[str]:
    return {o for a in p._actions if a.help is not argparse.SUPPRESS for o in a.option_strings
            if o.startswith("--") and o != "--help"}


def _table(heading: str) -> list[list[str]]:
    """The rows of the first Markdown table after ``heading`` (cells stripped)."""
    text = DOC[DOC.index(heading):]
    rows = re.search(r"((?:^\|.*\|\n)+)", text, re.M)
    assert rows, heading
    cells = [[c.strip() for c in line.strip().strip("|").split(" | ")] for line in rows.group(1).splitlines()]
    return [r for r in cells[2:]]


def documented() -> dict[str, set[str]]:
    """Command -> the options docs/cli.md says it has (both tables)."""
    got: dict[str, set[str]] = {name: set() for name in PARSERS}
    for opts, _meaning, commands in _table("## Options: one name, one meaning"):
        names = re.findall(r"`(--[\w-]+)", opts)
        for command in re.sub(r"\([^)]*\)", "", commands).split(","):
            command = command.strip()
            assert command in got, (command, opts)
            got[command] |= set(names)
    for command, opts in _table("Options only one command has"):
        got[command] |= set(re.findall(r"`(--[\w-]+)", opts))
    return got


def test_docs_cli_md_and_the_parsers_agree_both_ways():
    docs = documented()
    missing = {n: sorted(_options(p) - docs[n]) for n, p in PARSERS.items() if _options(p) - docs[n]}
    extra = {n: sorted(docs[n] - _options(p)) for n, p in PARSERS.items() if docs[n] - _options(p)}
    assert not missing, f"options not in docs/cli.md: {missing}"
    assert not extra, f"docs/cli.md names options the command does not have: {extra}"


def test_the_fail_on_problems_are_documented():
    assert [r[0].strip("`") for r in _table("The problems, named in")] == list(PROBLEMS)


@pytest.mark.parametrize("name", sorted(PARSERS))
def test_every_command_has_examples_that_parse(name):
    assert name in EXAMPLES, name
    help_text = PARSERS[name].format_help()
    assert "examples:\n" in help_text
    for line, _what in EXAMPLES[name]:
        assert line in help_text
        words = shlex.split(line)
        assert words[0] == "sharedlink"
        ns = build_parser().parse_args([w for w in words[1:] if w != ">" and not w.startswith("~")])
        assert ns.command == name.split()[0]


def test_the_man_page_is_fresh():
    pytest.importorskip("argparse_manpage")
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "manpage.py"), "-"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout == (ROOT / "docs" / "sharedlink.1").read_text(), "docs/sharedlink.1 is stale: run make man"
    for name in PARSERS:
        assert f"'sharedlink {name}'" in r.stdout, name


@pytest.mark.parametrize("shell", ["bash", "zsh", "fish"])
def test_completion_scripts_name_every_command_and_parse(shell, tmp_path):
    r = run_cli("completion", shell, timeout=120)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    for word in ("gen", "stats", "export", "serial", "completion", "--fail-on", "--sync-interval"):
        assert word in r.stdout, (shell, word)
    if shutil.which(shell):  # the script is valid in its shell
        script = tmp_path / f"c.{shell}"
        script.write_text(r.stdout)
        check = subprocess.run([shell, "-n", str(script)], capture_output=True, text=True, timeout=60)
        assert check.returncode == 0, check.stderr


#: `sharedlink ARGS`
_run = partial(run_cli, timeout=300)


def test_bare_sharedlink_lists_the_commands_and_exits_0():
    r = _run()
    assert r.returncode == 0 and r.stderr == "", r.stderr
    for name in {n.split()[0] for n in PARSERS}:
        assert re.search(rf"^\s+{name}\b", r.stdout, re.M), name


def test_an_unknown_option_prints_the_subcommands_usage():
    r = _run("stats", "x.pcap", "--no-such-option")
    assert r.returncode == 2
    assert r.stderr.startswith("usage: sharedlink stats ") and r.stderr.endswith(
        "sharedlink: error: unrecognized arguments: --no-such-option\n"), r.stderr
    r = _run("serial", "capture", "/dev/x", "--nope")
    assert r.returncode == 2 and r.stderr.startswith("usage: sharedlink serial capture "), r.stderr


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("caps")
    clean, faulty, serial = d / "clean.pcap", d / "faulty.pcap", d / "serial.pcapng"
    assert _run("gen", "-o", clean, "--frames", "60").returncode == 0
    assert _run("gen", "-o", faulty, "--frames", "3000", "--compress", "--drop", "0.05", "--bad-checksum", "0.02",
                "--quiet").returncode == 0
    assert _run("gen", "-o", serial, "--transport", "serial", "--frames", "20").returncode == 0
    return {"clean": clean, "faulty": faulty, "serial": serial}


def test_stats_fail_on(captures):
    import json

    st = json.loads(_run("stats", captures["faulty"], "--json").stdout)
    assert st["checksum_failures"] > 1 and st["sync_gaps"] > 1  # the capture has both
    r = _run("stats", captures["faulty"], "--fail-on", "checksum,late")
    assert r.returncode == 1 and "frames" in r.stdout
    assert r.stderr == (f"sharedlink: failed: {st['checksum_failures']} bad checksums, {st['sync_gaps']} late full "
                        "sets (--fail-on checksum,late)\n"), r.stderr
    r = _run("stats", captures["faulty"], "--fail-on", "late", "--json")
    assert r.returncode == 1 and json.loads(r.stdout)["sync_gaps"] == st["sync_gaps"]
    assert _run("stats", captures["clean"], "--fail-on", "checksum,late").returncode == 0
    r = _run("stats", captures["clean"], "--fail-on", "checksum,nonsense")
    assert r.returncode == 2 and "nonsense: give one or more of checksum,late" in r.stderr


def test_quiet_silences_progress_and_summaries(captures, tmp_path):
    loud = _run("compress", captures["clean"], "-o", tmp_path / "a.pcap")
    assert loud.returncode == 0 and loud.stderr.startswith("wrote ")
    for argv in (["compress", captures["clean"], "-o", tmp_path / "b.pcap", "--quiet"],
                 ["gen", "-o", tmp_path / "g.pcap", "--frames", "5", "-q"],
                 ["export", captures["clean"], "-o", tmp_path / "x.csv", "-q"],
                 ["stats", captures["clean"], "-q"]):
        r = _run(*argv)
        assert r.returncode == 0 and r.stderr == "", (argv, r.stderr)
    r = _run("export", captures["clean"], "--select", "Nope", "-o", tmp_path / "y.csv", "-q")
    assert r.returncode == 2 and "Nope" in r.stderr  # errors still said
    # the progress bar too: on a terminal with the bar at once, it shows unless --quiet
    big = tmp_path / "big.pcap"  # (20,000 frames: long enough for the bar to be drawn, as in test_progress)
    assert _run("gen", "-o", big, "--frames", "20000", "--compress", "-q").returncode == 0
    env = dict(os.environ, SHAREDLINK_PROGRESS_AFTER="0", COLUMNS="120")
    _code, shown = on_pty([*CLI, "export", str(big), "-o", str(tmp_path / "p.csv")], env)
    _code, quiet = on_pty([*CLI, "export", str(big), "-o", str(tmp_path / "q.csv"), "--quiet"], env)
    assert "exporting:" in shown and quiet == "", (shown[-300:], quiet)


def test_an_output_suffix_of_no_format_is_refused(captures, tmp_path):
    r = _run("export", captures["clean"], "-o", tmp_path / "x.xlsx")
    assert r.returncode == 2 and ".xlsx is not a format written here" in r.stderr and "--format" in r.stderr
    r = _run("gen", "-o", tmp_path / "x.txt", "--frames", "3")
    assert r.returncode == 2 and ".txt is not a format written here" in r.stderr
    assert list(tmp_path.iterdir()) == []
    assert _run("export", captures["clean"], "-o", tmp_path / "x.txt", "--format", "jsonl").returncode == 0
    assert (tmp_path / "x.txt").read_text().startswith("{")


@pytest.mark.parametrize("argv", [["gen", "-o", "-", "--frames", "3"], ["compress", "{c}", "-o", "-"],
                                  ["serial", "capture", "/dev/null"]], ids=["gen", "compress", "serial capture"])
def test_binary_output_to_a_terminal_is_refused(captures, argv):
    code, out = on_pty([*CLI, *[a.format(c=captures["clean"]) for a in argv]], dict(os.environ))
    assert code == 2 and "standard output is a terminal" in out and "\xd4\xc3\xb2\xa1" not in out, out


def test_one_message_for_a_serial_port_that_does_not_open(captures, tmp_path):
    missing = tmp_path / "ttyNOPE"
    want = f"sharedlink: error: {missing}: cannot open it: No such file or directory\n"
    for argv in (["serial", "capture", missing, "-o", tmp_path / "x.pcapng"],
                 ["replay", captures["clean"], "--serial", missing],
                 ["watch", "--serial", missing]):
        r = _run(*argv)
        assert r.returncode == 2 and r.stderr == want, (argv, r.stderr)
    ns = build_parser().parse_args(["serial", "capture", "/dev/ttyUSB0"])
    assert ns.baud == 9600  # as everywhere else


def test_replay_serial_of_a_two_way_capture_takes_one_direction(captures):
    recs = [r for r in read_records(captures["serial"])]
    inbound = b"".join(r.data for r in recs if r.flags & 3 == 1)
    assert inbound and any(r.flags & 3 == 2 for r in recs)
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        r = _run("replay", captures["serial"], "--serial", os.ttyname(slave), "--topspeed")
        assert r.returncode == 2 and "holds both directions" in r.stderr and "--direction in" in r.stderr, r.stderr
        r = _run("replay", captures["serial"], "--serial", os.ttyname(slave), "--topspeed", "--direction", "in",
                 "--quiet")
        assert r.returncode == 0, r.stderr
        got = b""
        while len(got) < len(inbound):
            got += os.read(master, 65536)
        assert got == inbound
    finally:
        os.close(master)
        os.close(slave)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_sigterm_exits_143_in_replay_and_watch(captures):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(60)
        p = subprocess.Popen([*CLI, "replay", str(captures["clean"]), "--to", f"127.0.0.1:{rx.getsockname()[1]}",
                              "--loop", "0", "--pps", "200", "--quiet"], stderr=subprocess.PIPE, text=True)
        rx.recv(65536)  # it is sending
        p.send_signal(signal.SIGTERM)
        _out, err = p.communicate(timeout=60)
    assert p.returncode == 143 and "Traceback" not in err, err
    p = subprocess.Popen([*CLI, "watch", "--port", str(_free_port()), "--bind-port"], stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    assert "udp port" in p.stderr.readline()  # listening
    p.send_signal(signal.SIGTERM)
    _out, err = p.communicate(timeout=60)
    assert p.returncode == 143 and "Traceback" not in err, err


def test_ingest_reingest_and_the_old_force(captures, tmp_path):
    pytest.importorskip("pyarrow")
    ds = tmp_path / "ds"
    assert _run("ingest", captures["clean"], "-o", ds).returncode == 0
    r = _run("ingest", captures["clean"], "-o", ds)
    assert "unchanged" in r.stderr
    r = _run("ingest", captures["clean"], "-o", ds, "--reingest")
    assert r.returncode == 0 and "ingested" in r.stderr and "deprecated" not in r.stderr, r.stderr
    r = _run("ingest", captures["clean"], "-o", ds, "--force")
    assert r.returncode == 0 and "ingested:" in r.stderr, r.stderr
    assert r.stderr.startswith("sharedlink: warning: --force is deprecated, use --reingest")


def test_the_arrow_spelling_of_a_node_pair_is_read(captures):
    import json

    plain = json.loads(_run("stats", captures["clean"], "--json", "--variables", "B>A: a:2,b:2,c:2,d:2").stdout)
    arrow = json.loads(_run("stats", captures["clean"], "--json", "--variables", "B\u2192A: a:2,b:2,c:2,d:2").stdout)
    assert plain == arrow
