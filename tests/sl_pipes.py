"""A standard output whose reader lags, for Ctrl-C tests of commands that stream to it: a pipe
that holds one page, the moment the command waits inside a write to it, and reading it all
afterwards (Linux: F_SETPIPE_SZ and /proc/PID/wchan)."""

from __future__ import annotations

import os
import select
import threading
import time

import pytest


def one_page_pipe() -> tuple[int, int]:
    """(read end, write end) of a pipe that holds one page: a longer write blocks part-way."""
    fcntl = pytest.importorskip("fcntl")
    if not hasattr(fcntl, "F_SETPIPE_SZ"):
        pytest.skip("needs F_SETPIPE_SZ (Linux)")
    r, w = os.pipe()
    fcntl.fcntl(w, fcntl.F_SETPIPE_SZ, 4096)
    return r, w


def _wchan(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/wchan") as fh:
            return fh.read()
    except OSError:
        return ""


def wait_in_kernel(pid: int, where: tuple[str, ...], timeout: float = 30) -> str:
    """Until process ``pid`` sleeps in one of the kernel functions ``where`` (substrings of
    /proc/PID/wchan), polled (the kernel has no event for it); its wchan then. Skips where /proc
    does not tell (no wchan, or only "0")."""
    end = time.monotonic() + timeout
    seen = ""
    while time.monotonic() < end:
        seen = _wchan(pid)
        if any(w in seen for w in where):
            return seen
        time.sleep(0.005)
    if seen in ("", "0"):
        pytest.skip("/proc/PID/wchan does not show where a process waits")
    raise AssertionError(f"process {pid} never waited in {where} (last seen in {seen!r})")


def wait_writing(pid: int, timeout: float = 30) -> None:
    """Until process ``pid`` waits inside a write to a pipe (the kernel's ``pipe_write``, or
    ``anon_pipe_write``)."""
    wait_in_kernel(pid, ("pipe_write",), timeout)


def wait_selecting(pid: int, timeout: float = 30) -> None:
    """Until process ``pid`` waits for input in select/poll/epoll (a capture loop's idle state:
    its ports opened and set up)."""
    wait_in_kernel(pid, ("epoll_wait", "ep_poll", "do_select", "do_sys_poll", "poll_schedule"), timeout)


def signal_taken(pid: int, sig: int, timeout: float = 30) -> None:
    """Until signal ``sig`` sent to process ``pid`` is no longer pending (its handler has run
    in the kernel's view: the signal came while the process was where it was), polled from
    /proc/PID/status; returns at once when the process is gone."""
    bit = 1 << (sig - 1)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            status = open(f"/proc/{pid}/status").read()
        except OSError:
            return
        pending = [int(line.split()[1], 16) for line in status.splitlines() if line.startswith(("SigPnd:", "ShdPnd:"))]
        if "State:\tZ" in status or not any(p & bit for p in pending):
            return
        time.sleep(0.001)
    raise AssertionError(f"signal {sig} still pending in process {pid} after {timeout} s")


def _on_inotify(path: str | os.PathLike, mask: int, check, timeout: float, what: str):
    """``check()``'s first true answer, asked again at each inotify event ``mask`` on ``path``
    (select on its descriptor, Linux; a poll elsewhere)."""
    import ctypes
    import ctypes.util

    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    fd = libc.inotify_init1(os.O_NONBLOCK) if hasattr(libc, "inotify_init1") else -1
    try:
        if fd >= 0 and libc.inotify_add_watch(fd, os.fsencode(path), mask) < 0:  # (no such path yet: a poll)
            os.close(fd)
            fd = -1
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            got = check()
            if got:
                return got
            if fd >= 0:
                if select.select([fd], [], [], left)[0]:
                    os.read(fd, 65536)
            else:  # pragma: no cover - no inotify
                time.sleep(0.01)
    finally:
        if fd >= 0:
            os.close(fd)
    raise AssertionError(f"{what} not within {timeout} s")


def wait_created(folder: str | os.PathLike, wanted, timeout: float = 60) -> str:
    """The first name in ``folder`` for which ``wanted(name)`` holds, waiting for its creation."""
    return _on_inotify(folder, 0x100 | 0x80, lambda: next((n for n in os.listdir(folder) if wanted(n)), None), timeout,
                       f"a file wanted in {folder}")  # IN_CREATE | IN_MOVED_TO


def wait_written(path: str | os.PathLike, done, timeout: float = 10) -> bool:
    """Until ``done()`` holds, asked again each time ``path`` is written to (IN_MODIFY)."""
    return _on_inotify(path, 0x2, lambda: bool(done()) or None, timeout, f"what was wanted of {path}")


def read_lines(fd: int, n: int, timeout: float = 60) -> bytes:
    """Bytes read from ``fd`` until they hold ``n`` lines: each read waits on the descriptor
    becoming readable (select), not on a clock; ``timeout`` only guards against a hang."""
    got = bytearray()
    end = time.monotonic() + timeout
    nl = b"\n"
    while got.count(nl) < n:
        left = end - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            raise AssertionError(f"{got.count(nl)} of {n} lines after {timeout} s: {bytes(got[-500:])!r}")
        chunk = os.read(fd, 65536)
        if not chunk:
            raise AssertionError(f"the end after {got.count(nl)} of {n} lines: {bytes(got[-500:])!r}")
        got += chunk
    return bytes(got)


def drain(r: int) -> tuple[threading.Thread, bytearray]:
    """Read ``r`` to its end in a thread (closing it then); the bytes gather in the bytearray."""
    got = bytearray()

    def run() -> None:
        while chunk := os.read(r, 65536):
            got.extend(chunk)
        os.close(r)

    t = threading.Thread(target=run)
    t.start()
    return t, got


def read_to_end(proc, r: int, timeout: float) -> tuple[bytearray, str]:
    """Read pipe ``r`` to its end while waiting for ``proc`` (killed if it still runs after
    ``timeout`` seconds, then the TimeoutExpired raised); (the bytes read, its standard error)."""
    reader, got = drain(r)
    try:
        _out, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
        reader.join(timeout)
    return got, err


def environment(unbuffered: str) -> dict[str, str]:
    """This environment with PYTHONUNBUFFERED set to ``unbuffered``, or removed when empty."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    if unbuffered:
        env["PYTHONUNBUFFERED"] = unbuffered
    return env


def on_pty(cmd: list[str], env: dict[str, str], timeout: float = 120) -> tuple[int, str]:
    """Run ``cmd`` with stdout and stderr on one pseudo-terminal (stdin empty): (exit code, all
    it wrote there, decoded). For what a command shows a person: progress bars, fitted tables."""
    import pty
    import subprocess

    master, slave = pty.openpty()
    try:
        p = subprocess.Popen(cmd, stdout=slave, stderr=slave, stdin=subprocess.DEVNULL, env=env)
        os.close(slave)
        out = b""
        while True:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: the command closed its end
                break
            if not chunk:
                break
            out += chunk
        return p.wait(timeout=timeout), out.decode("utf-8", "replace")
    finally:
        os.close(master)
