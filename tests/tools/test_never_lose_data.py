"""Every command that writes never loses data: it refuses to write over its input (same inode),
writes standard output, /dev/stdout and FIFOs in place, leaves nothing behind and the old file
as it was on a full disk (a file-size limit in the subprocess), and cleans up on SIGTERM as on
Ctrl-C."""

from __future__ import annotations

import hashlib
import os
import resource
import signal
import stat
import subprocess
import sys
import threading
import time
from functools import partial
from pathlib import Path

import pytest
from sl_cli import CLI, run_cli
from sl_pipes import wait_created

from sharedlink.generators.beacon import GenOptions, generate_file
from tshark_util import fields


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("keep") / "in.pcap"
    generate_file(GenOptions(frames=600), p)
    return p


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


#: `sharedlink ARGS`, its output as bytes
cli = partial(run_cli, text=False)


def sl_frames(path: Path) -> int:
    return len(fields(path, ["frame.number"], display_filter="sharedlink"))


def _writers(inp: Path, out: Path) -> dict[str, list[object]]:
    """Each writing command with ``inp`` as input and ``out`` as output."""
    return {
        "export": ["export", inp, "-o", out, "--format", "csv"],
        "compress": ["compress", inp, "-o", out],
        "expand": ["expand", inp, "-o", out],
        "plot": ["plot", inp, "-o", out],
        "serial import": ["serial", "import", inp, "-o", out, "--log-format", "raw"],
    }


# -- output = input ---------------------------------------------------------------------------


@pytest.mark.parametrize("command, how", [
    ("export", "same path"), ("plot", "same path"), ("compress", "hard link"), ("serial import", "hard link"),
    ("expand", "symbolic link"),
])
def test_output_that_is_the_input_is_refused(capture, tmp_path, command, how):
    inp = tmp_path / "in.png"  # plot wants an image name; every reader goes by content
    inp.write_bytes(capture.read_bytes())
    out = inp
    if how == "hard link":
        out = tmp_path / "other.png"
        os.link(inp, out)
    elif how == "symbolic link":
        out = tmp_path / "other.png"
        out.symlink_to(inp.name)
    before = digest(inp)
    r = cli(*_writers(inp, out)[command])
    assert r.returncode == 2, r.stderr
    assert b"is the input" in r.stderr and b"Traceback" not in r.stderr
    assert digest(inp) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({inp.name, out.name})


# -- streams and special files ------------------------------------------------------------------


@pytest.mark.parametrize("target", ["-", "/dev/stdout"])
def test_standard_output_is_written_in_place(capture, tmp_path, target):
    r = cli("compress", capture, "-o", target)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "piped.pcap"
    out.write_bytes(r.stdout)
    assert sl_frames(out) == 600
    assert os.path.islink("/dev/stdout")
    r = cli("export", capture, "-o", target)
    assert r.returncode == 0 and r.stdout.count(b"\n") == 601, r.stderr


def test_dev_stdout_redirected_to_a_file(capture, tmp_path):
    out = tmp_path / "redirected.csv"
    with open(out, "wb") as fh:
        r = subprocess.run([*CLI, "export", str(capture), "-o", "/dev/stdout"], stdout=fh, stderr=subprocess.PIPE, timeout=120)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes().count(b"\n") == 601
    assert os.path.islink("/dev/stdout")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["redirected.csv"]


def test_fifo_stays_a_fifo(capture, tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    got: list[bytes] = []

    def reader() -> None:
        with open(fifo, "rb") as fh:
            got.append(fh.read())

    t = threading.Thread(target=reader)
    t.start()
    r = cli("compress", capture, "-o", fifo)
    t.join(60)
    assert r.returncode == 0, r.stderr
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    out = tmp_path / "from-fifo.pcap"
    out.write_bytes(got[0])
    assert sl_frames(out) == 600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "from-fifo.pcap"]


# -- full disk --------------------------------------------------------------------------------


def _file_size_limit(limit: int):
    def apply() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes fail with EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


@pytest.mark.parametrize("command", ["export", "compress", "expand", "plot", "gen", "serial import"])
def test_full_disk_leaves_the_old_file_and_nothing_else(capture, tmp_path, command):
    suffix = {"export": ".csv", "plot": ".png"}.get(command, ".pcap")
    out = tmp_path / f"out{suffix}"
    out.write_bytes(b"the previous version")
    args = _writers(capture, out).get(command) or ["gen", "--frames", "5000", "-o", out]
    # no bytecode written under the limit: Python keeps a .pyc cut at 8,000 bytes (it does not
    # check the write) and every later import of that module fails (seen: matplotlib's, after
    # `pip --no-compile` left them to the first import, broke every plot test after this one)
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    r = cli(*args, preexec_fn=_file_size_limit(8000), env=env)
    assert r.returncode == 2, r.stderr
    assert b"sharedlink: error:" in r.stderr and b"Traceback" not in r.stderr, r.stderr
    assert str(out).encode() in r.stderr
    assert out.read_bytes() == b"the previous version"
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


# -- signals ----------------------------------------------------------------------------------


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_while_writing_cleans_up(tmp_path, sig, code):
    out = tmp_path / "big.pcap"
    proc = subprocess.Popen([*CLI, "gen", "--frames", "20000000", "-o", str(out)], stderr=subprocess.PIPE)
    wait_created(tmp_path, lambda name: name.endswith(".part"))
    assert proc.poll() is None
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert b"Traceback" not in err
    assert list(tmp_path.iterdir()) == []


_CTRL_C_AT_IMPORT = """
import os, signal, sys
target = sys.argv[1]
def hook(event, args):
    if event == "import" and args[0] == target:
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C just as this module starts loading
sys.addaudithook(hook)
from sharedlink.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize("module", [
    "sharedlink.protocols.codec",  # while the package loads
    "argparse",  # while the command line loads the standard library's modules
    "sharedlink.commands",  # while the command line loads
    "sharedlink.defaults",  # while the parser is built
    "sharedlink.analysis.stats",  # while the command runs
])
def test_ctrl_c_while_the_command_loads(capture, module):
    """Ctrl-C at any moment once the package starts loading: 130 and one line, no traceback
    (before that Python itself is starting, out of our hands)."""
    r = subprocess.run([sys.executable, "-c", _CTRL_C_AT_IMPORT, module, "stats", str(capture)],
                       capture_output=True, timeout=120)
    assert r.returncode == 130, r.stderr
    assert r.stderr == b"sharedlink: interrupted\n"


# -- symbolic links, failures before writing, special inputs ------------------------------------


def _writer_args(command: str, inp: Path, out: Path) -> list[object]:
    return _writers(inp, out).get(command) or ["gen", "--frames", "50", "-o", out]


@pytest.mark.parametrize("command", ["export", "compress", "expand", "plot", "gen", "serial import"])
@pytest.mark.parametrize("dangling", [False, True])
def test_output_through_a_symbolic_link_is_refused(capture, tmp_path, command, dangling):
    """An output that is a symbolic link onto another file (or onto nothing) is refused with one
    line and exit 2: the link's target is neither written nor created (before, it was replaced,
    or created through a dangling link)."""
    suffix = {"export": ".csv", "plot": ".png"}.get(command, ".pcap")
    target = tmp_path / f"precious{suffix}"
    if not dangling:
        target.write_bytes(b"someone else's file")
    out = tmp_path / f"out{suffix}"
    out.symlink_to(target)
    r = cli(*_writer_args(command, capture, out))
    assert r.returncode == 2, r.stderr
    assert r.stderr.count(b"\n") == 1 and b"symbolic link" in r.stderr and b"--force" in r.stderr, r.stderr
    assert out.is_symlink()
    if dangling:
        assert not target.exists()
    else:
        assert target.read_bytes() == b"someone else's file"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({out.name} | ({target.name} if not dangling else set()))


@pytest.mark.parametrize("command", ["export", "compress", "gen", "serial import"])
def test_force_replaces_the_link_itself(capture, tmp_path, command):
    suffix = ".csv" if command == "export" else ".pcap"
    target = tmp_path / f"precious{suffix}"
    target.write_bytes(b"someone else's file")
    out = tmp_path / f"out{suffix}"
    out.symlink_to(target)
    r = cli(*_writer_args(command, capture, out), "--force")
    assert r.returncode == 0, r.stderr
    assert not out.is_symlink() and out.stat().st_size > 100
    assert target.read_bytes() == b"someone else's file"


@pytest.mark.parametrize("args, suffix", [
    (["export", "--format", "jsonl"], ".jsonl"), (["export", "--format", "geojson"], ".geojson"),
    (["export", "--format", "kml"], ".kml"), (["export", "--format", "mcap"], ".mcap"),
    (["plot"], ".svg"), (["plot"], ".pdf"),
])
@pytest.mark.parametrize("dangling", [False, True])
def test_every_output_format_refuses_a_link(capture, tmp_path, args, suffix, dangling):
    """Each format's writer (MCAP through foxglove-sdk, the images through matplotlib) goes
    through the same check: a link onto another file, or onto nothing, is refused."""
    target = tmp_path / f"precious{suffix}"
    if not dangling:
        target.write_bytes(b"someone else's file")
    out = tmp_path / f"out{suffix}"
    out.symlink_to(target)
    r = cli(args[0], capture, *args[1:], "-o", out)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count(b"\n") == 1 and b"symbolic link" in r.stderr, r.stderr
    assert out.is_symlink() and (not target.exists() if dangling else target.read_bytes() == b"someone else's file")


def test_serial_capture_from_an_open_port_refuses_a_link(tmp_path):
    """`serial capture` with a device that opens (a pty): its -o link is refused all the same,
    before a byte is read."""
    m, s = os.openpty()
    try:
        target = tmp_path / "precious.pcapng"
        target.write_bytes(b"someone else's file")
        out = tmp_path / "out.pcapng"
        out.symlink_to(target)
        r = cli("serial", "capture", os.ttyname(s), "--baud", "9600", "-o", out, "--duration", "1")
    finally:
        os.close(m)
        os.close(s)
    assert r.returncode == 2 and r.stderr.count(b"\n") == 1 and b"symbolic link" in r.stderr, r.stderr
    assert target.read_bytes() == b"someone else's file" and out.is_symlink()


@pytest.mark.parametrize("command", ["export", "export --format mcap", "export --format kml", "compress", "expand", "plot"])
@pytest.mark.parametrize("damage", ["not a capture", "no such file", "unknown --select"])
def test_a_command_that_fails_before_writing_leaves_the_old_output(capture, tmp_path, command, damage):
    """The input is not a capture, is missing, or an option names a variable the capture lacks:
    one line, exit 2, and the existing output as it was, nothing else left."""
    suffix = {"export": ".csv", "plot": ".png", "export --format mcap": ".mcap", "export --format kml": ".kml"}.get(command, ".pcap")
    if damage == "unknown --select" and command in ("compress", "expand"):
        pytest.skip("no --select")
    out = tmp_path / f"old{suffix}"
    out.write_bytes(b"the previous version")
    inp = capture
    if damage == "not a capture":
        inp = tmp_path / "junk.pcap"
        inp.write_bytes(b"garbage-not-a-capture" * 10)
    elif damage == "no such file":
        inp = tmp_path / "missing.pcap"
    name, *opts = command.split()
    extra = ["--select", "NoSuchVariable"] if damage == "unknown --select" else []
    r = cli(name, inp, *opts, *extra, "-o", out)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count(b"\n") == 1 and b"Traceback" not in r.stderr, r.stderr
    assert out.read_bytes() == b"the previous version"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({out.name} | ({inp.name} if inp.parent == tmp_path and inp.exists() else set()))


def test_serial_capture_that_cannot_open_its_device_leaves_the_old_file(tmp_path):
    """`serial capture` opens its output once its port is open: a missing device is one line and
    exit 2, and the existing --out file stays as it was (before, it was emptied into a pcapng
    header)."""
    out = tmp_path / "old.pcapng"
    out.write_bytes(b"yesterday's capture")
    r = cli("serial", "capture", tmp_path / "no-such-tty", "--baud", "9600", "-o", out)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count(b"\n") == 1 and b"no-such-tty" in r.stderr and b"Traceback" not in r.stderr
    assert out.read_bytes() == b"yesterday's capture"
    link = tmp_path / "link.pcapng"
    link.symlink_to(out)
    r = cli("serial", "capture", tmp_path / "no-such-tty", "--baud", "9600", "-o", link)
    assert r.returncode == 2 and b"symbolic link" in r.stderr, r.stderr
    assert out.read_bytes() == b"yesterday's capture"


@pytest.mark.parametrize("command", [["export", "/dev/null", "-o", "-"], ["export", "/dev/null", "-o", "-", "--format", "jsonl"],
                                     ["replay", "/dev/null", "-q"], ["stats", "/dev/null"], ["compress", "/dev/null", "-o", "-"],
                                     ["diff", "/dev/null", "/dev/null"], ["watch", "/dev/null", "--json"]])
def test_dev_null_is_named_in_the_message(command):
    """Inputs that are not regular files are read once into a spool copy: messages still name
    the user's file, never the spool (before: /tmp/sharedlink-XXXX.spool)."""
    r = cli(*command)
    assert r.returncode == 2, r.stderr
    assert b"/dev/null: file header: empty file" in r.stderr and b"spool" not in r.stderr, r.stderr


def _children(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return []


def test_ctrl_c_to_diffs_process_group_is_one_line(tmp_path):
    """Ctrl-C at a terminal goes to the whole process group, diff's reader processes too: exit
    130 and one line (before, a reader printed a traceback: the parent's SIGTERM, meant to stop
    it, ran the command's own handler inside it)."""
    a, b = tmp_path / "a.pcap", tmp_path / "b.pcap"
    # big enough that the diff runs well past the last moment (150,000 frames took 0.45 s since
    # the readers got faster: a Ctrl-C after it ended met Python's own SIGINT at exit, -2)
    generate_file(GenOptions(frames=600_000, compress=True), a)
    generate_file(GenOptions(frames=600_000), b)
    for delay in (0.0, 0.02, 0.3):
        proc = subprocess.Popen([*CLI, "diff", str(a), str(b)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                start_new_session=True)
        deadline = time.monotonic() + 60
        while len(_children(proc.pid)) < 2:  # both readers running
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.01)
        time.sleep(delay)  # (the moment of the Ctrl-C: at once, soon, well into the run; no wait for anything)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err
        assert err == b"sharedlink: interrupted\n", err
