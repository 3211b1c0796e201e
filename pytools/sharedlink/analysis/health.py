"""Link health (issue 43): per link, its learnt rate, its outages, per-second link quality,
availability and its checksum habit, from the link's frame times.

The definition (docs/fields-sharedlink.md, "Link health"; the Lua twin is
``dissector/sharedlink/health.lua``, and a test holds the two together):

* a *link* is one direction of one conversation: sender address and port to receiver address and
  port (a serial capture: the direction) and the letter pair, as the decoding state is kept;
* *intervals*: the time from the link's latest frame so far to a later frame (frames at the same
  time or earlier give none); the *learnt period* is the median (the upper one of an even count)
  of the link's last :data:`WINDOW` intervals (outages among them: a few do not move a median);
  the *learnt rate* is its inverse;
* an *outage* is an interval longer than the threshold: a fixed ``--outage-after`` S when given,
  else the larger of :data:`FLOOR_S` and :data:`PERIODS` learnt periods (a link's first interval
  has no learnt period to be judged by: it is never an outage under this rule). It starts at the frame before the silence and ends at the frame
  after it; a link silent for longer than its threshold at the capture's end (the time of the
  capture's last frame) has an *open* outage (``end`` None) lasting to that end;
* *availability*: 1 - outage time / (capture end - the link's first frame);
* *link quality* per second (the Shepherd OCU's definition): the link's frames in that second
  (epoch-aligned, ``[s, s + 1)``) while it is up; while it is down (no frame in it and an outage
  in progress at its end, ``start <= s + 1 <= end``) the seconds since the outage began (to the
  capture's end at most), shown apart;
* *habit*: a link that has carried a checksum and then sends a frame without one is noted
  ("checksum missing on a link that carries them"); a link that never had one is not.

The feed costs little: :meth:`Health.frame` per frame through the reference path, and
:meth:`Health.run` per run of one link's frame times from the decoder's fast count tier (the
intervals taken at C speed; a run with no interval above the lowest possible threshold moves only
the window).
"""

from __future__ import annotations

from array import array
from collections import Counter, deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from itertools import compress
from operator import not_, sub

from sharedlink.capture.pcapio import NS
from sharedlink.present import Table, text_table
from sharedlink.protocols.limits import MAX_CONVERSATIONS

# -- the definition (twin: dissector/sharedlink/health.lua) ------------------------------------
#: the shortest silence that is an outage under the learnt rule (seconds)
FLOOR_S = 1.0
#: learnt periods of silence that make an outage
PERIODS = 3
#: intervals the learnt period is the median of
WINDOW = 16
#: links kept apart at most (as the decoder's directions); frames of later ones count under one
#: link named :data:`OTHER_LINKS` (pair ``*``), as the dissector's (max_conversations)
MAX_LINKS = MAX_CONVERSATIONS
OTHER_LINKS = "(links past the limit)"
#: what the habit note says
CHECKSUM_HABIT = "checksum missing on a link that carries them"


#: seconds of one :class:`SecondCounts` array (about 68 minutes)
SPAN_BITS = 12
_SPAN = 1 << SPAN_BITS
_ZEROS = bytes(4 << SPAN_BITS)


class SecondCounts:
    """A link's frames per epoch second (a timeline): arrays of 4,096 seconds, made as frames
    come, so a second costs 4 bytes where a dict entry took about 100 (issue 44: a day-long
    capture's ingest held 100 MB of them). :meth:`add` counts a frame, :meth:`update` a batch's
    seconds; :meth:`get` and :meth:`counts` read them."""

    __slots__ = ("spans",)

    def __init__(self) -> None:
        self.spans: dict[int, array] = {}

    def _span(self, s: int) -> array:
        a = self.spans.get(s >> SPAN_BITS)
        if a is None:
            a = self.spans[s >> SPAN_BITS] = array("I", _ZEROS)
        return a

    def get(self, s: int, default: int = 0) -> int:
        a = self.spans.get(s >> SPAN_BITS)
        n = 0 if a is None else a[s & (_SPAN - 1)]
        return n or default

    def add(self, s: int) -> None:
        """One frame in second ``s``."""
        a = self.spans.get(s >> SPAN_BITS)
        if a is None:
            a = self._span(s)
        a[s & (_SPAN - 1)] += 1

    def update(self, seconds: Iterable[int]) -> None:
        for s, n in Counter(seconds).items():
            self._span(s)[s & (_SPAN - 1)] += n

    def counts(self, start: int, end: int) -> list[int]:
        """The frames of each second in ``[start, end)``."""
        out: list[int] = []
        while start < end:
            k = start >> SPAN_BITS
            stop = min(end, (k + 1) << SPAN_BITS)
            a = self.spans.get(k)
            if a is None:
                out += [0] * (stop - start)
            else:
                lo = start & (_SPAN - 1)
                out += a[lo : lo + stop - start].tolist()
            start = stop
        return out

    def drop_before(self, s: int) -> None:
        """Forget the spans wholly before second ``s`` (a live view keeps the last minutes)."""
        for k in [k for k in self.spans if (k + 1) << SPAN_BITS <= s]:
            del self.spans[k]


def link_name(conv: tuple) -> str:
    """A link's sender and receiver as people write them: ``"192.168.1.12:7013 > 255.255.255.255:7013"``;
    a serial capture's direction: ``"serial inbound"`` (its direction name)."""
    if conv[0] == "serial":
        return f"serial {conv[1]}"
    return f"{_host(conv[1])}:{conv[2]} > {_host(conv[3])}:{conv[4]}"


def _host(addr: str) -> str:
    return f"[{addr}]" if ":" in addr else addr


@dataclass
class Outage:
    """One silence of a link: ``start`` (the frame before it) and ``end`` (the frame after it,
    None when open at the capture's end), epoch ns; ``duration_ns`` to ``end`` or to the
    capture's end."""

    link: str
    pair: str
    start_ns: int
    end_ns: int | None
    duration_ns: int

    def to_dict(self) -> dict:
        return {
            "link": self.link,
            "pair": self.pair,
            "start": self.start_ns / NS,
            "end": None if self.end_ns is None else self.end_ns / NS,
            "duration_s": self.duration_ns / NS,
        }


@dataclass
class LinkHealth:
    """One link's figures (see the module doc)."""

    link: str
    pair: str
    frames: int = 0
    first_ns: int | None = None
    last_ns: int | None = None  # the latest frame time so far
    outages: list[Outage] = field(default_factory=list)
    bad_checksum: int = 0
    late: int = 0
    had_checksum: bool = False
    checksum_missing: int = 0  # frames without one after the link carried one (the habit note)
    window: deque = field(default_factory=lambda: deque(maxlen=WINDOW))
    seconds: SecondCounts | None = None  # timeline: frames per epoch second
    end_ns: int | None = None  # the capture's end, once finished

    @property
    def period_ns(self) -> int | None:
        """The learnt period: the median of the window (None before the first interval)."""
        w = self.window
        return sorted(w)[len(w) // 2] if w else None

    @property
    def rate_hz(self) -> float | None:
        p = self.period_ns
        return NS / p if p else None

    def threshold_ns(self, fixed_ns: int | None) -> int | None:
        """The longest interval that is no outage now (None: no interval is one yet)."""
        if fixed_ns is not None:
            return fixed_ns
        p = self.period_ns
        if p is None:
            return None
        floor = int(FLOOR_S * NS)
        return floor if PERIODS * p < floor else PERIODS * p

    @property
    def outage_ns(self) -> int:
        return sum(o.duration_ns for o in self.outages)

    @property
    def longest_ns(self) -> int:
        return max((o.duration_ns for o in self.outages), default=0)

    @property
    def availability(self) -> float | None:
        """Share of the time from the link's first frame to the capture's end it was up."""
        if self.first_ns is None or self.end_ns is None:
            return None
        span = self.end_ns - self.first_ns
        return 1.0 if span <= 0 else max(0.0, 1.0 - self.outage_ns / span)

    def to_dict(self) -> dict:
        avail = self.availability
        return {
            "link": self.link,
            "pair": self.pair,
            "frames": self.frames,
            "rate_hz": self.rate_hz,
            "first": None if self.first_ns is None else self.first_ns / NS,
            "last": None if self.last_ns is None else self.last_ns / NS,
            "outages": len(self.outages),
            "outage_s": self.outage_ns / NS,
            "longest_outage_s": self.longest_ns / NS,
            "availability": avail,
            "bad_checksum": self.bad_checksum,
            "bad_checksum_pct": 100.0 * self.bad_checksum / self.frames if self.frames else 0.0,
            "sync_late": self.late,  # frames while a full set was overdue (as stats' sync_late)
            "checksum_missing": self.checksum_missing,
            "notes": [CHECKSUM_HABIT] if self.checksum_missing else [],
        }


class Health:
    """Link health of a capture, fed frame by frame (:meth:`frame`) or by runs of one link's
    frame times (:meth:`run`) in capture order per link; :meth:`finish` at the capture's end.
    ``outage_after_s``: a fixed threshold (None: the learnt rule); ``timeline``: keep frames
    per second per link (for :func:`quality`)."""

    def __init__(self, outage_after_s: float | None = None, timeline: bool = False) -> None:
        self.fixed_ns = None if outage_after_s is None else round(outage_after_s * NS)
        #: no interval at most this long is an outage (the learnt rule's floor, or the fixed threshold)
        self.low_ns = self.fixed_ns if self.fixed_ns is not None else int(FLOOR_S * NS)
        self.timeline = timeline
        self.links: dict[tuple, LinkHealth] = {}
        self.end_ns: int | None = None
        self.finished = False

    def link(self, conv: tuple, src: str, dst: str) -> LinkHealth:
        key = (conv, src, dst)
        h = self.links.get(key)
        if h is None:
            if len(self.links) >= MAX_LINKS:
                key, conv, src, dst = ("", "", "*"), None, "*", ""
                h = self.links.get(key)
                if h is not None:
                    return h
            h = self.links[key] = LinkHealth(link_name(conv) if conv else OTHER_LINKS, f"{src}>{dst}" if dst else src)
            if self.timeline:
                h.seconds = SecondCounts()
        return h

    def frame(self, h: LinkHealth, ts: int, checksum_ok: bool | None, late: bool = False) -> None:
        """One frame of link ``h`` (``checksum_ok`` None: it has no checksum field)."""
        if checksum_ok is None:
            if h.had_checksum:
                h.checksum_missing += 1
        else:
            h.had_checksum = True
            if checksum_ok is False:
                h.bad_checksum += 1
        if late:
            h.late += 1
        h.frames += 1
        if h.seconds is not None:
            h.seconds.add(ts // NS)
        last = h.last_ns
        if last is None:
            h.first_ns = h.last_ns = ts
            return
        gap = ts - last
        if gap <= 0:
            if ts < h.first_ns:  # type: ignore[operator]
                h.first_ns = ts
            return
        if gap > self.low_ns:
            limit = h.threshold_ns(self.fixed_ns)
            if limit is not None and gap > limit:
                h.outages.append(Outage(h.link, h.pair, last, ts, gap))
        h.window.append(gap)
        h.last_ns = ts

    def run(self, h: LinkHealth, stamps: Sequence[int], late: int = 0) -> None:
        """A run of link ``h`` 's frames (good checksums) at ``stamps``, in capture order."""
        n = len(stamps)
        if not n:
            return
        h.had_checksum = True
        h.late += late
        if h.seconds is not None:
            h.seconds.update([t // NS for t in stamps])
        last = h.last_ns
        if last is None:
            h.first_ns = h.last_ns = last = stamps[0]
            h.frames += 1
            stamps = stamps[1:]
            n -= 1
            if not n:
                return
        ds = list(map(sub, stamps, [last, *stamps[:-1]]))
        if min(ds) < 0 or max(ds) > self.low_ns:  # out of time order, or an outage maybe: frame by frame
            seconds, h.seconds = h.seconds, None  # (counted above)
            for ts in stamps:
                self.frame(h, ts, True)
            h.seconds = seconds
            return
        h.frames += n
        h.window.extend(filter(None, ds))
        h.last_ns = stamps[-1]

    def finish(self, end_ns: int | None = None) -> None:
        """The capture ends at ``end_ns`` (default: its latest frame): open outages, availability."""
        if end_ns is None:
            end_ns = max((h.last_ns for h in self.links.values() if h.last_ns is not None), default=None)
        self.end_ns = end_ns
        self.finished = True
        if end_ns is None:
            return
        for h in self.links.values():
            h.end_ns = end_ns
            last = h.last_ns
            if last is None:
                continue
            gap = end_ns - last
            limit = h.threshold_ns(self.fixed_ns)
            if gap > self.low_ns and limit is not None and gap > limit:
                h.outages.append(Outage(h.link, h.pair, last, None, gap))

    def finish_once(self, end_ns: int | None = None) -> Health:
        """:meth:`finish` unless done; the Health."""
        if not self.finished:
            self.finish(end_ns)
        return self

    def sorted_links(self) -> list[LinkHealth]:
        return sorted(self.links.values(), key=lambda h: (h.link, h.pair))

    def outages(self) -> list[Outage]:
        """Every outage, by start time."""
        return sorted((o for h in self.links.values() for o in h.outages), key=lambda o: (o.start_ns, o.link, o.pair))


def quality_of(frames: int, down_s: float | None) -> float:
    """Shepherd's Link Quality of a second: its frames while up, the seconds of outage while down."""
    return frames if down_s is None else down_s


def state_of(down_s: float | None) -> str:
    """A second's state: ``up``, or ``down`` (an outage in progress at its end, no frame in it)."""
    return "up" if down_s is None else "down"


@dataclass(frozen=True)
class Second:
    """One second of one link: ``frames`` received in it; ``down_s``: None while up, else the
    seconds since the outage in progress at the second's end began."""

    link: str
    pair: str
    second: int  # epoch seconds
    frames: int
    down_s: float | None

    @property
    def quality(self) -> float:
        """Shepherd's Link Quality: frames while up, seconds of outage while down."""
        return quality_of(self.frames, self.down_s)

    @property
    def state(self) -> str:
        return state_of(self.down_s)

    def to_dict(self) -> dict:
        return {"link": self.link, "pair": self.pair, "second": self.second, "frames": self.frames,
                "state": self.state, "quality": self.quality, "down_s": self.down_s}


def quality(h: LinkHealth) -> Iterable[Second]:
    """Link quality of ``h`` per second, from its first frame's second to the capture's end's
    (:meth:`Health` with ``timeline``, finished): :func:`quality_runs` a second at a time."""
    for first, frames, down in quality_runs(h):
        for s, f, d in zip(range(first, first + len(frames)), frames, down):
            yield Second(h.link, h.pair, s, f, d)


def quality_runs(h: LinkHealth, most: int = 65_536, align: int = 86_400
                 ) -> Iterator[tuple[int, list[int], list[float | None]]]:
    """Link quality of ``h`` as runs of seconds ``(first second, frames of each, down_s of
    each)``, at most ``most`` seconds a run, none across a multiple of ``align`` seconds (a UTC
    day): the one definition (see the module doc) :func:`quality` gives second by second. A
    second is down when it has no frame and an outage is in progress at its end."""
    if h.first_ns is None or h.end_ns is None or h.seconds is None:
        return
    seconds, end_ns = h.seconds, h.end_ns
    outages = sorted(h.outages, key=lambda o: o.start_ns)
    k = 0
    s, last = h.first_ns // NS, end_ns // NS
    while s <= last:
        e = min(last + 1, s + most, (s // align + 1) * align)
        frames = seconds.counts(s, e)
        down: list[float | None] = [None] * (e - s)
        for i in compress(range(e - s), map(not_, frames)):  # (seconds with no frame: down or not)
            at = (s + i + 1) * NS  # the second's end
            while k < len(outages) and outages[k].end_ns is not None and outages[k].end_ns < at:  # type: ignore[operator]
                k += 1
            if k < len(outages) and outages[k].start_ns <= at:
                down[i] = round((min(at, end_ns) - outages[k].start_ns) / NS, 3)
        yield s, frames, down
        s = e


# -- the feeds from the decoding core ------------------------------------------------------------


def feed_decoded(health: Health, d) -> None:
    """One :class:`~sharedlink.analysis.decode.Decoded` (a malformed frame keeps the link alive
    but says nothing of its checksum habit)."""
    h = health.link(d.conv, d.src, d.dst)
    ok = d.checksum_ok
    if ok is None and d.kind == "malformed":
        had, h.had_checksum = h.had_checksum, False
        health.frame(h, d.ts_ns, None, False)
        h.had_checksum = had
        return
    health.frame(h, d.ts_ns, ok, d.late)


def feed_counted(health: Health, batch) -> None:
    """A :class:`~sharedlink.analysis.decode.Counted` batch: each direction's run of frame times."""
    for c in batch.dirs.values():
        health.run(health.link(c.conv, c.src, c.dst), c.stamps, c.late)


def feed_columns(health: Health, batch) -> None:
    """A :class:`~sharedlink.analysis.decode.Columns` batch (the columns mode: ``export`` to
    MCAP, ``ingest``): each direction's run of frame times."""
    for c in batch.dirs.values():
        health.run(health.link(c.conv, c.src, c.dst), c.ts_ns, sum(c.late))


# -- what stats shows ----------------------------------------------------------------------------

#: the link table's headers (stats; the tap's report has the same columns)
LINK_HEADERS = ["link", "pair", "frames", "rate Hz", "outages", "outage s", "longest s", "available %",
                "bad checksum %", "sync late frames"]


def health_dict(health: Health | None) -> dict:
    """``--json``'s top-level ``"links"`` and ``"outages"`` (nothing without link health)."""
    if health is None:
        return {}
    return {
        "links": [h.to_dict() for h in health.sorted_links()],
        "outages": [o.to_dict() for o in health.outages()],
    }


def link_rows(health: Health) -> list[list[str]]:
    rows = []
    for h in health.sorted_links():
        d = h.to_dict()
        avail = d["availability"]
        rows.append([
            h.link, h.pair, str(h.frames), "" if d["rate_hz"] is None else "%.3f" % d["rate_hz"], str(len(h.outages)),
            "%.3f" % d["outage_s"], "%.3f" % d["longest_outage_s"], "" if avail is None else "%.2f" % (100 * avail),
            "%.2f" % d["bad_checksum_pct"], str(h.late),
        ])
    return rows


def health_table(health: Health | None) -> list[Table]:
    """The "Link health" table (and the outages and notes, when there are any) for stats
    (:mod:`sharedlink.present` tables)."""
    if health is None:
        return []
    out = [("Link health", LINK_HEADERS, link_rows(health))]
    outages = health.outages()
    if outages:
        out.append(("Outages (UTC)", ["link", "pair", "start", "end", "duration s"], [
            [o.link, o.pair, _when(o.start_ns), "(open)" if o.end_ns is None else _when(o.end_ns), "%.6f" % (o.duration_ns / NS)]
            for o in outages
        ]))
    notes = [[h.link, h.pair, f"{CHECKSUM_HABIT} ({h.checksum_missing} frames)"] for h in health.sorted_links()
             if h.checksum_missing]
    if notes:
        out.append(("Link notes", ["link", "pair", "note"], notes))
    return [text_table(*t) for t in out]


def _when(ns: int) -> str:
    """UTC time of day to the microsecond (``--json`` has the epoch seconds)."""
    import time

    return time.strftime("%H:%M:%S", time.gmtime(ns // NS)) + ".%06d" % (ns % NS // 1000)


class OutageFeed:
    """Outages as they end, frame by frame (``export``'s outage rows): :meth:`feed` gives the
    outages a :class:`~sharedlink.analysis.decode.Decoded` ends, :meth:`finish` the open ones."""

    def __init__(self, outage_after_s: float | None = None) -> None:
        self.health = Health(outage_after_s)

    def feed(self, d) -> list[Outage]:
        h = self.health.link(d.conv, d.src, d.dst)
        n = len(h.outages)
        feed_decoded(self.health, d)
        return h.outages[n:] if len(h.outages) > n else []

    def finish(self) -> list[Outage]:
        before = {id(h): len(h.outages) for h in self.health.links.values()}
        self.health.finish_once()
        return sorted((o for h in self.health.links.values() for o in h.outages[before[id(h)]:]),
                      key=lambda o: (o.start_ns, o.link, o.pair))


def outage_row(o: Outage) -> dict:
    """An outage as an export row of its own (``kind: outage``)."""
    src, _, dst = o.pair.partition(">")
    return {"kind": "outage", "src": src, "dst": dst, **o.to_dict()}


def live_down_s(h: LinkHealth, now_ns: int, fixed_ns: int | None = None) -> float | None:
    """``watch``: the seconds since the link's last frame when that silence is an outage now (the
    link's threshold, :data:`FLOOR_S` before it has one), else None."""
    if h.last_ns is None:
        return None
    gap = now_ns - h.last_ns
    limit = h.threshold_ns(fixed_ns)
    return gap / NS if gap > (limit if limit is not None else int(FLOOR_S * NS)) else None
