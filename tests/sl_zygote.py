"""``sharedlink`` runs forked from a loaded interpreter: what ``sl_cli.run_cli`` uses to spare
each run the interpreter's and the package's start-up (about 0.1 s of CPU of the 0.11-0.17 a
short run costs), docs/testing.md ("The CLI zygote").

One zygote a pytest process (each xdist worker), started on the first run: this file run as a
script, which imports ``sharedlink.cli``, every command's module and what they import, then
waits on a Unix socket. A run connects, the zygote forks a *waiter* for it and goes back to
waiting; the waiter receives the run's standard input, output and error as real descriptors
(``socket.send_fds``), its argument list, environment and working directory, forks the *run*
and reports its pid, then its wait status and CPU. The run is a real process running the real
command: descriptors 0-2 are the test's pipes, ``os.environ`` is the test's (``time.tzset()``
after it), the working directory the test's, ``sys.argv``, ``sys.path[0]`` and the standard
streams as ``python -m sharedlink`` has them; it runs ``sharedlink.__main__`` with ``runpy``
and ends as Python does (``SystemExit``'s code, a traceback and 1, non-daemon threads joined,
``atexit``, standard streams flushed: 120 if that fails). A run past its timeout is killed and
``subprocess.TimeoutExpired`` raised, as ``subprocess.run`` does.

:func:`run` returns ``None`` (the caller then starts a plain subprocess) when the run is not
one the zygote can reproduce: options beyond ``env``, ``cwd``, ``input`` and ``stdin``, an
environment whose interpreter settings differ from the zygote's (``PYTHON*``, the locale,
``MALLOC_*``, ``LD_*``), ``SHAREDLINK_ZYGOTE=0``, a process that is not the one that started
the zygote, or a zygote that would not start or has died. The zygote ends when its pytest
process does (its standard input is a pipe from it: end of file), and is waited for at exit.
"""

from __future__ import annotations

import atexit
import io
import json
import os
import selectors
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

_HERE = Path(__file__).resolve()
# environment variables read when an interpreter starts (or by libc then): a run whose values
# differ from the zygote's starts a plain process
_STARTUP_VARS = ("PYTHON", "LC_", "LANG", "MALLOC_", "LD_")
_ALLOWED_KW = {"env", "cwd", "input", "stdin"}

#: runs made through the zygote in this process: [count, CPU seconds] (the CPU probe reads it)
TALLY = [0, 0.0]
#: the pid of the last run started (tests)
LAST_PID = 0


def _startup_env(env: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in env.items() if k.startswith(_STARTUP_VARS)}


# --- the test's side ------------------------------------------------------------------------

class _Zygote:
    def __init__(self) -> None:
        self.owner = os.getpid()
        self.dir = tempfile.mkdtemp(prefix="sl-zygote-")
        self.path = os.path.join(self.dir, "sock")
        self.log = os.path.join(self.dir, "log")  # the zygote's and its waiters' standard error
        self.env = dict(os.environ)
        self.proc = subprocess.Popen(
            [sys.executable, str(_HERE), self.path], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            stderr=open(self.log, "wb"), env=self.env, cwd=self.dir)
        assert self.proc.stdout is not None
        ready = self.proc.stdout.readline()  # b"ready\n" once loaded and listening
        self.ok = ready == b"ready\n"
        atexit.register(self.close)

    def alive(self) -> bool:
        return self.ok and os.getpid() == self.owner and self.proc.poll() is None

    def close(self) -> None:
        if os.getpid() != self.owner:
            return
        try:
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            self.proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        shutil.rmtree(self.dir, ignore_errors=True)


_zygote: _Zygote | None = None
_starting = threading.Lock()


def _get() -> _Zygote | None:
    if os.environ.get("SHAREDLINK_ZYGOTE", "1") == "0":
        return None
    with _starting:  # runs from several threads of a test start one zygote
        return _started()


def _started() -> _Zygote | None:
    global _zygote
    if _zygote is None or (_zygote.owner != os.getpid()):
        if _zygote is not None:  # a forked copy of the pytest process: not its zygote
            return None
        try:
            _zygote = _Zygote()
        except OSError:
            return None
    return _zygote if _zygote.alive() else None


def run(cmd: list[str], timeout: float | None, text: bool, **kw: Any) -> subprocess.CompletedProcess[Any] | None:
    """``cmd`` (``sl_cli.CLI`` and the arguments) run as ``subprocess.run(cmd,
    capture_output=True, text=text, timeout=timeout, **kw)`` would, forked from the zygote; or
    ``None`` when the zygote cannot reproduce it (the caller starts a plain process)."""
    if not set(kw) <= _ALLOWED_KW or cmd[:3] != [sys.executable, "-m", "sharedlink"]:
        return None
    env = dict(os.environ if kw.get("env") is None else kw["env"])
    z = _get()
    if z is None or _startup_env(env) != _startup_env(z.env):
        return None
    cwd = os.path.abspath(os.fspath(kw["cwd"])) if kw.get("cwd") is not None else os.getcwd()
    data = kw.get("input")
    if isinstance(data, str):
        data = data.encode(_encoding())
    try:
        started = _Run(z, cmd, env, cwd, kw.get("stdin"), data)
    except OSError:  # the zygote went away before the run was handed over: a plain process
        return None
    return started.finish(timeout, text)


def _encoding() -> str:
    import locale

    return locale.getpreferredencoding(False)


class _Run:
    """One run: its pipes, its connection to the waiter, its pid once known."""

    def __init__(self, z: _Zygote, cmd: list[str], env: dict[str, str], cwd: str, stdin: Any,
                 data: bytes | None) -> None:
        self.zygote, self.cmd, self.data = z, cmd, data
        self.out_r, out_w = os.pipe()
        self.err_r, err_w = os.pipe()
        self.in_w: int | None = None
        close = [out_w, err_w]
        if data is not None or stdin == subprocess.PIPE:
            in_r, self.in_w = os.pipe()
            close.append(in_r)
        elif stdin is None:
            in_r = 0
        elif stdin == subprocess.DEVNULL:
            in_r = os.open(os.devnull, os.O_RDONLY)
            close.append(in_r)
        else:
            in_r = stdin if isinstance(stdin, int) else stdin.fileno()
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self.sock.connect(z.path)
            body = json.dumps({"argv": [str(a) for a in cmd[3:]], "env": env, "cwd": cwd}).encode()
            socket.send_fds(self.sock, [struct.pack("!Q", len(body))], [in_r, out_w, err_w])
            self.sock.sendall(body)
        except BaseException:
            self._close()
            raise
        finally:
            for fd in close:
                os.close(fd)
        self.pid = 0
        self.status: int | None = None
        self.cpu = 0.0
        self.buf = b""

    def _messages(self) -> None:
        while b"\n" in self.buf:
            line, self.buf = self.buf.split(b"\n", 1)
            msg = json.loads(line)
            if "pid" in msg:
                global LAST_PID
                self.pid = LAST_PID = msg["pid"]
            else:
                self.status, self.cpu = msg["status"], msg["cpu"]

    def finish(self, timeout: float | None, text: bool) -> subprocess.CompletedProcess[Any]:
        out: dict[int, list[bytes]] = {self.out_r: [], self.err_r: []}
        sel = selectors.DefaultSelector()
        for fd in out:
            sel.register(fd, selectors.EVENT_READ)
        sel.register(self.sock, selectors.EVENT_READ)
        pending = memoryview(self.data or b"")
        if self.in_w is not None:
            if pending:
                os.set_blocking(self.in_w, False)
                sel.register(self.in_w, selectors.EVENT_WRITE)
            else:
                os.close(self.in_w)
                self.in_w = None
        deadline = None if timeout is None else time.monotonic() + timeout
        open_fds = 3
        try:
            while open_fds:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    self._kill_and_wait()
                    raise subprocess.TimeoutExpired(self.cmd, timeout, b"".join(out[self.out_r]),
                                                    b"".join(out[self.err_r]))
                for key, _ in sel.select(left):
                    fd = key.fd
                    if fd == self.in_w:
                        try:
                            n = os.write(fd, pending[:65536])
                        except BrokenPipeError:
                            n = len(pending)
                        pending = pending[n:]
                        if not pending:
                            sel.unregister(fd)
                            os.close(fd)
                            self.in_w = None
                        continue
                    chunk = os.read(fd, 65536) if fd != self.sock.fileno() else self.sock.recv(65536)
                    if fd == self.sock.fileno():
                        self.buf += chunk
                        self._messages()
                    elif chunk:
                        out[fd].append(chunk)
                    if not chunk:
                        sel.unregister(fd)
                        open_fds -= 1
        finally:
            sel.close()
            self._close()
        if self.status is None:  # the waiter died: no status to give
            raise RuntimeError(f"sl_zygote: no exit status for {self.cmd}: {self.log_tail()}")
        TALLY[0] += 1
        TALLY[1] += self.cpu
        code = (-os.WTERMSIG(self.status) if os.WIFSIGNALED(self.status)
                else os.WEXITSTATUS(self.status))
        stdout, stderr = b"".join(out[self.out_r]), b"".join(out[self.err_r])
        if text:
            stdout, stderr = _decode(stdout), _decode(stderr)
        return subprocess.CompletedProcess(self.cmd, code, stdout, stderr)

    def log_tail(self) -> str:
        try:
            return Path(self.zygote.log).read_text(errors="replace")[-2000:]
        except OSError:
            return "(no log)"

    def _kill_and_wait(self) -> None:
        """As ``subprocess.run`` on a timeout: SIGKILL, then the status."""
        if self.pid:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self.sock.settimeout(30)
        while self.status is None:
            chunk = self.sock.recv(65536)
            if not chunk:
                break
            self.buf += chunk
            self._messages()

    def _close(self) -> None:
        for fd in (self.out_r, self.err_r, self.in_w):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.sock.close()


def _decode(data: bytes) -> str:
    """As ``subprocess.run(text=True)``: the locale's encoding, universal newlines."""
    return io.TextIOWrapper(io.BytesIO(data), encoding=_encoding()).read()


# --- the zygote's side ----------------------------------------------------------------------

# modules not loaded ahead: the fleet's (pyarrow and numpy start threads: no fork after that)
# and scapy's layer (not the CLI's)
_NOT_AHEAD = ("sharedlink.fleet", "sharedlink.scapy_layer", "sharedlink.__main__")


def _load() -> str:
    """What the runs share: the CLI and the package's modules, as the runs import them (each
    its command's and what that command imports when it runs); why not to serve, or ""."""
    import importlib
    import pkgutil

    import sharedlink

    for mod in pkgutil.walk_packages(sharedlink.__path__, "sharedlink."):
        if not mod.name.startswith(_NOT_AHEAD):
            importlib.import_module(mod.name)
    import rich.console  # noqa: F401 - every table and progress bar
    import rich.table  # noqa: F401

    threads = Path("/proc/self/status").read_text().split("Threads:")[1].split()[0]
    return "" if threads == "1" else f"{threads} threads after loading: no fork"


def _serve(path: str) -> None:
    with tempfile.TemporaryFile() as said:  # what loading wrote on stderr (a warning): refuse
        keep = os.dup(2)
        os.dup2(said.fileno(), 2)
        try:
            why = _load()
        finally:
            sys.stderr.flush()
            os.dup2(keep, 2)
            os.close(keep)
        if os.fstat(said.fileno()).st_size:
            said.seek(0)
            why = "loading wrote on stderr:\n" + said.read().decode(errors="replace")
        if why:
            sys.stderr.write(f"sl_zygote: not serving: {why}\n")
            return
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(64)
    # waiters reaped as they end (SIGCHLD wakes the loop), so that their CPU and their runs' is
    # counted in ours, and ours in the pytest process's (SIG_IGN would drop it from the count)
    woken_r, woken_w = os.pipe()
    os.set_blocking(woken_w, False)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    signal.set_wakeup_fd(woken_w)
    os.write(1, b"ready\n")
    sel = selectors.DefaultSelector()
    sel.register(listener, selectors.EVENT_READ)
    sel.register(0, selectors.EVENT_READ)
    sel.register(woken_r, selectors.EVENT_READ)
    waiters = 0
    while True:
        for key, _ in sel.select():
            if key.fd == woken_r:
                os.read(woken_r, 4096)
                waiters -= _reap(block=False)
            elif key.fd == 0:  # the pytest process closed our stdin or is gone
                if not os.read(0, 4096):
                    sel.unregister(0)
                    _reap(block=True, count=waiters)  # the runs still going end as they would
                    return
            else:
                conn, _ = listener.accept()
                if os.fork() == 0:
                    try:
                        signal.set_wakeup_fd(-1)
                        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                        for fd in (woken_r, woken_w):
                            os.close(fd)
                        listener.close()
                        sel.close()
                        _waiter(conn)
                    finally:
                        os._exit(0)
                waiters += 1
                conn.close()


def _reap(block: bool, count: int = 0) -> int:
    """Waiters reaped: every one that has ended, or (``block``) ``count`` of them."""
    reaped = 0
    while True:
        try:
            pid, _ = os.waitpid(-1, 0 if block else os.WNOHANG)
        except ChildProcessError:
            return reaped
        if pid == 0:
            return reaped
        reaped += 1
        if block and reaped >= count:
            return reaped


def _recv_exact(conn: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise EOFError
        data += chunk
    return data


def _waiter(conn: socket.socket) -> None:
    head, fds, _, _ = socket.recv_fds(conn, 8, 3)
    head += _recv_exact(conn, 8 - len(head))
    req = json.loads(_recv_exact(conn, struct.unpack("!Q", head)[0]))
    pid = os.fork()
    if pid == 0:
        try:
            conn.close()
            _child(req, fds)
        except BaseException:  # the set-up failed: said on the run's stderr (or the zygote's log)
            import traceback

            traceback.print_exc()
            sys.stderr.flush()
        finally:
            os._exit(1)
    for fd in fds:
        os.close(fd)
    conn.sendall(json.dumps({"pid": pid}).encode() + b"\n")
    _, status, ru = os.wait4(pid, 0)
    conn.sendall(json.dumps({"status": status, "cpu": ru.ru_utime + ru.ru_stime}).encode() + b"\n")


def _std(fd: int, write: bool, like: io.TextIOWrapper) -> io.TextIOWrapper:
    """A standard stream as Python's start-up makes it (closefd false, newline "\\n", line
    buffered on a terminal, and stderr always; output unbuffered under ``PYTHONUNBUFFERED``)."""
    raw = io.FileIO(fd, "wb" if write else "rb", closefd=False)
    unbuffered = write and isinstance(like.buffer, io.FileIO)  # as the zygote's own (same settings)
    buf: Any = raw if unbuffered else io.BufferedWriter(raw) if write else io.BufferedReader(raw)
    return io.TextIOWrapper(buf, encoding=like.encoding, errors=like.errors, newline="\n",
                            line_buffering=raw.isatty() or fd == 2, write_through=like.write_through)


def _child(req: dict[str, Any], fds: list[int]) -> None:
    for target, fd in enumerate(fds):  # received as new descriptors, each above 2
        os.dup2(fd, target)
    for fd in fds:
        os.close(fd)
    os.chdir(req["cwd"])
    os.environ.clear()
    os.environ.update(req["env"])
    time.tzset()
    sys.path[0] = req["cwd"]
    sys.stdin = sys.__stdin__ = _std(0, False, sys.stdin)
    sys.stdout = sys.__stdout__ = _std(1, True, sys.stdout)
    sys.stderr = sys.__stderr__ = _std(2, True, sys.stderr)
    sys.argv = ["-m", *req["argv"]]
    os._exit(_main())


def _main() -> int:
    """``sharedlink.__main__`` run and ended as ``python -m sharedlink`` ends."""
    import runpy
    import traceback

    code = 0
    try:
        runpy.run_module("sharedlink", run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        if exc.code is None:
            code = 0
        elif isinstance(exc.code, int):
            code = exc.code & 0xFF
        else:
            print(exc.code, file=sys.stderr)
            code = 1
    except KeyboardInterrupt:
        traceback.print_exc()
        code = -signal.SIGINT
    except BaseException:
        traceback.print_exc()
        code = 1
    threading._shutdown()  # type: ignore[attr-defined]  # non-daemon threads joined, as at exit
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            if stream is sys.stdout:
                code = 120
    if code == -signal.SIGINT:  # an uncaught Ctrl-C ends a Python program by SIGINT
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGINT)
    return code


if __name__ == "__main__":
    sys.path.pop(0)  # not tests/: the zygote imports what `python -m sharedlink` imports
    _serve(sys.argv[1])
