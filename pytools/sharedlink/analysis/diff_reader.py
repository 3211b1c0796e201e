"""The reader process of a side of ``sharedlink diff`` (:mod:`sharedlink.analysis.diff`): one
capture's change records (:func:`~sharedlink.analysis.changes.read_changes`) read in a child
process and sent to the parent through a pipe, chunk by chunk, then the side's stats.

The child keeps the garbage collector on but runs it seldom (:data:`GC_THRESHOLD`); the parent
takes the messages off the pipe in a thread as they come, so the reader never waits for the
aligner; Ctrl-C and SIGTERM while the child starts are held and delivered after
(:func:`start_quietly`).
"""

from __future__ import annotations

import gc
import marshal
import multiprocessing
import os
import queue
import signal
import threading
from collections.abc import Iterator, Sequence
from pathlib import Path

from sharedlink.analysis.changes import read_changes
from sharedlink.capture.stream import Chunk, SideStats


def start_quietly(proc: multiprocessing.process.BaseProcess) -> None:
    """``proc.start()`` with Ctrl-C and SIGTERM held until it returns, then delivered: raised
    inside the fork's own hooks (logging's lock release), they were printed as "Exception
    ignored" and lost, and the command ran on. The child inherits the holding handler until
    :func:`worker` sets its own, and there it does what worker's do: Ctrl-C ignored, SIGTERM
    ends the child (held there, it was lost: the child ran on into a pipe nobody read, and
    multiprocessing's exit-time join waited for ever after a Ctrl-C under load)."""
    if threading.current_thread() is not threading.main_thread():
        proc.start()
        return
    held: list[int] = []
    parent = os.getpid()

    def hold(signum: int, _frame: object) -> None:
        if os.getpid() == parent:
            held.append(signum)
        elif signum == signal.SIGTERM:  # the child, before worker() set SIG_DFL: as SIG_DFL does
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)

    old = {sig: signal.signal(sig, hold) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        proc.start()
    finally:
        for sig, handler in old.items():
            if handler is not None:  # None: set outside Python, left as the fork found it
                signal.signal(sig, handler)
    for sig in dict.fromkeys(held):
        signal.raise_signal(sig)


#: the youngest generation's threshold while a diff decodes: the collector stays on (the decoders
#: make reference cycles, a direction's state and its compiled layouts: with it off, a declaration
#: before every data frame grew the reader by a direction state each, issue 44) but runs seldom
#: (measured: the default 700 cost 10% more CPU on 200,000 frames, this one nothing measurable)
GC_THRESHOLD = 50_000


def sparse_collector() -> None:
    """Keep the collector on, its youngest generation collected every GC_THRESHOLD allocations."""
    gc.set_threshold(max(GC_THRESHOLD, gc.get_threshold()[0]), *gc.get_threshold()[1:])


def worker(conn, path: str, variables: list, sync_interval: float, fast: bool) -> None:  # pragma: no cover - child
    """Child process: send one capture's chunks, then its stats, through ``conn``. Ctrl-C to the
    process group is the parent's to handle (it stops the child), and the parent's SIGTERM ends
    the child quietly: the handlers inherited from the command would print a traceback here."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    sparse_collector()  # decoding makes reference cycles: the collector stays on (issue 44)
    gc.freeze()  # what the process holds now (modules, ...) is never scanned again: each chunk's collect is cheap
    try:
        for item in read_changes(path, variables, sync_interval, fast):
            if isinstance(item, Chunk):
                conn.send_bytes(marshal.dumps((0, item.as_tuple())))
                gc.collect()  # a chunk's cycles, while the reader holds little else (cheap: ~1 ms)
            else:
                conn.send_bytes(marshal.dumps((1, item.to_dict())))
    except (KeyboardInterrupt, BrokenPipeError, EOFError):
        pass
    except Exception as exc:  # noqa: BLE001 - reported to the parent as the side's error
        try:
            conn.send_bytes(marshal.dumps((1, SideStats(path=path, error=f"{path}: {exc}").to_dict())))
        except OSError:
            pass
    finally:
        conn.close()


def read_remote(path: str, variables: Sequence[tuple[str, int | None]], sync_interval: float,
                fast: bool) -> Iterator[Chunk | SideStats]:
    """One capture read in a child process. A thread here takes its messages off the pipe
    as they come (up to a few chunks ahead), so the reader never waits for the aligner."""
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(
        target=worker, args=(send, path, list(variables), sync_interval, fast), daemon=True
    )
    inbox: queue.Queue = queue.Queue(maxsize=4)
    stop = threading.Event()

    def pump() -> None:
        item: bytes | None = None
        while not stop.is_set():
            try:
                item = recv.recv_bytes()
            except (EOFError, OSError):
                item = None
            while not stop.is_set():
                try:
                    inbox.put(item, timeout=0.1)
                    break
                except queue.Full:
                    continue
            if item is None:
                return

    thread = threading.Thread(target=pump, name=f"sharedlink-diff-{Path(path).name}", daemon=True)
    try:
        # (a Ctrl-C held while the child started is raised here: the finally stops the child)
        start_quietly(proc)
        send.close()
        thread.start()
        while True:
            data = inbox.get()
            if data is None:
                yield SideStats(path=path, error=f"{path}: the reader process stopped unexpectedly")
                return
            tag, payload = marshal.loads(data)
            if tag == 0:
                yield Chunk.from_tuple(payload)
            else:
                yield SideStats(**payload)
                return
    finally:
        stop.set()
        send.close()  # (closed already once the child started: a no-op then)
        if proc.pid is not None:  # (started)
            if proc.is_alive():
                proc.terminate()
            # A child that does not stop on SIGTERM (blocked on a pipe nobody reads, a signal
            # lost in a start-up this module did not foresee) is killed: a bare join() waited
            # for ever (seen under load after Ctrl-C to the process group).
            proc.join(timeout=2.0)
            if proc.is_alive():
                proc.kill()
                proc.join()
        if thread.ident is not None:  # (started)
            thread.join(timeout=1.0)
        recv.close()
