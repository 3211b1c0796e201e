"""``sharedlink health``: link health of a capture with its per-second quality, through the
decoding core's count tier (no per-frame objects for the frames its fast path takes), and its
forms: rows (CSV, JSONL), a terminal table, a PNG strip."""

from __future__ import annotations

import csv
import io
import json
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from sharedlink.analysis.decode import Counted, Decoded, Decoder
from sharedlink.analysis.health import Health, LinkHealth, Second, feed_counted, feed_decoded, quality
from sharedlink.analysis.malformed import PIECE, other_protocol, talk_key, unframed_pieces
from sharedlink.analysis.robot_health import feed_session
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import NS, CaptureError
from sharedlink.capture.serial_format import GIVEN_UP
from sharedlink.capture.stream import StreamFrame
from sharedlink.protocols.state import BEACON_VARIABLES

#: the columns of a quality row (CSV and JSONL)
ROW_KEYS = ["link", "pair", "second", "time", "frames", "state", "quality", "down_s"]


@dataclass
class CaptureHealth:
    path: str
    health: Health
    error: str | None = None

    @property
    def frames(self) -> int:
        return sum(h.frames for h in self.health.links.values())


def capture_health(
    path: str | Path,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
    progress: Callable[[int, int], None] | None = None,
    outage_after: float | None = None,
) -> CaptureHealth:
    """Link health with the per-second counts of every link of one capture, P2OS and blackboard
    links too (analysis/robot_health.py; a damaged file: everything before the damage, ``error``
    set; a missing one raises CaptureError)."""
    health = Health(outage_after, timeline=True)
    out = CaptureHealth(str(path), health)
    dec = Decoder(variables, sync_interval, carried=False)
    dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
    talks: dict[tuple, str] = {}
    try:
        for item in dec.capture(path, progress, counts=True):
            if isinstance(item, Counted):
                feed_counted(health, item)
            elif isinstance(item, Decoded):
                feed_decoded(health, item)
            elif type(item) is SessionMessage:
                feed_session(health, item)
            elif isinstance(item, StreamFrame):
                _malformed(health, item, talks)
    except CaptureError as exc:
        if exc.record is None and out.frames == 0:
            raise
        out.error = str(exc)
    health.finish()
    return out


def _malformed(health: Health, item: StreamFrame, talks: dict[tuple, str]) -> None:
    """The ``malformed`` frames in unframed bytes, as stats counts them (CaptureStats.add_unframed):
    they keep a link alive; a related protocol's segments and serial noise are none."""
    if item.error in (PIECE, GIVEN_UP) or item.conv[0] == "serial" or b"[:" not in item.raw:
        return
    key = talk_key(item.conv)
    other = other_protocol(item.raw)
    if other is not None:
        talks[key] = other
    if other is not None or key in talks:
        return
    for src, dst, _start, _end, _bad in unframed_pieces(item.raw):
        if src is not None:
            health.frame(health.link(item.conv, src, dst), item.ts_ns, None)


def utc(second: int) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(second))


def rows(ch: CaptureHealth) -> Iterator[dict]:
    """Every link's seconds, link by link."""
    for h in ch.health.sorted_links():
        for s in quality(h):
            d = s.to_dict()
            d["time"] = utc(s.second)
            yield {k: d[k] for k in ROW_KEYS}


def write_rows(ch: CaptureHealth, fh: io.TextIOBase, fmt: str) -> int:
    n = 0
    if fmt == "csv":
        w = csv.DictWriter(fh, ROW_KEYS, lineterminator="\n")
        w.writeheader()
        for r in rows(ch):
            w.writerow({k: "" if v is None else v for k, v in r.items()})
            n += 1
    else:
        for r in rows(ch):
            fh.write(json.dumps(r) + "\n")
            n += 1
    return n


def cell(s: Second | None) -> str:
    """One second of one link on a terminal: its frames, or ``DOWN 3.2 s``."""
    if s is None:
        return ""
    return str(s.frames) if s.down_s is None else "DOWN %.1f s" % s.down_s


def grid(ch: CaptureHealth) -> tuple[list[str], list[list[str]]]:
    """The quality as a table: a row per second (UTC), a column per link."""
    links = ch.health.sorted_links()
    per = [{s.second: s for s in quality(h)} for h in links]
    seconds = sorted({s for p in per for s in p})
    headers = ["time (UTC)"] + [f"{h.link} {h.pair}" for h in links]
    return headers, [[utc(s)] + [cell(p.get(s)) for p in per] for s in seconds]


def plot_strip(ch: CaptureHealth, fh, fmt: str = "png") -> None:
    """A strip per link: frames per second as bars, down seconds shaded red with their outage."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    links = ch.health.sorted_links() or []
    fig, axes = plt.subplots(max(1, len(links)), 1, figsize=(10, 1.2 + 1.1 * max(1, len(links))), squeeze=False,
                             sharex=True)
    t0 = min((h.first_ns for h in links if h.first_ns is not None), default=0) // NS
    for ax, h in zip(axes[:, 0], links):
        _strip(ax, h, t0)
    axes[-1, 0].set_xlabel("seconds from %s" % utc(t0))
    fig.suptitle(f"Link quality: {Path(ch.path).name}", fontsize=10)
    fig.tight_layout()
    fig.savefig(fh, format=fmt)
    plt.close(fig)


def _strip(ax, h: LinkHealth, t0: int) -> None:
    secs = list(quality(h))
    up = [(s.second - t0, s.frames) for s in secs if s.down_s is None]
    ax.bar([x for x, _ in up], [y for _, y in up], width=1.0, align="edge", color="tab:green", linewidth=0)
    for o in h.outages:
        a = (o.start_ns / NS) - t0
        ax.axvspan(a, a + o.duration_ns / NS, color="tab:red", alpha=0.3, linewidth=0)
    ax.set_ylabel("frames/s", fontsize=7)
    ax.set_title(f"{h.link} {h.pair}: {len(h.outages)} outage(s)", fontsize=8, loc="left")
    ax.tick_params(labelsize=7)
