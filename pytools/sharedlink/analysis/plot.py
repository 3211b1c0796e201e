"""Plots: a capture's GPS track and its variables over time, as one PNG (matplotlib, headless).

:func:`collect` reads the capture once (streaming, through the decoding core's columns mode:
no per-frame object for the frames its fast path takes; long series are thinned to about
``max_points`` points each, so memory stays bounded) into :class:`PlotData`;
:func:`build_figure` draws it and returns the matplotlib :class:`~matplotlib.figure.Figure`
(the top panel is the track, then one panel per variable, then the events strip:
``2 + len(variables)`` axes besides the speed colour bar); :func:`plot_capture` does both and
writes the file.

What people read (issue 41):

* the track panel: latitude/longitude of every direction that carries a position, points
  coloured by speed (viridis), start and end marked, dropped frames (no frame for longer than
  ``gap_factor`` times the usual period) and frames with a bad checksum marked where the vehicle
  was then: every one up to :data:`MAX_MARKERS`, beyond that an even sample of that many,
  smaller and translucent (the legend says how many there are and how many are drawn);
* the variable panels share the time axis: clock time (UTC) by default, time since the first
  frame with ``elapsed=True`` (in s, min or h as the capture's length asks); the y axes carry the
  variable's unit when :mod:`sharedlink.protocols.units` knows it; a dropped-frame stretch is
  shaded and a bad checksum a thin line only while there are at most :data:`MAX_MARKERS` of
  them, beyond that the events strip alone shows them;
* the events strip (the last panel): dropped frames and bad checksums counted per time bin
  (:data:`EVENT_BINS` bins), so a faulty capture reads as a rate, never as a wall of red;
* one legend, for the whole figure: the node pairs' colours (the same in every panel), start
  and end, the markers.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from sharedlink.analysis.decode import NS, Columns, Decoded, Decoder, DirColumns
from sharedlink.analysis.export import LAT, LON
from sharedlink.analysis.health import Health, feed_decoded, quality
from sharedlink.analysis.robot_plot import RobotPlotData
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.analysis.thinned import Thinned
from sharedlink.capture.pcapio import CaptureError, display_name
from sharedlink.protocols.codec import guess_value, typed_value
from sharedlink.protocols.state import BEACON_VARIABLES
from sharedlink.protocols.units import label as unit_label
from sharedlink.protocols.units import unit_of

SPEED = "AutoGpsVel"
TRACK_CMAP = "viridis"
#: panels beyond this many variables are not drawn (use --select)
MAX_PANELS = 12
#: markers of each kind drawn one by one at most (beyond: an even sample of this many)
MAX_MARKERS = 300
#: markers of each kind kept while reading (a bounded even sample; MAX_MARKERS of them drawn)
MAX_MARKS = 2000
#: bins of the events strip
EVENT_BINS = 200
#: the events' colours
DROPPED_COLOUR = "tab:orange"
BAD_COLOUR = "tab:red"


def sample(xs: Sequence, n: int) -> list:
    """At most ``n`` of ``xs``, evenly spread (first and last kept)."""
    if len(xs) <= n:
        return list(xs)
    step = (len(xs) - 1) / (n - 1)
    return [xs[round(i * step)] for i in range(n)]


@dataclass
class PairTrack:
    pair: str
    points: Thinned  # (t, lon, lat, speed or nan)
    start: tuple[float, float, float] | None = None  # (t, lon, lat)
    end: tuple[float, float, float] | None = None
    last_pos: tuple[float, float] | None = None
    gaps: Thinned = field(default_factory=lambda: Thinned(MAX_MARKS))  # (t0, t1, lon, lat): dropped frames
    bad: Thinned = field(default_factory=lambda: Thinned(MAX_MARKS))  # (t, lon, lat)
    gap_times: array = field(default_factory=lambda: array("d"))  # every stretch of dropped frames (its start)
    bad_times: array = field(default_factory=lambda: array("d"))  # every bad checksum
    dropped: int = 0  # frames missing in the stretches, about (each stretch's length / the usual period, less one)
    last_ts: int | None = None
    intervals: list[int] = field(default_factory=list)  # the first intervals, for the usual period
    period_ns: int | None = None
    held: dict[str, tuple[int | None, str]] = field(default_factory=dict)  # the position's variables now

    def interval(self, ts: int, t0_ns: int, gap_factor: float) -> None:
        """A frame at ``ts``: a stretch of dropped frames when later than ``gap_factor`` periods."""
        if self.last_ts is not None:
            dt = ts - self.last_ts
            if self.period_ns is None:
                if dt > 0:
                    self.intervals.append(dt)
                if len(self.intervals) >= 50:
                    self.period_ns = sorted(self.intervals)[len(self.intervals) // 2]
                    self.intervals = []
            period = self.period_ns or (sorted(self.intervals)[len(self.intervals) // 2] if self.intervals else None)
            if period and dt > gap_factor * period:
                lo_, la_ = self.last_pos or (math.nan, math.nan)
                t_from = (self.last_ts - t0_ns) / NS
                self.gaps.add(t_from, (ts - t0_ns) / NS, lo_, la_)
                self.gap_times.append(t_from)
                self.dropped += max(1, round(dt / period) - 1)
        self.last_ts = ts


@dataclass
class PlotData:
    path: str
    t0_ns: int | None = None
    frames: int = 0
    duration_s: float = 0.0
    series: dict[str, dict[str, Thinned]] = field(default_factory=dict)  # name -> pair -> (t, value)
    tracks: dict[str, PairTrack] = field(default_factory=dict)
    speed_var: str = SPEED
    error: str | None = None
    robots: RobotPlotData = field(default_factory=RobotPlotData)  # P2OS, blackboard (robot_plot.py)
    #: link health (analysis/health.py): lines broken at outages, the link-quality strip
    health: Health = field(default_factory=lambda: Health(timeline=True))

    @property
    def variables(self) -> list[str]:
        """Variables with numeric values, in order of first appearance."""
        return list(self.series)

    @property
    def gaps(self) -> int:
        """Stretches of dropped frames."""
        return sum(t.gaps.seen for t in self.tracks.values())

    @property
    def dropped_frames(self) -> int:
        """Frames missing in those stretches, about."""
        return sum(t.dropped for t in self.tracks.values())

    @property
    def checksum_failures(self) -> int:
        return sum(t.bad.seen for t in self.tracks.values())

    def track(self, pair: str, max_points: int) -> PairTrack:
        tr = self.tracks.get(pair)
        if tr is None:
            tr = self.tracks[pair] = PairTrack(pair, Thinned(max_points))
        return tr


def _number(type_code: int | None, text: str) -> float | None:
    x = guess_value(text) if type_code is None else typed_value(type_code, text)
    if isinstance(x, (int, float)) and math.isfinite(x):
        return float(x)
    return None


@dataclass
class _Names:
    lat: str
    lon: str
    speed: str
    max_points: int
    gap_factor: float


def collect(
    path: str | Path,
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES,
    sync_interval: float = 1.0,
    max_points: int = 5000,
    gap_factor: float = 1.5,
    lat: str = LAT,
    lon: str = LON,
    speed: str = SPEED,
    progress: Callable[[int, int], None] | None = None,
) -> PlotData:
    """Read a capture into :class:`PlotData` (one streaming pass). Damage after the first
    record sets ``error``; a missing or unreadable file raises CaptureError."""
    data = PlotData(str(path), speed_var=speed, robots=RobotPlotData(max_points))
    names = _Names(lat, lon, speed, max_points, gap_factor)
    dec = Decoder(variables, sync_interval, carried=False)  # a frame's own values; the tables hold the rest
    dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
    try:
        for item in dec.capture(path, progress, columns=True):
            if isinstance(item, Columns):
                for c in sorted(item.dirs.values(), key=lambda c: c.ts_ns[0] if c.ts_ns else 0):
                    _add_columns(data, c, names)
                    data.health.run(data.health.link(c.conv, c.src, c.dst), c.ts_ns, sum(c.late))
            elif isinstance(item, Decoded):
                _add(data, item, names)
                feed_decoded(data.health, item)
            elif type(item) is SessionMessage:
                data.robots.add(item)
    except CaptureError as exc:
        if exc.record is None and data.frames == 0 and data.robots.packets == 0:
            raise
        data.error = str(exc)
    data.health.finish_once()
    return data


def _start(data: PlotData, ts: int) -> None:
    if data.t0_ns is None:
        data.t0_ns = ts


def _add(data: PlotData, d: Decoded, names: _Names) -> None:
    """A frame the reference path decoded (a bad checksum, a declaration, the first frames)."""
    _start(data, d.ts_ns)
    data.frames += 1
    t = (d.ts_ns - data.t0_ns) / NS  # type: ignore[operator]
    data.duration_s = max(data.duration_s, t)
    pair = d.pair
    tr = data.track(pair, names.max_points)
    tr.interval(d.ts_ns, data.t0_ns, names.gap_factor)  # type: ignore[arg-type]
    if d.checksum_ok is False:
        lo_, la_ = tr.last_pos or (math.nan, math.nan)
        tr.bad.add(t, lo_, la_)
        tr.bad_times.append(t)
        return
    if not d.updates:
        return
    vars_ = d.table.vars
    for u in d.present():
        v = vars_.get(u.name)
        x = _number(v.type_code if v is not None else None, u.text or "")
        if x is not None:
            _series(data, u.name, pair, names.max_points).add(t, x)
    for name in (names.lat, names.lon, names.speed):
        v = vars_.get(name)
        if v is not None and v.text is not None:
            tr.held[name] = (v.type_code, v.text)
    _track_point(tr, t, names)
    _finish(tr, t, names)


def _series(data: PlotData, name: str, pair: str, max_points: int) -> Thinned:
    by_pair = data.series.setdefault(name, {})
    s = by_pair.get(pair)
    if s is None:
        s = by_pair[pair] = Thinned(max_points)
    return s


def _track_point(tr: PairTrack, t: float, names: _Names) -> None:
    """The position after a frame, as a track point (thinned)."""
    pts = tr.points
    pts.seen += 1
    if (pts.seen - 1) % pts.stride:
        return
    pos = _position(tr, names)
    if pos is None:
        return
    x, y, spd = pos
    pts.rows.append((t, x, y, spd))
    if len(pts.rows) >= 2 * pts.limit:
        pts.rows = pts.rows[::2]
        pts.stride *= 2
    tr.last_pos = (x, y)
    if tr.start is None:
        tr.start = (t, x, y)
    tr.end = (t, x, y)


def _position(tr: PairTrack, names: _Names) -> tuple[float, float, float] | None:
    la, lo = tr.held.get(names.lat), tr.held.get(names.lon)
    if la is None or lo is None:
        return None
    y, x = _number(*la), _number(*lo)
    if y is None or x is None or not (-90 <= y <= 90 and -180 <= x <= 180):
        return None
    sp = tr.held.get(names.speed)
    spd = _number(*sp) if sp is not None else None
    return x, y, math.nan if spd is None else spd


def _add_columns(data: PlotData, c: DirColumns, names: _Names) -> None:
    """A batch of one direction's frames the fast path took (good full or delta frames): their
    values per row, thinned per series as they come (only the kept ones parsed)."""
    if not c.ts_ns:
        return
    _start(data, c.ts_ns[0])
    t0 = data.t0_ns
    tr = data.track(c.pair, names.max_points)
    pair = c.pair
    data.frames += len(c.ts_ns)
    data.duration_s = max(data.duration_s, (max(c.ts_ns) - t0) / NS)  # type: ignore[operator]
    names_, texts, types = c.name, c.text, c.type_code
    watched = {names.lat, names.lon, names.speed}
    held = tr.held
    by_name: dict[str, Thinned | None] = {}
    interval = tr.interval
    factor = names.gap_factor
    k = 0
    for ts, n in zip(c.ts_ns, c.nvalues):
        interval(ts, t0, factor)  # type: ignore[arg-type]
        if not n:
            continue
        t = (ts - t0) / NS  # type: ignore[operator]
        for j in range(k, k + n):
            name = names_[j]
            s = by_name.get(name, False)
            if s is False:
                s = by_name[name] = data.series.get(name, {}).get(pair)
            if s is None:  # not (yet) a numeric series: made at its first number
                x = _number(types[j], texts[j])
                if x is not None:
                    s = by_name[name] = _series(data, name, pair, names.max_points)
                    s.add(t, x)
            else:
                s.seen += 1
                if not (s.seen - 1) % s.stride:
                    x = _number(types[j], texts[j])
                    if x is not None:
                        s.rows.append((t, x))
                        if len(s.rows) >= 2 * s.limit:
                            s.rows = s.rows[::2]
                            s.stride *= 2
            if name in watched:
                held[name] = (types[j], texts[j])
        k += n
        _track_point(tr, t, names)
    _finish(tr, (c.ts_ns[-1] - t0) / NS, names)  # type: ignore[operator]


def _finish(tr: PairTrack, t: float, names: _Names) -> None:
    """The end marker and the last position: where the direction is after its frame at ``t``
    (its last frames may have been thinned away)."""
    if tr.start is not None and (tr.end is None or tr.end[0] < t):
        pos = _position(tr, names)
        if pos is not None:
            tr.end = (t, pos[0], pos[1])
            tr.last_pos = (pos[0], pos[1])


# -- drawing ---------------------------------------------------------------------------------------


#: the seconds since 1970 matplotlib's dates can show (years 1 to 9999)
_DATES = (-62135596800.0, 253402300799.0)


@dataclass
class TimeAxis:
    """How seconds since the first frame are drawn: clock time (matplotlib dates, UTC) or
    elapsed time in s, min or h."""

    elapsed: bool
    t0_ns: int
    scale: float  # divide seconds by this (elapsed), or seconds per day (clock)
    label: str

    @classmethod
    def of(cls, data: PlotData, elapsed: bool) -> TimeAxis:
        clock = data.t0_ns is not None and _DATES[0] <= data.t0_ns / NS and data.t0_ns / NS + data.duration_s < _DATES[1]
        if elapsed or not clock:
            d = data.duration_s
            scale, unit = (1.0, "s") if d < 600 else (60.0, "min") if d < 36000 else (3600.0, "h")
            since = "the first frame"
            if data.t0_ns is not None and not elapsed:  # (a time matplotlib's dates cannot hold: said in the label)
                from sharedlink.present import timestamp

                since = f"the first frame, {timestamp(data.t0_ns)}"
            return cls(True, data.t0_ns or 0, scale, f"time since {since} ({unit})")
        return cls(False, data.t0_ns, 86400.0, "time (UTC)")

    def x(self, ts: Sequence[float]) -> list[float]:
        if self.elapsed:
            s = self.scale
            return [t / s for t in ts]
        base = self.t0_ns / NS / 86400.0  # matplotlib's dates: days since 1970-01-01 UTC
        return [base + t / 86400.0 for t in ts]

    def style(self, ax) -> None:
        ax.set_xlabel(self.label)
        if not self.elapsed:
            import datetime as dt

            import matplotlib.dates as mdates

            loc = mdates.AutoDateLocator(tz=dt.timezone.utc)
            ax.xaxis.set_major_locator(loc)
            ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc, tz=dt.timezone.utc))


def _title(data: PlotData, title: str | None) -> str:
    from sharedlink.present import count, duration

    label = title or display_name(Path(data.path).name)
    return (f"{label}: {count(data.frames)} frames, {duration(data.duration_s)}, "
            f"{count(data.dropped_frames)} dropped frames, {count(data.checksum_failures)} bad checksums")


def build_figure(data: PlotData, variables: Sequence[str] | None = None, title: str | None = None,
                 elapsed: bool = False):
    """Draw :class:`PlotData`; returns the Figure (the track, a panel per variable and the
    events strip, plus the speed colour bar axes, labelled ``<colorbar>``). Unknown or
    non-numeric variables in ``variables`` raise ValueError. ``elapsed``: the time axis in
    time since the first frame instead of clock time (UTC)."""
    from matplotlib.figure import Figure

    names = list(data.variables) if variables is None else list(variables)
    unknown = [n for n in names if n not in data.series]
    if unknown:
        have = ", ".join(data.variables) or "none"
        raise ValueError(f"no numeric values for {', '.join(unknown)} in {data.path} (variables: {have})")
    names = names[:MAX_PANELS]
    n = len(names)
    strip = 1 if data.health.links else 0
    fig = Figure(figsize=(10, 6.8 + 1.7 * n + 1.2 * strip), dpi=100, layout="constrained")
    gs = fig.add_gridspec(2 + n + strip, 1, height_ratios=[4.5] + [1.5] * n + [1.0] * strip + [0.8])
    ax = fig.add_subplot(gs[0])
    colours = _pair_colours(data)
    _draw_track(fig, ax, data)
    fig.suptitle(_title(data, title))
    axis = TimeAxis.of(data, elapsed)
    first = None
    for i, name in enumerate(names):
        vax = fig.add_subplot(gs[1 + i], sharex=first)
        first = first or vax
        _draw_series(vax, data, name, axis, colours)
        vax.tick_params(labelbottom=False)
    if strip:
        qax = fig.add_subplot(gs[1 + n], sharex=first)
        _draw_quality(qax, data, axis, colours)
        qax.tick_params(labelbottom=False)
    eax = fig.add_subplot(gs[1 + n + strip], sharex=first)
    eax.set_label("events")
    _draw_events(eax, data, axis)
    axis.style(eax)
    _legend(fig, ax, colours)
    return fig


def _pair_colours(data: PlotData) -> dict[str, str]:
    """One colour per node pair, the same in every panel."""
    pairs = sorted({p for by_pair in data.series.values() for p in by_pair} | set(data.tracks))
    return {p: f"C{i % 10}" for i, p in enumerate(pairs)}


def _legend(fig, ax, colours: dict[str, str]) -> None:
    """The one legend: the track's markers and the node pairs' line colours."""
    from matplotlib.lines import Line2D

    handles, labels = ax.get_legend_handles_labels()
    if len(colours) > 1:
        for pair, colour in colours.items():
            handles.append(Line2D([], [], color=colour, linewidth=1.5))
            labels.append(pair)
    if handles:
        fig.legend(handles, labels, loc="outside lower center", fontsize="small", ncols=min(4, len(handles)))


def _marker_label(what: str, seen: int, drawn: int, suffix: str) -> str:
    from sharedlink.present import count

    places = "place" if seen == 1 else "places"
    if what.startswith("bad"):
        shown = f", {count(drawn)} drawn" if drawn < seen else ""
        return f"{what} ({count(seen)}{shown}){suffix}"
    shown = f", {count(drawn)} drawn" if drawn < seen else ""
    return f"{what} ({count(seen)} {places}{shown}){suffix}"


#: the link-quality strip's axes label (not a variable panel)
QUALITY_LABEL = "<link quality>"


def _draw_quality(ax, data: PlotData, axis: TimeAxis, colours: dict[str, str]) -> None:
    """Frames per second per link (Shepherd's link quality while up), outages shaded red; each
    link in its node pair's colour (the figure's one legend names them)."""
    ax.set_label(QUALITY_LABEL)
    t0 = (data.t0_ns or 0) / NS
    for h in data.health.sorted_links():
        secs = list(quality(h))
        ax.step(axis.x([x.second - t0 for x in secs]), [math.nan if x.down_s is not None else x.frames for x in secs],
                where="post", linewidth=1.0, color=colours.get(h.pair))
        for o in h.outages:
            a = (o.start_ns - (data.t0_ns or 0)) / NS
            x0, x1 = axis.x((a, a + o.duration_ns / NS))
            ax.axvspan(x0, x1, color="tab:red", alpha=0.3, linewidth=0)
    n = len(data.health.outages())
    ax.set_ylabel("frames/s", fontsize="small")
    ax.set_title(f"link quality ({n} outage{'s' if n != 1 else ''})", loc="left", fontsize="small")
    ax.grid(True, linewidth=0.3)


def broken(ts: list[float], vs: list[float], spans: list[tuple[float, float]]) -> tuple[list[float], list[float]]:
    """``ts``/``vs`` with a NaN point inside each outage span that has points on both sides (the
    line is not drawn across the silence)."""
    if not spans:
        return ts, vs
    import bisect

    out_t, out_v, k = [], [], 0
    for a, b in sorted(spans):
        i = bisect.bisect_right(ts, a + 1e-6, lo=k)
        if 0 < i < len(ts) and ts[i] >= b - 1e-6:  # (b: the next frame's time, to float rounding)
            out_t += ts[k:i] + [(a + b) / 2]
            out_v += vs[k:i] + [math.nan]
            k = i
    return out_t + ts[k:], out_v + vs[k:]


def _draw_track(fig, ax, data: PlotData) -> None:
    import matplotlib as mpl

    ax.set_title("GPS track", loc="left")
    ax.set_xlabel(unit_label(LON).replace(LON, "longitude"))
    ax.set_ylabel(unit_label(LAT).replace(LAT, "latitude"))
    drawn = False
    mappable = None
    lats: list[float] = []
    vmin, vmax = math.inf, -math.inf
    for tr in data.tracks.values():
        cols = tr.points.columns()
        if cols:
            sp = [s for s in cols[3] if not math.isnan(s)]
            if sp:
                vmin, vmax = min(vmin, min(sp)), max(vmax, max(sp))
    if vmin > vmax:
        vmin, vmax = 0.0, 1.0
    elif vmin == vmax:
        vmax = vmin + 1.0
    norm = mpl.colors.Normalize(vmin=vmin, vmax=vmax)
    many = len([t for t in data.tracks.values() if t.start is not None]) > 1
    for tr in data.tracks.values():
        cols = tr.points.columns()
        if not cols:
            continue
        ts, xs, ys, sp = cols
        lats += ys
        drawn = True
        ax.plot(xs, ys, color="0.6", linewidth=0.8, zorder=1)
        colour_by = sp if not all(math.isnan(s) for s in sp) else ts
        mappable = ax.scatter(xs, ys, c=colour_by, cmap=TRACK_CMAP, norm=norm if colour_by is sp else None,
                              s=9, linewidths=0, zorder=2)
        suffix = f" {tr.pair}" if many else ""
        if tr.start is not None and tr.end is not None:
            ax.plot(tr.start[1], tr.start[2], marker="^", markersize=12, color="tab:green",
                    markeredgecolor="black", linestyle="none", zorder=4, label="start" + suffix)
            ax.plot(tr.end[1], tr.end[2], marker="s", markersize=10, color="tab:red",
                    markeredgecolor="black", linestyle="none", zorder=4, label="end" + suffix)
        _track_marks(ax, tr, suffix)
    if not drawn:
        ax.text(0.5, 0.5, f"no position ({LAT}/{LON}) in this capture", transform=ax.transAxes,
                ha="center", va="center", color="0.4")
        return
    mid = sum(lats) / len(lats)
    ax.set_aspect(1.0 / max(0.05, math.cos(math.radians(mid))), adjustable="datalim")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.grid(True, linewidth=0.3)
    if mappable is not None:
        cb = fig.colorbar(mappable, ax=ax, shrink=0.8, pad=0.01)
        cb.set_label(f"speed, {unit_label(data.speed_var)}" if mappable.norm is norm else "time since the first frame (s)")


def _track_marks(ax, tr: PairTrack, suffix: str) -> None:
    """Where frames were dropped and where a checksum failed: every one up to MAX_MARKERS,
    beyond that an even sample of that many, smaller and translucent."""
    g = [r for r in tr.gaps.rows if not math.isnan(r[2])]
    if g:
        g = sample(g, MAX_MARKERS)
        few = tr.gaps.seen <= MAX_MARKERS
        ax.plot([r[2] for r in g], [r[3] for r in g], marker="o", markersize=9 if few else 5, markerfacecolor="none",
                markeredgecolor=DROPPED_COLOUR, markeredgewidth=1.8 if few else 1.0, alpha=1.0 if few else 0.6,
                linestyle="none", zorder=3, label=_marker_label("frames dropped", tr.gaps.seen, len(g), suffix))
    b = [r for r in tr.bad.rows if not math.isnan(r[1])]
    if b:
        b = sample(b, MAX_MARKERS)
        few = tr.bad.seen <= MAX_MARKERS
        ax.plot([r[1] for r in b], [r[2] for r in b], marker="x", markersize=8 if few else 4, color=BAD_COLOUR,
                markeredgewidth=2 if few else 1.0, alpha=1.0 if few else 0.6, linestyle="none", zorder=3,
                label=_marker_label("bad checksums", tr.bad.seen, len(b), suffix))


def _draw_series(ax, data: PlotData, name: str, axis: TimeAxis, colours: dict[str, str]) -> None:
    by_pair = data.series.get(name, {})
    for pair, s in by_pair.items():
        cols = s.columns()
        if cols:
            t0_ns = data.t0_ns or 0
            spans = [((o.start_ns - t0_ns) / NS, (o.start_ns + o.duration_ns - t0_ns) / NS)
                     for o in data.health.outages() if o.pair == pair]
            ts, vs = broken(cols[0], cols[1], spans)  # no line across an outage
            ax.plot(axis.x(ts), vs, drawstyle="steps-post", linewidth=1.0, color=colours.get(pair))
    for tr in data.tracks.values():  # a few events: where they are; many: the events strip alone
        if 0 < tr.gaps.seen <= MAX_MARKERS:
            for t0, t1, *_ in tr.gaps.rows:
                x0, x1 = axis.x((t0, t1))
                ax.axvspan(x0, x1, color=DROPPED_COLOUR, alpha=0.25, linewidth=0)
        if 0 < tr.bad.seen <= MAX_MARKERS:
            for x in axis.x([r[0] for r in tr.bad.rows]):
                ax.axvline(x, color=BAD_COLOUR, alpha=0.5, linewidth=0.8)
    unit = unit_of(name)
    ax.set_ylabel(name if unit is None else f"{name}\n({unit})", fontsize="small")
    ax.grid(True, linewidth=0.3)
    ax.ticklabel_format(axis="y", useOffset=False)


def _draw_events(ax, data: PlotData, axis: TimeAxis) -> None:
    """Dropped frames and bad checksums counted per bin, as two step lines."""
    width = bin_width(data.duration_s)
    bins = max(1, math.ceil(data.duration_s / width))
    edges = [i * width for i in range(bins + 1)]
    for colour, times in ((DROPPED_COLOUR, [t for tr in data.tracks.values() for t in tr.gap_times]),
                          (BAD_COLOUR, [t for tr in data.tracks.values() for t in tr.bad_times])):
        counts = [0] * bins
        for t in times:
            counts[max(0, min(bins - 1, int(t / width)))] += 1  # (a frame before the first: the first bin)
        if times:
            ax.stairs(counts, axis.x(edges), color=colour, linewidth=1.2)
    ax.set_ylabel(f"per {_bin_text(width)}", fontsize="small")
    ax.set_title("dropped frames (orange) and bad checksums (red)", loc="left", fontsize="small")
    ax.grid(True, linewidth=0.3)
    ax.set_ylim(bottom=0)


#: the events strip's bin widths (s): the first that makes at most EVENT_BINS bins
BIN_WIDTHS = (0.1, 0.2, 0.5, 1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400)


def bin_width(span_s: float) -> float:
    """A round bin width giving at most :data:`EVENT_BINS` bins over ``span_s`` seconds."""
    for w in BIN_WIDTHS:
        if span_s / w <= EVENT_BINS:
            return float(w)
    return 86400.0 * math.ceil(span_s / 86400.0 / EVENT_BINS)


def _bin_text(seconds: float) -> str:
    """``1 s``, ``15 min``, ``1 h``."""
    for unit, size in (("day", 86400), ("h", 3600), ("min", 60)):
        if seconds >= size and seconds % size == 0:
            n = int(seconds // size)
            return f"{n} {unit}" + ("s" if unit == "day" and n > 1 else "")
    return f"{seconds:g} s"


def figure_for_capture(path: str | Path, variables: Sequence[str] | None = None, **kw):
    """:func:`collect` then :func:`build_figure`: the Figure, for inspection."""
    elapsed = kw.pop("elapsed", False)
    return build_figure(collect(path, **kw), variables, elapsed=elapsed)


def plot_capture(path: str | Path, out: str | Path, select: Sequence[str] | None = None, **kw) -> PlotData:
    """Write the plot of ``path`` to ``out`` (format from its suffix: png, svg, pdf), with a
    panel per ``select``ed variable (default: every numeric one). ``variables=`` is the
    a-priori list as everywhere (:func:`collect`); a list of plain names there is the old
    spelling of ``select`` and still taken so, with a DeprecationWarning."""
    old = kw.get("variables")
    if old is not None and all(isinstance(v, str) for v in old):
        import warnings

        warnings.warn("plot_capture(variables=[names]) is deprecated: use select=", DeprecationWarning, stacklevel=2)
        select = list(kw.pop("variables"))
    elapsed = kw.pop("elapsed", False)
    data = collect(path, **kw)
    fig = build_figure(data, select, elapsed=elapsed)
    fig.savefig(str(out))
    return data
