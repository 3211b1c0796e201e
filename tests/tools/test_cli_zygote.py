"""`sl_cli.run_cli`'s zygote (`tests/sl_zygote.py`, docs/testing.md "The CLI zygote"): a run
forked from the loaded interpreter gives what a plain `python -m sharedlink` process gives (exit
code, standard output and error, byte for byte), with the test's standard input, environment and
working directory; a run past its timeout is killed; a run the zygote cannot reproduce is a
plain process; the zygote ends with the process that started it."""

from __future__ import annotations

import os
import select
import subprocess
import sys
from pathlib import Path

import pytest
import sl_zygote
from sl_cli import CLI, run_cli

ROOT = Path(__file__).resolve().parents[2]
BEACON = ROOT / "captures" / "beacon-full.pcap"
P2OS = ROOT / "tests" / "dissector" / "golden_small" / "p2os-serial.pcapng"


def plain(*args: object, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=kw.pop("text", True), timeout=120, **kw)


def forked(*args: object, **kw) -> subprocess.CompletedProcess:
    """``run_cli``, asserted to have gone through the zygote."""
    before = sl_zygote.TALLY[0]
    r = run_cli(*args, **kw)
    assert sl_zygote.TALLY[0] == before + 1, "not run by the zygote"
    return r


@pytest.mark.parametrize("args", [
    ["--version"],
    ["stats", BEACON],
    ["stats", "--json", BEACON],
    ["health", P2OS],
    ["stats", "no-such-file.pcap"],  # exit 2, the error on stderr
    ["stats", "--no-such-option"],  # usage error
    [],  # the commands' list
    ["diff", BEACON, ROOT / "captures" / "beacon-compressed.pcap"],
])
def test_a_forked_run_is_the_plain_process(args):
    want, got = plain(*args), forked(*args)
    assert (got.returncode, got.stdout, got.stderr) == (want.returncode, want.stdout, want.stderr)
    assert got.args == [*CLI, *map(str, args)]


def test_binary_output_standard_input_and_a_relative_path_in_the_working_directory(tmp_path):
    (tmp_path / "in.pcap").write_bytes(BEACON.read_bytes())
    args = ["export", "--format", "jsonl", "-o", "-", "in.pcap"]
    want, got = plain(*args, cwd=tmp_path, text=False), forked(*args, cwd=tmp_path, text=False)
    assert got.returncode == want.returncode == 0 and got.stdout == want.stdout and got.stdout.startswith(b"{")
    piped = ["watch", "-", "--speed", "1e6", "-q", "--json"]
    data = P2OS.read_bytes()
    want = plain(*piped, input=data, text=False)
    got = forked(*piped, input=data, text=False)
    assert (got.returncode, got.stdout, got.stderr) == (want.returncode, want.stdout, want.stderr)
    assert got.stdout.count(b"\n") > 10


def test_the_environment_is_the_runs(tmp_path):
    narrow = {**os.environ, "COLUMNS": "60"}
    wide = {**os.environ, "COLUMNS": "200"}
    a, b = forked("stats", "--help", env=narrow), forked("stats", "--help", env=wide)
    assert a.stdout != b.stdout  # argparse wraps its help to COLUMNS
    assert a.stdout == plain("stats", "--help", env=narrow).stdout
    assert b.stdout == plain("stats", "--help", env=wide).stdout
    home = {**os.environ, "HOME": str(tmp_path), "XDG_CONFIG_HOME": str(tmp_path / "config")}
    got = forked("plugins", "path", "--json", env=home)  # the folders tshark names, by its environment
    assert got.returncode == 0 and str(tmp_path) in got.stdout
    assert got.stdout == plain("plugins", "path", "--json", env=home).stdout


def test_an_interpreter_setting_of_its_own_runs_a_plain_process():
    before = sl_zygote.TALLY[0]
    r = run_cli("--version", env={**os.environ, "PYTHONWARNINGS": "error::DeprecationWarning"})
    assert r.returncode == 0 and r.stdout.startswith("sharedlink ")
    assert sl_zygote.TALLY[0] == before


def test_a_dead_zygote_leaves_plain_processes():
    script = ("import os, sys; sys.path.insert(0, %r); import sl_cli, sl_zygote;"
              "sl_cli.run_cli('--version', check=True); z = sl_zygote._zygote; z.proc.kill(); z.proc.wait();"
              "r = sl_cli.run_cli('--version', check=True); print(r.stdout.strip(), sl_zygote.TALLY[0])"
              % str(ROOT / "tests"))
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["sharedlink", plain("--version").stdout.split()[1], "1"]  # the second run plain


def test_a_run_past_its_timeout_is_killed(tmp_path):
    fifo = tmp_path / "never"
    os.mkfifo(fifo)  # opened by nobody else: `stats` waits on it for ever
    with pytest.raises(subprocess.TimeoutExpired):
        run_cli("stats", fifo, timeout=1)
    pid = sl_zygote.LAST_PID
    assert pid and not Path(f"/proc/{pid}").exists()  # killed and reaped before the exception


def test_the_zygote_ends_with_its_process(tmp_path):
    script = ("import os, sys; sys.path.insert(0, %r); import sl_cli, sl_zygote;"
              "sl_cli.run_cli('--version', check=True); print(sl_zygote._zygote.proc.pid, flush=True); os._exit(0)"
              % str(ROOT / "tests"))
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    pid = int(r.stdout)
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return  # gone already
    try:
        assert select.select([fd], [], [], 30)[0], "the zygote outlived its process"
    finally:
        os.close(fd)
