"""The ``links`` and ``outages`` tables of a fleet dataset (issue 43): link health
(:mod:`sharedlink.analysis.health`, the one definition ``stats`` uses) of an ingested capture's
SharedLink links and its P2OS and blackboard links (:mod:`sharedlink.analysis.robot_health`), fed as the frames are decoded and written when the capture is done.

* ``links``: one row per link and second (epoch-aligned) from the link's first frame's second to
  the capture's end: the frames in it and its Shepherd link quality, ``state`` up or down;
* ``outages``: one row per outage of a link (``open`` when it lasts to the capture's end).

Both are partitioned as the frames, ``day=YYYY-MM-DD/link=B_to_A`` (the day of the second, or of
the outage's start); columns :data:`~sharedlink.fleet.dataset.LINKS_COLUMNS` and
:data:`~sharedlink.fleet.dataset.OUTAGES_COLUMNS`.
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Iterable, Iterator
from typing import Any

import pyarrow as pa

from sharedlink.analysis.decode import Columns, Decoded
from sharedlink.analysis.health import Health, feed_columns, feed_decoded, quality_of, quality_runs, state_of
from sharedlink.analysis.robot_health import feed_session
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import NS
from sharedlink.fleet.dataset import LINKS_COLUMNS, OUTAGES_COLUMNS, link_name

#: rows of a link's ``links`` table made at a time
CHUNK_ROWS = 65_536


def _day(s: int) -> str:
    return _dt.datetime.fromtimestamp(s, _dt.timezone.utc).strftime("%Y-%m-%d")


class HealthRows:
    """A capture's link health, fed by :meth:`fed` (the decoder's items as they pass: its
    frames, and its fast path's :class:`~sharedlink.analysis.core.columns.DirColumns`), its
    rows made by :meth:`tables`."""

    def __init__(self) -> None:
        self.health = Health(timeline=True)
        self.written = False

    def fed(self, items: Iterable[Any]) -> Iterator[Any]:
        """``items`` (a :meth:`~sharedlink.analysis.decode.Decoder.capture` in columns mode),
        each fed to the link health on its way."""
        health = self.health
        for item in items:
            t = type(item)
            if t is Columns:
                feed_columns(health, item)
            elif t is Decoded:
                feed_decoded(health, item)
            elif t is SessionMessage:  # P2OS, blackboard links (analysis/robot_health.py)
                feed_session(health, item)
            yield item

    def _src_dst(self) -> Iterator[tuple[Any, str, str]]:
        for h in self.health.sorted_links():  # (a robot link's pair: "robot>client", "master>slave")
            src, _, dst = h.pair.partition(">")
            yield h, src, dst

    def tables(self, capture: str, vehicle: str) -> Iterator[tuple[str, tuple[str, str], dict[str, pa.Array], int]]:
        """(table, (day, link partition), columns, rows) of the finished capture (end: its latest
        frame); nothing the second time. A link's seconds come :data:`CHUNK_ROWS` at a time (a
        partition's rows may come in several pieces, in order): a long capture's seconds are
        never all held (issue 44)."""
        if self.written:
            return
        self.written = True
        self.health.finish_once()
        outages: dict[tuple[str, str], list[dict[str, Any]]] = {}
        for h, src, dst in self._src_dst():
            link = link_name(src, dst)
            base = {"conversation": h.link, "src": src, "dst": dst, "pair": h.pair}
            for day, cols, n in _seconds(h):
                yield "links", (day, link), health_columns("links", {**cols, **base}, n, capture, vehicle), n
            for o in h.outages:
                outages.setdefault((_day(o.start_ns // NS), link), []).append({
                    **base, "time_ns": o.start_ns, "end_ns": o.end_ns, "duration_ns": o.duration_ns,
                    "duration_s": o.duration_ns / NS, "open": o.end_ns is None})
        for part, rows in sorted(outages.items()):
            rows.sort(key=lambda r: (r["time_ns"], r["conversation"]))
            cols = {name: [r[name] for r in rows] for name, _kind in OUTAGES_COLUMNS[2:]}
            yield "outages", part, health_columns("outages", cols, len(rows), capture, vehicle), len(rows)


def _seconds(h: Any) -> Iterator[tuple[str, dict[str, list], int]]:
    """Link ``h``'s rows of the ``links`` table as (UTC day, columns, rows), at most
    :data:`CHUNK_ROWS` rows and one day at a time."""
    for first, frames, down in quality_runs(h, CHUNK_ROWS, 86_400):
        n = len(frames)
        yield _day(first), {
            "time_ns": [s * NS for s in range(first, first + n)], "frames": frames,
            "state": list(map(state_of, down)), "quality": list(map(quality_of, frames, down)), "down_s": down}, n


def health_columns(table: str, cols: dict[str, Any], n: int, capture: str, vehicle: str) -> dict[str, pa.Array]:
    """The table's columns from ``cols`` (name -> a list of ``n`` values, or one value for every
    row), ``capture`` and ``vehicle`` as dictionary arrays."""
    zeros = pa.repeat(pa.scalar(0, pa.int32()), n)
    out: dict[str, pa.Array] = {
        "capture": pa.DictionaryArray.from_arrays(zeros, pa.array([capture], pa.string())),
        "vehicle": pa.DictionaryArray.from_arrays(zeros, pa.array([vehicle], pa.string())),
    }
    for name, kind in (LINKS_COLUMNS if table == "links" else OUTAGES_COLUMNS)[2:]:
        x = cols[name]
        out[name] = pa.array(x, getattr(pa, kind)()) if isinstance(x, list) else pa.repeat(
            pa.scalar(x, getattr(pa, kind)()), n)
    return out
