"""The C library's heap kept for reuse while an ingest task decodes (:func:`heap_kept`), in a
process started as Dask's nanny starts its workers (see :func:`heap_kept` for why and
:mod:`sharedlink.fleet.ingest` for the task)."""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: what glibc keeps while a task decodes, in a process started with a small trim threshold
_KEPT_HEAP = 64 << 20
_GLIBC_MMAP_THRESHOLD = 128 * 1024  # glibc's default


@contextmanager
def heap_kept() -> Iterator[None]:
    """Dask's nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536`` (glibc hands freed
    heap back to the OS at once, and its mmap threshold stays at 128 KiB): then every block,
    batch and column buffer a task allocates is fresh pages, and a frame costs about 25 % more
    CPU than in a ``--workers`` process (measured: page faults doubled; a local pool started with
    that variable slows the same). While a task decodes, such a process keeps up to
    :data:`_KEPT_HEAP` of freed heap for reuse; after it, its own setting again, and the heap is
    trimmed as it would have been. Elsewhere (no variable, no glibc) nothing changes."""
    wanted = os.environ.get("MALLOC_TRIM_THRESHOLD_", "")
    libc = glibc() if wanted.isdigit() and int(wanted) < _KEPT_HEAP else None
    if libc is None:
        yield
        return
    libc.mallopt(_M_TRIM_THRESHOLD, _KEPT_HEAP)
    libc.mallopt(_M_MMAP_THRESHOLD, _KEPT_HEAP // 2)
    try:
        yield
    finally:
        libc.mallopt(_M_MMAP_THRESHOLD, _GLIBC_MMAP_THRESHOLD)
        libc.mallopt(_M_TRIM_THRESHOLD, int(wanted))
        libc.malloc_trim(0)


def glibc():
    """The C library when it is glibc (it has ``mallopt`` and ``malloc_trim``), else None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt, libc.malloc_trim  # noqa: B018 - glibc's, absent from musl
    except (OSError, AttributeError):
        return None
    return libc
