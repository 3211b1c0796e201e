"""Exports: a capture's frames (or variable changes) as CSV, JSON Lines, GeoJSON, KML or MCAP.

Streaming: rows are written as frames are decoded (:func:`sharedlink.analysis.decode.iter_decoded`);
nothing grows with the capture except, for GeoJSON and KML, the track coordinates, which are
spooled to a temporary file and copied into the document at the end. CSV needs its columns
before the first row, so without ``columns`` its rows are spooled to a temporary file while the
variable names are learnt (one pass over the capture), then copied out after the header.

Rows, one per SharedLink frame (``changes=False``):
``number, time (UTC ISO 8601, ns), ts_ns, t (s since the first frame), src, dst, kind,
checksum (good/bad/none)`` then every variable's value as the frame leaves its direction's
table (values carried forward included; a frame with a bad checksum changes nothing), but for a
reply: its row holds the values the reply carries, typed as its direction's list types them
(a reply's values are never stored: docs/fields-sharedlink.md, "Replies"), and no other. A
row's ``changed`` (jsonl) names only values the row holds. With
``changes=True``: one row per variable that a frame gave a new value: ``number, time, ts_ns,
t, src, dst, name, type, value``. JSON exports carry typed values (numbers for long and
double); CSV keeps the text as sent.

GeoJSON: a FeatureCollection with one Point per data frame that has a position (properties: the
row) and one LineString track per direction. KML: one Placemark LineString track per direction
with start and end points (with their times).

MCAP (a binary file, for Foxglove and PlotJuggler) is written by
:mod:`sharedlink.analysis.mcap_export` (its channels: :mod:`sharedlink.analysis.foxglove_channels`);
:func:`export_file` dispatches to it.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any
from xml.sax.saxutils import escape as xml_escape

from sharedlink.analysis.decode import Decoded, Decoder, format_time
from sharedlink.analysis.robot_export import RobotCsv, RobotJsonl, RobotTrack
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import CaptureError, atomic_open, display_name
from sharedlink.defaults import EXPORT_BINARY_FORMATS, EXPORT_FORMATS
from sharedlink.errors import UsageError
from sharedlink.protocols.codec import TYPE_DOUBLE, TYPE_LONG
from sharedlink.protocols.state import BEACON_VARIABLES, Variable

FORMATS = EXPORT_FORMATS
#: formats written as bytes to a file by their own module (not through :func:`export`)
BINARY_FORMATS = EXPORT_BINARY_FORMATS
LAT, LON, HEADING, VELOCITY = "AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel"
#: the frames a position comes from (GeoJSON, KML): a reply's values are not its direction's
_DATA_KINDS = ("full", "delta")
FRAME_COLUMNS = ["number", "time", "ts_ns", "t", "src", "dst", "kind", "checksum"]
CHANGE_COLUMNS = ["number", "time", "ts_ns", "t", "src", "dst", "name", "type", "value"]


@dataclass
class ExportOptions:
    fmt: str = "csv"
    changes: bool = False
    variables: Sequence[tuple[str, int | None]] = BEACON_VARIABLES  # a-priori positional list
    columns: Sequence[str] | None = None  # variables to export (default: all in the capture)
    sync_interval: float = 1.0
    lat: str = LAT
    lon: str = LON
    heading: str = HEADING  # mcap: the LocationFix heading
    velocity: str = VELOCITY  # mcap: the speed variable (LocationFix velocity)
    require: Sequence[str] = ()  # names the capture must carry (csv/jsonl/geojson/kml), else UsageError
    progress: Callable[[int, int], None] | None = None  # called with (bytes read, records) now and then
    outages: bool = False  # jsonl, csv: outage rows (kind: outage, analysis/health.py) among the frames'
    outage_after: float | None = None  # ... their fixed threshold (None: learnt)


@dataclass
class ExportResult:
    rows: int = 0
    frames: int = 0
    points: int = 0  # positions written (GeoJSON/KML)
    columns: list[str] = field(default_factory=list)
    error: str | None = None  # the capture is damaged here; everything before it was written
    seen: set[str] = field(default_factory=set)  # variable names given a value (with opts.require)
    packets: int = 0  # P2OS packets and blackboard messages (csv/jsonl rows: robot_export.py)
    robot_rows_left_out: int = 0  # csv of a capture with SharedLink frames too: its robot rows, not written


def _checksum(d: Decoded) -> str:
    return "none" if d.checksum_ok is None else ("good" if d.checksum_ok else "bad")


def own_values(d: Decoded) -> dict[str, Variable]:
    """A reply's values as the row holds them (issue 40): the ones it carries itself, typed by its
    ``T`` or its direction's list (its Updates; never in the table)."""
    return {u.name: Variable(u.name, u.type_code, u.text) for u in d.updates if u.text is not None}


def row_vars(d: Decoded) -> dict[str, Variable]:
    """The values a frame's row holds: the direction's table after it, a reply's own values."""
    return own_values(d) if d.kind == "reply" else d.table.vars


def _typed(v: Variable | None) -> Any:
    """A variable's typed value for JSON (a number that JSON cannot hold stays text)."""
    if v is None or v.text is None:
        return None
    x = v.value  # (kept on the variable while its text stays: carried values cost nothing)
    if isinstance(x, float) and not math.isfinite(x):
        return v.text
    return x


#: jsonl lines gathered before one write
_HELD_LINES = 256


def _value_json(v: Variable) -> str:
    """``json.dumps(_typed(v))``, without the general typing: a long's or double's text that
    ``int()``/``float()`` take, once the forms they take beyond the protocol's (``_``, spaces,
    other digits) are ruled out, is converted directly (a float's and an int's JSON is their
    repr); ``nan``/``inf`` and overflowing exponents are not finite and stay text, as in
    :func:`~sharedlink.protocols.codec.parse_typed`."""
    t, tc = v.text, v.type_code
    if (tc == TYPE_DOUBLE or tc == TYPE_LONG or tc is None) and "_" not in t and t.isascii() and t.strip() == t:
        if tc != TYPE_DOUBLE:
            try:
                return repr(int(t))
            except ValueError:  # not an integer (or more digits than Python converts)
                if tc == TYPE_LONG:
                    return _jstr(t)
        try:
            x = float(t)
        except ValueError:
            return _jstr(t)
        if x - x == 0.0:  # finite (inf - inf and nan are nan)
            return repr(x)
    return _jstr(t)


#: a str as a JSON string (the C function json.dumps uses for one)
_jstr = json.encoder.encode_basestring_ascii  # type: ignore[attr-defined]


def _robot_rows(opts: ExportOptions) -> bool:
    """Whether P2OS and blackboard packets are rows too (csv, jsonl without --changes: one row a
    frame, every column) or an odometry track (geojson, kml: a track keeps every point)."""
    if opts.columns is not None:
        return False
    return opts.fmt in ("geojson", "kml") or (opts.fmt in ("csv", "jsonl") and not opts.changes)


def _frames(path: str | Path, opts: ExportOptions, result: ExportResult) -> Iterator[Decoded | SessionMessage]:
    """The decoded frames (and the P2OS/blackboard packets, :func:`_robot_rows`); damage after
    the first record ends the stream with ``error`` set."""
    seen = result.seen if opts.require else None
    try:
        # (rows read values from the table and what frames changed: carried Updates are not needed)
        dec = Decoder(opts.variables, opts.sync_interval, carried=False)
        if _robot_rows(opts):
            dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
        for item in dec.capture(path, opts.progress):
            if isinstance(item, Decoded):
                result.frames += 1
                if seen is not None:
                    seen.update(u.name for u in item.updates if u.text is not None)
                yield item
            elif type(item) is SessionMessage:
                result.packets += 1
                yield item
    except CaptureError as exc:
        if exc.record is None and result.frames == 0:
            raise
        result.error = str(exc)


class _Writer:
    """Rows for one capture: the base of the four formats."""

    def __init__(self, out: IO[str], opts: ExportOptions, columns: list[str]) -> None:
        self.out, self.opts, self.columns = out, opts, columns
        self.t0: int | None = None
        self.robot_rows: Any = None  # the P2OS/blackboard rows beside these (robot_export.py)

    def base(self, d: Decoded) -> dict[str, Any]:
        if self.t0 is None:
            self.t0 = d.ts_ns
        return {
            "number": d.number,
            "time": format_time(d.ts_ns),
            "ts_ns": d.ts_ns,
            "t": round((d.ts_ns - self.t0) / 1e9, 9),
            "src": d.src,
            "dst": d.dst,
        }

    def frame_row(self, d: Decoded) -> dict[str, Any]:
        row = self.base(d)
        row["kind"] = d.kind
        row["checksum"] = _checksum(d)
        return row

    def change_rows(self, d: Decoded, text: bool = False) -> Iterator[dict[str, Any]]:
        """One row per change, its value typed (``text``: as sent), from the frame's own
        Updates (a reply's values are never in the table: issue 29)."""
        wanted = self.opts.columns
        for u in d.changes():
            if wanted is not None and u.name not in wanted:
                continue
            row = self.base(d)
            row.update(name=u.name, type=u.type_code, value=u.text if text else _typed(Variable(u.name, u.type_code, u.text)))
            yield row

    def write(self, d: Decoded) -> int:
        raise NotImplementedError

    def close(self) -> None:
        pass


class _Csv(_Writer):
    """CSV rows. ``learn``: the columns are not known before the first row (every variable the
    capture gives a value, in order of first appearance), so rows go to a spool file with the
    columns known when they are written; :meth:`close` writes the header, then the rows, those
    written before the last column appeared padded with empty cells (a variable has no value
    in a row before the first frame that gives it one). One pass over the capture."""

    def __init__(self, out: IO[str], opts: ExportOptions, columns: list[str], learn: bool = False) -> None:
        super().__init__(out, opts, columns)
        self.learn = learn
        if learn:
            self.known = set(columns)
            self.pieces: list[str] = []
            self.spool = tempfile.TemporaryFile("w+b")  # noqa: SIM115 (closed in close)
            self.runs: list[list[int]] = [[len(columns), 0]]  # [columns known, rows written with them]
            self.w = csv.writer(_Pieces(self.pieces), lineterminator="\n")
            return
        self.w = csv.writer(out, lineterminator="\n")
        self.w.writerow(CHANGE_COLUMNS if opts.changes else self.head() + columns)

    def head(self) -> list[str]:
        """The frame columns (with ``--outages`` one more: an outage row's ``duration_s``)."""
        return FRAME_COLUMNS + (["duration_s"] if self.opts.outages else [])

    def outage(self, row: dict) -> None:
        """An outage's row (kind ``outage``): the frame that ends it (none when open), its start's
        time, the pair's letters, its duration; no values."""
        if self.t0 is None:
            self.t0 = row["start_ns"]
        ts = row["start_ns"]
        vals = [row["number"] if row["number"] is not None else "", format_time(ts), ts, round((ts - self.t0) / 1e9, 9),
                row["src"], row["dst"], "outage", "", repr(row["duration_s"])]
        if self.learn:
            runs = self.runs
            if runs[-1][0] != len(self.columns):
                runs.append([len(self.columns), 0])
            runs[-1][1] += 1
        self.w.writerow(vals + [""] * len(self.columns))

    def write(self, d: Decoded) -> int:
        if self.opts.changes:
            n = 0
            for row in self.change_rows(d, text=True):
                self.w.writerow(["" if row[c] is None else row[c] for c in CHANGE_COLUMNS])
                n += 1
            return n
        if self.learn:
            known = self.known
            for u in d.updates:
                if u.name not in known and u.text is not None:
                    known.add(u.name)
                    self.columns.append(u.name)
            runs = self.runs
            if runs[-1][0] != len(self.columns):
                runs.append([len(self.columns), 0])
            runs[-1][1] += 1
            if len(self.pieces) >= _HELD_LINES:
                self._spill()
        if self.t0 is None:
            self.t0 = d.ts_ns
        ts, ok = d.ts_ns, d.checksum_ok
        vars_ = row_vars(d)
        vals = [d.number, format_time(ts), ts, round((ts - self.t0) / 1e9, 9), d.src, d.dst, d.kind,
                "none" if ok is None else ("good" if ok else "bad")]
        if self.opts.outages:
            vals.append("")
        add = vals.append
        for name in self.columns:
            v = vars_.get(name)
            add("" if v is None or v.text is None else v.text)
        self.w.writerow(vals)
        return 1

    def _spill(self) -> None:
        self.spool.write("".join(self.pieces).encode("utf-8"))
        self.pieces.clear()

    def close(self) -> None:
        if not self.learn:
            return
        self._spill()
        self.spool.seek(0)
        out, width = self.out, len(self.columns)
        csv.writer(out, lineterminator="\n").writerow(self.head() + self.columns)
        with io.TextIOWrapper(self.spool, encoding="utf-8", newline="") as rows:
            pad = csv.writer(out, lineterminator="\n")
            reader = csv.reader(rows)
            for known, n in self.runs[:-1]:  # rows written before the last column appeared
                for row in itertools.islice(reader, n):
                    pad.writerow(row + [""] * (width - known))
            shutil.copyfileobj(rows, out, 1 << 20)  # (the last run has every column)


class _Pieces:
    """A file-like ``write`` that keeps what is written in a list (csv.writer's rows, gathered)."""

    def __init__(self, pieces: list[str]) -> None:
        self.write = pieces.append


class _Jsonl(_Writer):
    def __init__(self, out: IO[str], opts: ExportOptions, columns: list[str]) -> None:
        super().__init__(out, opts, columns)
        self._frags: dict[str, tuple[str, int | None, str]] = {}  # name -> (text, type, '"name": value')
        self._json: dict[str, str] = {}  # names as JSON strings
        self._heads: dict[tuple, str] = {}  # (src, dst, kind, checksum) -> their members, "values" opened
        self._names: dict[tuple[str, ...], str] = {}  # changed names -> their JSON list's inside
        self._held: list[str] = []  # lines not yet written (written in blocks: one write per block)

    def write(self, d: Decoded) -> int:
        if self.opts.changes:
            n = 0
            for row in self.change_rows(d):
                self.out.write(json.dumps(row) + "\n")
                n += 1
            return n
        held = self._held
        held.append(self.line(d))
        if len(held) >= _HELD_LINES:
            self.flush()
        return 1

    def outage(self, row: dict) -> None:
        """An outage's row, in its place among the frames' (kind: outage)."""
        if self.opts.changes:
            self.out.write(json.dumps(row) + "\n")
        else:
            self._held.append(json.dumps(row) + "\n")

    def flush(self) -> None:
        if self._held:
            self.out.write("".join(self._held))
            self._held.clear()

    def close(self) -> None:
        self.flush()

    def row(self, d: Decoded) -> dict[str, Any]:
        """A frame's row as a dict (the plain path :meth:`line` is checked against)."""
        row = self.frame_row(d)
        row["values"] = self.values(d)
        wanted = self.opts.columns
        row["changed"] = [u.name for u in d.changes() if wanted is None or u.name in wanted]
        return row

    def line(self, d: Decoded) -> str:
        """``json.dumps(self.row(d)) + "\\n"``, built from pieces kept while they hold: a
        value's ``"name": value`` is made again only when its text or type changed; the
        letters, kind and checksum members once per combination; the changed names once per
        list of names."""
        if d.kind == "reply":  # (rare: the plain path; its values are its own, never the table's)
            return json.dumps(self.row(d)) + "\n"
        if self.t0 is None:
            self.t0 = d.ts_ns
        frags, wanted = self._frags, self.opts.columns
        if len(frags) > 8192 or len(self._json) > 8192 or len(self._heads) > 8192 or len(self._names) > 8192:
            frags.clear()
            self._json.clear()
            self._heads.clear()
            self._names.clear()
        values = []
        add = values.append
        for n, v in d.table.vars.items():
            text = v.text
            if text is None or (wanted is not None and n not in wanted):
                continue
            f = frags.get(n)
            if f is None or f[0] is not text or f[1] != v.type_code:
                f = frags[n] = (text, v.type_code, "%s: %s" % (self._js(n), _value_json(v)))
            add(f[2])
        changed = tuple([u.name for u in d.updates if u.changed and not u.carried and u.text is not None
                         and (wanted is None or u.name in wanted)])
        names = self._names.get(changed)
        if names is None:
            names = self._names[changed] = ", ".join([self._js(n) for n in changed])
        ok = d.checksum_ok
        hkey = (d.src, d.dst, d.kind, ok)
        head = self._heads.get(hkey)
        if head is None:
            head = self._heads[hkey] = '"src": %s, "dst": %s, "kind": %s, "checksum": "%s", "values": {' % (
                self._js(d.src), self._js(d.dst), self._js(d.kind), "none" if ok is None else ("good" if ok else "bad"))
        ts = d.ts_ns
        return '{"number": %d, "time": "%s", "ts_ns": %d, "t": %r, %s%s}, "changed": [%s]}\n' % (
            d.number, format_time(ts), ts, round((ts - self.t0) / 1e9, 9), head, ", ".join(values), names)

    def _js(self, text: str) -> str:
        j = self._json.get(text)
        if j is None:
            j = self._json[text] = json.dumps(text)
        return j

    def values(self, d: Decoded) -> dict[str, Any]:
        wanted = self.opts.columns
        return {
            n: _typed(v)
            for n, v in row_vars(d).items()
            if v.text is not None and (wanted is None or n in wanted)
        }


class _Track:
    """Per-direction positions spooled to a temporary file (``lon lat ts_ns`` lines)."""

    def __init__(self) -> None:
        self.files: dict[str, IO[str]] = {}
        self.counts: dict[str, int] = {}
        self.first: dict[str, tuple[float, float, int]] = {}
        self.last: dict[str, tuple[float, float, int]] = {}

    def add(self, pair: str, lon: float, lat: float, ts: int) -> None:
        f = self.files.get(pair)
        if f is None:
            f = self.files[pair] = tempfile.TemporaryFile("w+", encoding="ascii")  # noqa: SIM115
            self.counts[pair] = 0
            self.first[pair] = (lon, lat, ts)
        f.write("%r %r %d\n" % (lon, lat, ts))
        self.counts[pair] += 1
        self.last[pair] = (lon, lat, ts)

    def coords(self, pair: str) -> Iterator[tuple[str, str, int]]:
        f = self.files[pair]
        f.flush()
        f.seek(0)
        for line in f:
            lon, lat, ts = line.split()
            yield lon, lat, int(ts)

    def close(self) -> None:
        for f in self.files.values():
            f.close()


def _position(d: Decoded, opts: ExportOptions) -> tuple[float, float] | None:
    vars_ = d.table.vars
    la, lo = vars_.get(opts.lat), vars_.get(opts.lon)
    if la is None or lo is None or la.text is None or lo.text is None:
        return None
    try:
        lat, lon = float(la.text), float(lo.text)
    except ValueError:
        return None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        return None
    return lat, lon


class _GeoJson(_Jsonl):
    def __init__(self, out: IO[str], opts: ExportOptions, columns: list[str]) -> None:
        super().__init__(out, opts, columns)
        self.track = _Track()
        self.first = True
        self.robots: RobotTrack | None = None  # P2OS odometry tracks, in the robot's frame (robot_export.py)
        out.write('{"type": "FeatureCollection", "features": [\n')

    def _feature(self, obj: dict[str, Any]) -> None:
        if not self.first:
            self.out.write(",\n")
        self.first = False
        self.out.write(json.dumps(obj))

    def write(self, d: Decoded) -> int:
        if d.checksum_ok is False or d.kind not in _DATA_KINDS:
            return 0
        pos = _position(d, self.opts)
        if pos is None:
            return 0
        lat, lon = pos
        self.track.add(d.pair, lon, lat, d.ts_ns)  # the track keeps every point (--changes too; KML's the same)
        if self.opts.changes:
            rows = list(self.change_rows(d))
            if not rows:
                return 0
            props = self.frame_row(d)
            props["changes"] = {r["name"]: r["value"] for r in rows}
        else:
            props = self.frame_row(d)
            props["values"] = self.values(d)
        self._feature({"type": "Feature", "geometry": {"type": "Point", "coordinates": [lon, lat]}, "properties": props})
        return 1

    def close(self) -> None:
        tr = self.track
        for pair in sorted(tr.files):
            src, _, dst = pair.partition(">")
            if not self.first:
                self.out.write(",\n")
            self.first = False
            self.out.write(
                '{"type": "Feature", "properties": %s, "geometry": {"type": "LineString", "coordinates": ['
                % json.dumps(
                    {
                        "track": pair,
                        "src": src,
                        "dst": dst,
                        "points": tr.counts[pair],
                        "start": format_time(tr.first[pair][2]),
                        "end": format_time(tr.last[pair][2]),
                    }
                )
            )
            sep = ""
            for lon, lat, _ts in tr.coords(pair):
                self.out.write("%s[%s, %s]" % (sep, lon, lat))
                sep = ", "
            self.out.write("]}}")
        for feature in self.robots.geojson() if self.robots is not None else ():
            self.out.write(("" if self.first else ",\n") + feature)
            self.first = False
        self.out.write("\n]}\n")
        tr.close()


class _Kml(_Writer):
    def __init__(self, out: IO[str], opts: ExportOptions, columns: list[str]) -> None:
        super().__init__(out, opts, columns)
        self.track = _Track()
        self.name = ""
        self.robots: RobotTrack | None = None  # P2OS odometry tracks, in the robot's frame (robot_export.py)

    def write(self, d: Decoded) -> int:
        if d.checksum_ok is False or d.kind not in _DATA_KINDS:
            return 0
        pos = _position(d, self.opts)  # (--changes too: the track keeps every point, as GeoJSON's)
        if pos is None:
            return 0
        self.track.add(d.pair, pos[1], pos[0], d.ts_ns)
        return 1

    def close(self) -> None:
        o, tr = self.out, self.track
        o.write('<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="http://www.opengis.net/kml/2.2">\n<Document>\n')
        o.write("<name>%s</name>\n" % xml_escape(self.name or "SharedLink tracks"))
        o.write(
            '<Style id="track"><LineStyle><color>ff0000ff</color><width>3</width></LineStyle></Style>\n'
            '<Style id="start"><IconStyle><color>ff00ff00</color></IconStyle></Style>\n'
            '<Style id="end"><IconStyle><color>ff0000ff</color></IconStyle></Style>\n'
        )
        for pair in sorted(tr.files):
            first, last = tr.first[pair], tr.last[pair]
            o.write("<Folder><name>%s</name>\n" % xml_escape(pair))
            o.write(
                "<Placemark><name>track %s</name><styleUrl>#track</styleUrl>"
                "<TimeSpan><begin>%s</begin><end>%s</end></TimeSpan>"
                "<LineString><tessellate>1</tessellate><coordinates>\n"
                % (xml_escape(pair), format_time(first[2]), format_time(last[2]))
            )
            for lon, lat, _ts in tr.coords(pair):
                o.write("%s,%s,0\n" % (lon, lat))
            o.write("</coordinates></LineString></Placemark>\n")
            for label, (lon, lat, ts) in (("start", first), ("end", last)):
                o.write(
                    "<Placemark><name>%s</name><styleUrl>#%s</styleUrl><TimeStamp><when>%s</when></TimeStamp>"
                    "<Point><coordinates>%r,%r,0</coordinates></Point></Placemark>\n"
                    % (label, label, format_time(ts), lon, lat)
                )
            o.write("</Folder>\n")
        if self.robots is not None:
            o.write(self.robots.kml())
        o.write("</Document>\n</kml>\n")
        tr.close()


_WRITERS: dict[str, type[_Writer]] = {"csv": _Csv, "jsonl": _Jsonl, "geojson": _GeoJson, "kml": _Kml}


def export(path: str | Path, out: IO[str], opts: ExportOptions) -> ExportResult:
    """Write ``path`` 's frames to ``out`` in ``opts.fmt``. A damaged capture: everything before
    the damage is written (and the document closed), ``error`` set. A missing or unreadable
    file raises :class:`~sharedlink.capture.pcapio.CaptureError`."""
    if opts.fmt not in _WRITERS:
        if opts.fmt in BINARY_FORMATS:
            raise ValueError(f"{opts.fmt} is written to a file: use export_file")
        raise ValueError(f"unknown format {opts.fmt!r} (one of {', '.join(FORMATS)})")
    result = ExportResult()
    columns = list(opts.columns) if opts.columns is not None else []
    result.columns = columns  # (csv without columns: the writer adds them as it learns them)
    return _write(path, out, opts, columns, result)


def _write(path: str | Path, out: IO[str], opts: ExportOptions, columns: list[str], result: ExportResult) -> ExportResult:
    frames = _frames(path, opts, result)
    first = next(frames, None)  # a missing/unreadable file raises here, before any output
    if opts.fmt == "csv" and not opts.changes and opts.columns is None:
        writer: _Writer = _Csv(out, opts, columns, learn=True)
    else:
        writer = _WRITERS[opts.fmt](out, opts, columns)
    if isinstance(writer, _Kml):
        writer.name = f"SharedLink tracks: {display_name(Path(path).name)}"
    robots: RobotCsv | RobotJsonl | RobotTrack | None = None
    if _robot_rows(opts):
        if isinstance(writer, (_GeoJson, _Kml)):
            robots = writer.robots = RobotTrack()
        else:
            robots = RobotJsonl(writer._held, writer.flush) if isinstance(writer, _Jsonl) else RobotCsv(opts.outages)
    writer.robot_rows = robots
    if opts.outages and type(writer) in (_Jsonl, _Csv):  # outage rows (kind: outage, link health)
        frames = _with_outages(itertools.chain([first] if first is not None else [], frames), writer, result)
        first = None
    try:
        for d in itertools.chain(() if first is None else (first,), frames):
            if type(d) is SessionMessage:
                if robots is not None:
                    result.rows += robots.write(d)  # type: ignore[arg-type]
                continue
            result.rows += writer.write(d)  # type: ignore[arg-type]
        missing = [n for n in opts.require if n not in result.seen]
        if missing and result.error is None:  # a file output is not left behind (atomic_open)
            have = ", ".join(sorted(result.seen)) or "none"
            raise UsageError(f"no variable {', '.join(missing)} in {display_name(str(path))} (its variables: {have})")
    finally:
        if isinstance(robots, RobotCsv) and robots.rows and result.frames == 0:
            robots.finish(out)  # a P2OS or blackboard capture: the CSV is theirs
        else:
            if isinstance(robots, RobotCsv):  # SharedLink frames too: the CSV keeps SharedLink's columns
                result.rows -= robots.rows
                result.robot_rows_left_out = robots.rows  # (the command warns: jsonl holds both)
            writer.close()
        if isinstance(robots, RobotCsv):
            robots.close()
    if isinstance(writer, (_GeoJson, _Kml)):
        result.points = sum(writer.track.counts.values()) + (robots.points if isinstance(robots, RobotTrack) else 0)
    return result


def _with_outages(frames: Iterator[Decoded], writer: _Jsonl | _Csv, result: ExportResult) -> Iterator[Decoded]:
    """The frames, an outage's row (analysis/health.py) written before the frame that ends it and
    the open ones at the end."""
    from sharedlink.analysis.health import OutageFeed, outage_row
    from sharedlink.analysis.robot_health import session_outages

    feed = OutageFeed(writer.opts.outage_after)
    csv_ = isinstance(writer, _Csv)
    robots = writer.robot_rows
    for d in frames:
        if type(d) is SessionMessage:  # a P2OS/blackboard packet: its robot link (analysis/robot_health.py)
            for o in session_outages(feed, d):
                _outage(writer, robots, o, d.number, csv_)
                result.rows += 1
            yield d
            continue
        for o in feed.feed(d):
            writer.outage(_csv_row(o, d.number) if csv_ else outage_row(o))
            result.rows += 1
        yield d
    for o in feed.finish():
        _outage(writer, robots, o, None, csv_)
        result.rows += 1


def _outage(writer: _Jsonl | _Csv, robots: Any, o, number: int | None, csv_: bool) -> None:
    """An outage's row: a robot link's in a CSV among the robot rows (their columns), else the writer's."""
    from sharedlink.analysis.health import outage_row

    if csv_ and isinstance(robots, RobotCsv) and o.link.partition(" ")[0] in ("p2os", "blackboard"):
        robots.outage(o, number)
    else:
        writer.outage(_csv_row(o, number) if csv_ else outage_row(o))


def _csv_row(o, number: int | None) -> dict:
    src, _, dst = o.pair.partition(">")
    return {"number": number, "start_ns": o.start_ns, "src": src, "dst": dst, "duration_s": o.duration_ns / 1e9}


def export_file(path: str | Path, dest: str | Path, opts: ExportOptions) -> ExportResult:
    """:func:`export` to a file, written beside it and renamed into place when complete."""
    if opts.fmt == "mcap":
        from sharedlink.analysis.mcap_export import export_mcap  # foxglove-sdk loads only for MCAP

        return export_mcap(path, dest, opts)
    with atomic_open(dest, "w", encoding="utf-8", newline="") as fh:
        return export(path, fh, opts)
