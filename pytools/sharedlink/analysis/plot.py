"""Plots: a capture's GPS track and its variables over time, as one PNG (matplotlib, headless).

:func:`collect` reads the capture once (streaming; long series are thinned to about
``max_points`` points each, so memory stays bounded) into :class:`PlotData`;
:func:`build_figure` draws it and returns the matplotlib :class:`~matplotlib.figure.Figure`
(the top panel is the track, then one panel per variable: ``1 + len(variables)`` axes besides
the speed colour bar); :func:`plot_capture` does both and writes the file.

The track panel: latitude/longitude of every direction that carries a position, points
coloured by speed (viridis), start and end marked, gaps (no frame for longer than
``gap_factor`` times the usual period) and frames with a bad checksum marked where the
vehicle was then. The variable panels share the time axis (seconds since the first frame)
and show the same gaps (shaded) and checksum failures (red lines).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from sharedlink.analysis.decode import NS, Decoded, iter_decoded
from sharedlink.analysis.export import LAT, LON
from sharedlink.analysis.health import Health, feed_decoded, quality
from sharedlink.capture.pcapio import CaptureError, display_name
from sharedlink.protocols.codec import guess_value, typed_value
from sharedlink.protocols.state import BEACON_VARIABLES

SPEED = "AutoGpsVel"
TRACK_CMAP = "viridis"
#: panels beyond this many variables are not drawn (use --vars)
MAX_PANELS = 12
#: markers of each kind kept at most (beyond that, thinned)
MAX_MARKS = 2000


class Thinned:
    """Points ``(t, values...)`` kept at most about ``2 * limit`` : when full, every other point
    is dropped and only every ``stride``-th new one is kept."""

    def __init__(self, limit: int) -> None:
        self.limit = max(2, limit)
        self.stride = 1
        self.seen = 0
        self.rows: list[tuple[float, ...]] = []

    def add(self, *row: float) -> None:
        self.seen += 1
        if (self.seen - 1) % self.stride:
            return
        self.rows.append(row)
        if len(self.rows) >= 2 * self.limit:
            self.rows = self.rows[::2]
            self.stride *= 2

    def columns(self) -> list[list[float]]:
        if not self.rows:
            return []
        return [list(c) for c in zip(*self.rows)]


@dataclass
class PairTrack:
    pair: str
    points: Thinned  # (t, lon, lat, speed or nan)
    start: tuple[float, float, float] | None = None  # (t, lon, lat)
    end: tuple[float, float, float] | None = None
    last_pos: tuple[float, float] | None = None
    gaps: Thinned = field(default_factory=lambda: Thinned(MAX_MARKS))  # (t0, t1, lon, lat)
    bad: Thinned = field(default_factory=lambda: Thinned(MAX_MARKS))  # (t, lon, lat)
    last_ts: int | None = None
    intervals: list[int] = field(default_factory=list)  # the first intervals, for the usual period
    period_ns: int | None = None


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
    #: link health (analysis/health.py): lines broken at outages, the link-quality strip
    health: Health = field(default_factory=lambda: Health(timeline=True))

    @property
    def variables(self) -> list[str]:
        """Variables with numeric values, in order of first appearance."""
        return list(self.series)

    @property
    def gaps(self) -> int:
        return sum(t.gaps.seen for t in self.tracks.values())

    @property
    def checksum_failures(self) -> int:
        return sum(t.bad.seen for t in self.tracks.values())


def _number(type_code: int | None, text: str) -> float | None:
    x = guess_value(text) if type_code is None else typed_value(type_code, text)
    if isinstance(x, (int, float)) and math.isfinite(x):
        return float(x)
    return None


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
    data = PlotData(str(path), speed_var=speed)
    try:
        for item in iter_decoded(path, variables, sync_interval, progress=progress):
            if isinstance(item, Decoded):
                _add(data, item, max_points, gap_factor, lat, lon, speed)
                feed_decoded(data.health, item)
    except CaptureError as exc:
        if exc.record is None and data.frames == 0:
            raise
        data.error = str(exc)
    data.health.finish_once()
    return data


def _add(data: PlotData, d: Decoded, max_points: int, gap_factor: float, lat: str, lon: str, speed: str) -> None:
    if data.t0_ns is None:
        data.t0_ns = d.ts_ns
    data.frames += 1
    t = (d.ts_ns - data.t0_ns) / NS
    data.duration_s = t
    pair = d.pair
    tr = data.tracks.get(pair)
    if tr is None:
        tr = data.tracks[pair] = PairTrack(pair, Thinned(max_points))
    # gaps: a frame later than gap_factor times the usual period (the median of the first 50)
    if tr.last_ts is not None:
        dt = d.ts_ns - tr.last_ts
        if tr.period_ns is None:
            if dt > 0:
                tr.intervals.append(dt)
            if len(tr.intervals) >= 50:
                tr.period_ns = sorted(tr.intervals)[len(tr.intervals) // 2]
                tr.intervals = []
        period = tr.period_ns or (sorted(tr.intervals)[len(tr.intervals) // 2] if tr.intervals else None)
        if period and dt > gap_factor * period:
            lo_, la_ = tr.last_pos or (math.nan, math.nan)
            tr.gaps.add((tr.last_ts - data.t0_ns) / NS, t, lo_, la_)
    tr.last_ts = d.ts_ns
    if d.checksum_ok is False:
        lo_, la_ = tr.last_pos or (math.nan, math.nan)
        tr.bad.add(t, lo_, la_)
        return
    if not d.updates:
        return
    vars_ = d.table.vars
    for u in d.present():
        v = vars_.get(u.name)
        x = _number(v.type_code if v is not None else None, u.text or "")
        if x is None:
            continue
        by_pair = data.series.setdefault(u.name, {})
        s = by_pair.get(pair)
        if s is None:
            s = by_pair[pair] = Thinned(max_points)
        s.add(t, x)
    la, lo = vars_.get(lat), vars_.get(lon)
    if la is None or lo is None or la.text is None or lo.text is None:
        return
    y, x = _number(la.type_code, la.text), _number(lo.type_code, lo.text)
    if y is None or x is None or not (-90 <= y <= 90 and -180 <= x <= 180):
        return
    sp = vars_.get(speed)
    spd = _number(sp.type_code, sp.text) if sp is not None and sp.text is not None else None
    tr.points.add(t, x, y, math.nan if spd is None else spd)
    tr.last_pos = (x, y)
    if tr.start is None:
        tr.start = (t, x, y)
    tr.end = (t, x, y)


def build_figure(data: PlotData, variables: Sequence[str] | None = None, title: str | None = None):
    """Draw :class:`PlotData`; returns the Figure (``1 + len(variables)`` panels, plus the
    speed colour bar axes, labelled ``<colorbar>``). Unknown or non-numeric variables in
    ``variables`` raise ValueError."""
    from matplotlib.figure import Figure

    names = list(data.variables) if variables is None else list(variables)
    unknown = [n for n in names if n not in data.series]
    if unknown:
        have = ", ".join(data.variables) or "none"
        raise ValueError(f"no numeric values for {', '.join(unknown)} in {data.path} (variables: {have})")
    names = names[:MAX_PANELS]
    n = len(names)
    strip = 1 if data.health.links else 0
    fig = Figure(figsize=(10, 6 + 1.7 * n + 1.2 * strip), dpi=100, layout="constrained")
    gs = fig.add_gridspec(1 + n + strip, 1, height_ratios=[4.5] + [1.5] * n + [1.0] * strip)
    ax = fig.add_subplot(gs[0])
    _draw_track(fig, ax, data)
    label = title or display_name(Path(data.path).name)
    fig.suptitle(
        f"{label}: {data.frames} frames, {data.duration_s:.1f} s, "
        f"{data.gaps} gaps, {data.checksum_failures} checksum failures"
    )
    first = None
    for i, name in enumerate(names):
        vax = fig.add_subplot(gs[1 + i], sharex=first)
        first = first or vax
        _draw_series(vax, data, name)
        if i < n - 1 or strip:
            vax.tick_params(labelbottom=False)
        else:
            vax.set_xlabel("time since the first frame (s)")
    if strip:
        qax = fig.add_subplot(gs[1 + n], sharex=first)
        _draw_quality(qax, data)
        qax.set_xlabel("time since the first frame (s)")
    return fig


#: the link-quality strip's axes label (not a variable panel)
QUALITY_LABEL = "<link quality>"


def _draw_quality(ax, data: PlotData) -> None:
    """Frames per second per link (Shepherd's link quality while up), outages shaded red."""
    ax.set_label(QUALITY_LABEL)
    t0 = (data.t0_ns or 0) / NS
    many = len(data.health.links) > 1
    for h in data.health.sorted_links():
        secs = list(quality(h))
        ax.step([x.second - t0 for x in secs], [math.nan if x.down_s is not None else x.frames for x in secs],
                where="post", linewidth=1.0,
                label=f"{h.link} {h.pair}" if many else None)
        for o in h.outages:
            a = (o.start_ns - (data.t0_ns or 0)) / NS
            ax.axvspan(a, a + o.duration_ns / NS, color="tab:red", alpha=0.3, linewidth=0)
    n = len(data.health.outages())
    ax.set_ylabel("frames/s", fontsize="small")
    ax.set_title(f"link quality ({n} outage{'s' if n != 1 else ''})", loc="left", fontsize="small")
    ax.grid(True, linewidth=0.3)
    if many:
        ax.legend(loc="upper right", fontsize="x-small")


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
    ax.set_xlabel("longitude (°)")
    ax.set_ylabel("latitude (°)")
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
        gcols = tr.gaps.columns()
        if gcols and any(not math.isnan(x) for x in gcols[2]):
            ax.plot(gcols[2], gcols[3], marker="o", markersize=9, markerfacecolor="none", markeredgecolor="tab:orange",
                    markeredgewidth=1.8, linestyle="none", zorder=3, label=f"gap ({tr.gaps.seen})" + suffix)
        bcols = tr.bad.columns()
        if bcols and any(not math.isnan(x) for x in bcols[1]):
            ax.plot(bcols[1], bcols[2], marker="x", markersize=8, color="red", markeredgewidth=2,
                    linestyle="none", zorder=3, label=f"bad checksum ({tr.bad.seen})" + suffix)
    if not drawn:
        ax.text(0.5, 0.5, f"no position ({LAT}/{LON}) in this capture", transform=ax.transAxes,
                ha="center", va="center", color="0.4")
        return
    mid = sum(lats) / len(lats)
    ax.set_aspect(1.0 / max(0.05, math.cos(math.radians(mid))), adjustable="datalim")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.grid(True, linewidth=0.3)
    ax.legend(loc="best", fontsize="small")
    if mappable is not None:
        cb = fig.colorbar(mappable, ax=ax, shrink=0.8, pad=0.01)
        cb.set_label(f"speed ({data.speed_var})" if mappable.norm is norm else "time (s)")


def _draw_series(ax, data: PlotData, name: str) -> None:
    by_pair = data.series.get(name, {})
    for pair, s in by_pair.items():
        cols = s.columns()
        if cols:
            t0_ns = data.t0_ns or 0
            spans = [((o.start_ns - t0_ns) / NS, (o.start_ns + o.duration_ns - t0_ns) / NS)
                     for o in data.health.outages() if o.pair == pair]
            ts, vs = broken(cols[0], cols[1], spans)
            ax.plot(ts, vs, drawstyle="steps-post", linewidth=1.0, label=pair if len(by_pair) > 1 else None)
    for tr in data.tracks.values():
        g = tr.gaps.columns()
        if g:
            for t0, t1 in zip(g[0], g[1]):
                ax.axvspan(t0, t1, color="tab:orange", alpha=0.25, linewidth=0)
        b = tr.bad.columns()
        if b:
            for t in b[0]:
                ax.axvline(t, color="red", alpha=0.5, linewidth=0.8)
    ax.set_ylabel(name, fontsize="small")
    ax.grid(True, linewidth=0.3)
    ax.ticklabel_format(axis="y", useOffset=False)
    if len(by_pair) > 1:
        ax.legend(loc="upper right", fontsize="x-small")


def figure_for_capture(path: str | Path, variables: Sequence[str] | None = None, **kw):
    """:func:`collect` then :func:`build_figure`: the Figure, for inspection."""
    return build_figure(collect(path, **kw), variables)


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
    data = collect(path, **kw)
    fig = build_figure(data, select)
    fig.savefig(str(out))
    return data
