"""Decoded traffic as Foxglove channels: what the MCAP export writes and ``watch --foxglove`` serves.

:class:`FoxgloveChannels` turns :class:`~sharedlink.analysis.decode.Decoded` frames and
:class:`~sharedlink.analysis.sessions.SessionMessage` s into messages on channels of a
``foxglove.Context``; whatever sink is attached to the context (an MCAP writer, the WebSocket
server) receives them. Log time is the capture (or arrival) time in ns.

Topics (``B_to_A`` is the direction from node B to node A; a second conversation carrying the
same pair gets ``B_to_A_2``, the conversation is in the channel metadata):

* ``/sharedlink/B_to_A/location`` ``foxglove.LocationFix`` after each good value frame once the
  direction has a valid latitude and longitude (``lat``/``lon`` variables), in the units the
  official schema gives: ``heading`` in radians clockwise from north (the heading variable is in
  degrees), ``velocity`` east/north in m/s from the speed variable (in ``speed_unit``, mph for
  the beacon's AutoGpsVel, BUL-049) and the heading; no covariance is known: nine zeros,
  ``position_covariance_type`` UNKNOWN. The channel is made with its first message (a direction
  without a position has no location channel). The values channel keeps the variables as sent.
* ``/sharedlink/B_to_A/values`` JSON, after every frame: each variable's typed value
  (numbers for long and double, text for strings and for numbers JSON cannot hold).
* ``/sharedlink/B_to_A/frames`` JSON, every frame: number, src, dst, kind, checksum
  (good/bad/none), late, changed (names), text (as sent, CR LF left out).
* ``/p2os/N/pose`` ``foxglove.PoseInFrame`` (frame ``odom``) for each standard SIP of session N:
  x, y in metres, the heading as a rotation about z; ``/p2os/N/sip`` the whole SIP as JSON
  (velocities, battery, ...); ``/p2os/N/commands`` the client's commands as JSON;
  ``/p2os/N/server`` the robot's other packets (SYNC echoes, CONFIG, ENCODER) as JSON.
* ``/blackboard/N/messages`` JSON: the master's set and request messages and the slave's
  answers (ack or read response), with their checksum verdicts.
"""

from __future__ import annotations

import json
import math
import re
import struct
from dataclasses import dataclass, field
from itertools import repeat
from operator import itemgetter
from typing import Any

import foxglove
from foxglove.channels import PoseInFrameChannel
from foxglove.messages import (
    LocationFix,
    LocationFixPositionCovarianceType,
    Timestamp,
    Vector3,
)

from sharedlink.analysis.decode import VALUE_KINDS, Columns, Decoded, DirColumns
from sharedlink.analysis.robot_foxglove import blackboard_json, command_json, server_json, sip_json, sip_pose
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import NS
from sharedlink.errors import UsageError
from sharedlink.protocols import p2os
from sharedlink.protocols.codec import TYPE_DOUBLE, TYPE_LONG, guess_value, parse_typed
from sharedlink.protocols.state import Variable

# -- default variable names (the beacon's, BUL-009)
LAT, LON, HEADING, SPEED = "AutoGpsLat", "AutoGpsLon", "AutoGpsHead", "AutoGpsVel"

# -- JSON schemas (titles are the schema names tools show)
_ANY = {"type": ["number", "string", "null"]}
VALUES_SCHEMA = {"type": "object", "title": "sharedlink.Values", "additionalProperties": _ANY}
FRAME_SCHEMA = {
    "type": "object",
    "title": "sharedlink.Frame",
    "properties": {
        "number": {"type": "integer"}, "src": {"type": "string"}, "dst": {"type": "string"},
        "kind": {"type": "string"}, "checksum": {"type": "string", "enum": ["good", "bad", "none"]},
        "late": {"type": "boolean"}, "changed": {"type": "array", "items": {"type": "string"}},
        "text": {"type": "string"},
    },
}
SIP_SCHEMA = {"type": "object", "title": "p2os.Sip", "additionalProperties": True}
COMMAND_SCHEMA = {"type": "object", "title": "p2os.Command", "additionalProperties": True}
SERVER_SCHEMA = {"type": "object", "title": "p2os.ServerPacket", "additionalProperties": True}
BLACKBOARD_SCHEMA = {"type": "object", "title": "blackboard.Message", "additionalProperties": True}


#: metres per second in one unit of speed (``ChannelOptions.speed_unit``)
SPEED_UNITS = {"mph": 0.44704, "m/s": 1.0, "km/h": 1 / 3.6, "kn": 1852 / 3600}
#: LocationFix.position_covariance when none is known (the schema wants 9 items, type UNKNOWN)
_NO_COVARIANCE = [0.0] * 9
_UNKNOWN_COVARIANCE = LocationFixPositionCovarianceType.Unknown


@dataclass
class ChannelOptions:
    lat: str = LAT
    lon: str = LON
    heading: str = HEADING  # degrees clockwise from north
    speed: str = SPEED
    speed_unit: str = "mph"  # the speed variable's unit, a key of SPEED_UNITS (BUL-049: AutoGpsVel in mph)
    #: channels that may be opened, or None for no limit (an MCAP file holds at most 65535: its
    #: channel id is 16 bits, and foxglove-sdk drops every message of a channel past it)
    max_channels: int | None = None

    def __post_init__(self) -> None:
        if self.speed_unit not in SPEED_UNITS:
            raise ValueError(f"speed unit {self.speed_unit!r}: one of {', '.join(SPEED_UNITS)}")


def _typed(v: Any) -> Any:
    x = v.value
    if isinstance(x, float) and not math.isfinite(x):
        return v.text
    return x


#: a JSON number; a value sent in this form goes into the values message as sent
_JSON_NUMBER = re.compile(r"-?(?:0|[1-9][0-9]*)(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?\Z")


#: a variable name's JSON string (a few names a capture)
_NAME_JSON: dict[str, str] = {}


def _fragment(name: str, v: Any) -> tuple[Any, str]:
    """A variable's typed value and its ``"name": value`` JSON member (:func:`_fragment_of`)."""
    return _fragment_of(name, v.text, v.type_code, v)


def _fragment_of(name: str, t: str, tc: int | None, v: Any = None) -> tuple[Any, str]:
    """The typed value of text ``t`` of type ``tc`` and its ``"name": value`` JSON member. A
    number whose text is already a JSON number of the same kind (integer text for a long, a
    fraction or exponent for a double) is written as sent: JSON reads it back as the same
    value, and the float is not formatted again.

    Hot path (each changed variable of each frame): a JSON-number text of an untyped, long or
    double variable is converted here, once (``Variable.value`` would match it against its
    type's pattern first); anything else takes the general way below (``v``: the Variable,
    whose value is kept on it; else typed as it types it)."""
    key = _member_key(name)
    if (tc is None or tc == TYPE_LONG or tc == TYPE_DOUBLE) and _JSON_NUMBER.match(t) is not None:
        if t.lstrip("-").isdigit():
            if tc != TYPE_DOUBLE:
                return int(t), key + t
        elif tc != TYPE_LONG:
            x = float(t)
            if math.isfinite(x):
                return x, key + t
    if v is not None:
        x = _typed(v)
    else:  # (as Variable.value, then _typed)
        x = guess_value(t) if tc is None else parse_typed(tc, t)[0]
        if isinstance(x, float) and not math.isfinite(x):
            x = t
    if type(x) is float:
        plain = _JSON_NUMBER.match(t) is not None and ("." in t or "e" in t or "E" in t)
    elif type(x) is int:
        plain = _JSON_NUMBER.match(t) is not None and t.lstrip("-").isdigit()
    else:
        plain = False
    return x, key + (t if plain else _dumps(x))


def _plain_decimals(texts: list[str]) -> list[float] | None:
    """The floats of ``texts`` when every one is a JSON number with a fraction and no exponent
    (``-?(0|[1-9][0-9]*)\\.[0-9]+``, a beacon's doubles) and finite, else None. Checked on all
    of them at once by counting in the joined lines (C speed; a pattern over them costs three
    times as much): only digits, ``.``, ``-`` and newlines; one ``.`` a line (as many as lines,
    and ``float`` refuses a line with two), a digit on both sides of it, a leading 0 only
    right before the ``.`` (``float`` refuses a ``-`` but first)."""
    n = len(texts)
    h = "\n" + "\n".join(texts) + "\n"
    if (h.count(".") != n or h.count("\n") != n + 1 or not h.isascii()
            or h.encode().translate(None, b"0123456789.-\n") or "\n." in h or "\n-." in h or ".\n" in h
            or h.count("\n0") + h.count("\n-0") != h.count("\n0.") + h.count("\n-0.")):
        return None
    try:
        values = list(map(float, texts))
    except ValueError:  # (a line with two points, another with none)
        return None
    return values if math.isfinite(sum(values)) else None  # (an infinite sum of finite values: None too)


def _rows_typed(names: list[str], texts: list[str], tcs: list[int | None], changed: list[bool], a0: int,
                a1: int) -> tuple[list[Any], list[str]]:
    """The typed values and JSON members (:func:`_fragment_of`) of value rows ``a0 .. a1 - 1``
    (those of rows not ``changed`` are not used: they may be anything). Hot path: when every row
    is a double sent as a plain decimal (:func:`_plain_decimals`), all at once: the members are
    the name and the text as sent."""
    tx = texts[a0:a1]
    n = a1 - a0
    if n and tcs[a0:a1].count(TYPE_DOUBLE) == n:
        values = _plain_decimals(tx)
        if values is not None:
            nm = names[a0:a1]
            keys = {x: _member_key(x) for x in set(nm)}
            return values, list(map(str.__add__, map(keys.__getitem__, nm), tx))
    typed: list[Any] = []
    frags: list[str] = []
    for j in range(a0, a1):
        if changed[j]:
            x, f = _fragment_of(names[j], texts[j], tcs[j])
        else:
            x, f = None, ""
        typed.append(x)
        frags.append(f)
    return typed, frags


def _names_json(changed: list[str]) -> str:
    """The JSON list of a frame's changed names, kept for a few lists a capture."""
    key = tuple(changed)
    names = _NAMES.get(key)
    if names is None:
        names = _dumps(changed)
        if len(_NAMES) < _NAMES_MAX:
            _NAMES[key] = names
    return names


def _member_key(name: str) -> str:
    """``"name": `` (a JSON member's start), kept for a few names a capture."""
    key = _NAME_JSON.get(name)
    if key is None:
        key = _jstr(name) + ": "
        if len(_NAME_JSON) < _NAMES_MAX:
            _NAME_JSON[name] = key
    return key


#: the types of a number among typed values (compared by type(): a bool is not one)
_NUMERIC = (int, float)


_dumps = json.dumps
#: a str as a JSON string (the C function json.dumps uses for one, without its overhead)
_jstr = json.encoder.encode_basestring_ascii  # type: ignore[attr-defined]
#: JSON of lists of changed names (FoxgloveChannels.frame's cache)
_NAMES: dict[tuple[str, ...], str] = {}
_NAMES_MAX = 4096
#: the frames message, formatted by hand (see FoxgloveChannels.frame)
_ROW = ('{"number": %%d, "src": %s, "dst": %s, "kind": "%s", "checksum": "%s", "late": %s, "changed": %%s, '
        '"text": %%s}')


def values_json(d: Decoded) -> dict[str, Any]:
    """A frame's ``values`` message (the reference for :meth:`FoxgloveChannels.frame`): its
    direction's values after it; a reply's: the values it carries (issue 40: never stored, so
    never the table's), typed by its ``T`` or its direction's list."""
    if d.kind == "reply":
        return {u.name: _typed(Variable(u.name, u.type_code, u.text)) for u in d.updates if u.text is not None}
    return {n: _typed(v) for n, v in d.table.vars.items() if v.text is not None}


def frame_json(d: Decoded) -> dict[str, Any]:
    """A frame's ``frames`` message (the reference :meth:`FoxgloveChannels.frame` formats by hand)."""
    text = d.raw.decode("latin-1")
    return {"number": d.number, "src": d.src, "dst": d.dst, "kind": d.kind, "checksum": _checksum(d.checksum_ok),
            "late": d.late, "changed": [u.name for u in d.changes()], "text": text[:-2] if text.endswith("\r\n") else text}


#: LocationFixChannel's schema (the location channels are fed encoded LocationFix messages)
_FIX_SCHEMA = LocationFix.get_schema()
#: the packed position_covariance field (9 zero doubles): field 4, length 72; the covariance
#: type (5) is UNKNOWN, 0, left out
_COVARIANCE_FIELD = b"\x22\x48" + bytes(72)


#: [True: the hand-made LocationFix encoding equals foxglove-sdk's (checked on the first fix),
#: False: it does not (the sdk's is used), None: not checked yet]
_splice: list[bool | None] = [None]
_pack_double = struct.Struct("<d").pack
#: latitude (field 1) and longitude (field 2) with their tags
_pack_lat_lon = struct.Struct("<BdBd").pack


#: _tail's cache (all directions), at most
_TAILS_MAX = 8192


def _varint(n: int) -> bytes:
    if 0 <= n < 0x4000:  # (lengths, and counts of a few thousand)
        return _BYTE[n] if n < 0x80 else bytes(((n & 0x7F) | 0x80, n >> 7))
    if 0x10000000 <= n < 0x800000000:  # (five bytes: the seconds of times from 1978 to 3058, most nanos)
        return bytes(((n & 0x7F) | 0x80, (n >> 7 & 0x7F) | 0x80, (n >> 14 & 0x7F) | 0x80, (n >> 21 & 0x7F) | 0x80, n >> 28))
    n &= 0xFFFFFFFFFFFFFFFF  # (a negative int64: ten bytes, two's complement)
    out = bytearray()
    while n >= 0x80:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


_last_seconds: tuple[int | None, bytes] = (None, b"")


def _timestamp_field(ts_ns: int) -> bytes:
    """LocationFix's timestamp field (6: google.protobuf.Timestamp, seconds 1 and nanos 2, each
    left out when 0) for ``ts_ns``."""
    global _last_seconds
    sec, nanos = divmod(ts_ns, NS)
    last = _last_seconds
    if last[0] != sec:
        last = _last_seconds = (sec, b"\x08" + _varint(sec) if sec else b"")
    frac = _NANOS.get(nanos)
    if frac is None:  # (frames at a steady rate share a few fractions of a second)
        if len(_NANOS) >= 4096:
            _NANOS.clear()
        frac = _NANOS[nanos] = b"\x10" + _varint(nanos) if nanos else b""
    body = last[1] + frac
    return b"\x32" + _LENGTH[len(body)] + body


def _timestamp_bodies(ts: list[int]) -> list[bytes]:
    """The insides of :func:`_timestamp_field` for each of a run's times (a few seconds, a few
    fractions of one: each made once), in passes over the run."""
    sn = list(map(divmod, ts, repeat(NS)))
    secs, nanos = list(map(itemgetter(0), sn)), list(map(itemgetter(1), sn))
    sf = {s: b"\x08" + _varint(s) if s else b"" for s in set(secs)}
    nf = {n: b"\x10" + _varint(n) if n else b"" for n in set(nanos)}
    return list(map(bytes.__add__, map(sf.__getitem__, secs), map(nf.__getitem__, nanos)))


#: the timestamp field's tag and one-byte length, by length
_STAMP_HEAD = [b"\x32" + bytes((n,)) for n in range(128)]
#: nanos of a second -> their field; a one-byte length
_NANOS: dict[int, bytes] = {}
_LENGTH = _BYTE = [bytes((n,)) for n in range(128)]


def _stamp(ts_ns: int) -> Timestamp:
    return Timestamp(ts_ns // NS, ts_ns % NS)


def _checksum(ok: bool | None) -> str:
    return "none" if ok is None else ("good" if ok else "bad")


@dataclass
class _Direction:
    """The channels of one direction, and its last values message (reused while unchanged)."""

    location: Any  # made with the first location message (None until then)
    values: Any
    frames: Any
    meta: dict[str, str] = field(default_factory=dict)
    log_frames: Any = None  # the channels' log methods (bytes, log time)
    log_values: Any = None
    nvars: int = -1
    typed: dict[str, Any] = field(default_factory=dict)  # name -> typed value
    frags: dict[str, str] = field(default_factory=dict)  # name -> '"name": value' (JSON)
    values_json: bytes = b"{}"
    location_topic: str = ""
    values_topic: str = ""
    frames_topic: str = ""
    nframes: int = 0
    nlocations: int = 0
    nmalformed: int = 0  # frames of kind malformed: a frames message, no values message
    ngaps: int = 0  # values messages that break the plotted lines at an outage (foxglove_health)
    log_location: Any = None
    pair: str = ""  # "B>A"
    src: str = ""
    dst: str = ""
    rows: dict[tuple, str] = field(default_factory=dict)  # (kind, checksum ok, late) -> frames row format
    fix: tuple | None = None  # (heading, speed as typed, frame id, _fix_tail) of the last fix made


@dataclass
class _Session:
    prefix: str
    metadata: dict[str, str]
    channels: dict[str, Any] = field(default_factory=dict)
    sip: dict[str, Any] = field(default_factory=dict)  # p2os: the last SIP's JSON (foxglove_health's gap messages)


class FoxgloveChannels:
    """Publishes decoded frames and session messages on channels of ``context``."""

    def __init__(self, context: foxglove.Context, opts: ChannelOptions | None = None) -> None:
        self.ctx = context
        self.opts = opts or ChannelOptions()
        self._speed_scale = SPEED_UNITS[self.opts.speed_unit]
        self._counts: dict[str, int] = {}  # session topic -> messages logged (directions count their own)
        self._dirs: dict[tuple[object, str, str], _Direction] = {}
        self._pair_convs: dict[str, int] = {}
        self._sessions: dict[tuple[str, int], _Session] = {}
        self._labels: dict[tuple[str, str], _Session] = {}  # (protocol, label) -> its first session (foxglove_health)
        self._channels_left = self.opts.max_channels
        #: (frame id, heading, speed) -> _fix_tail, for all directions (_tail), at most _TAILS_MAX
        self._tails: dict[tuple[str, Any, Any], bytes] = {}

    def _open(self, n: int) -> None:
        """Account for ``n`` channels about to be opened; past ``max_channels`` a clear refusal
        (a UsageError: the export writes no file) instead of messages lost one by one."""
        if self._channels_left is None:
            return
        if self._channels_left < n:
            raise UsageError(f"more conversations than an MCAP file has channels ({self.opts.max_channels}: three a "
                             f"direction, one a session topic); export a part of the capture, or as jsonl")
        self._channels_left -= n

    # -- SharedLink ------------------------------------------------------------------------

    def _direction(self, d: Decoded) -> _Direction:
        key = (d.conv, d.src, d.dst)
        dr = self._dirs.get(key)
        if dr is None:
            self._open(2)
            name = f"{d.src}_to_{d.dst}"
            n = self._pair_convs[name] = self._pair_convs.get(name, 0) + 1
            base = f"/sharedlink/{name}" + (f"_{n}" if n > 1 else "")
            meta = {"src": d.src, "dst": d.dst, "conversation": " ".join(map(str, d.conv))}
            dr = self._dirs[key] = _Direction(
                None,
                foxglove.Channel(base + "/values", schema=VALUES_SCHEMA, metadata=meta, context=self.ctx),
                foxglove.Channel(base + "/frames", schema=FRAME_SCHEMA, metadata=meta, context=self.ctx),
                meta,
            )
            dr.location_topic, dr.values_topic, dr.frames_topic = base + "/location", base + "/values", base + "/frames"
            dr.pair, dr.src, dr.dst = d.pair, d.src, d.dst
            # the base channels' log, called with encoded bytes (foxglove.Channel.log's own path
            # for bytes, without its type checks)
            dr.log_frames, dr.log_values = dr.frames.base.log, dr.values.base.log
        return dr

    def frame(self, d: Decoded) -> None:
        """The frames, values and (when known) location messages of one frame.

        Hot path (one call per frame): typed values are kept per direction and redone only for
        the variables the frame changed (all of them when the table grew or a list was
        declared), the values message is re-encoded only then, and the frame row is formatted
        by hand; :func:`frame_json` and :func:`values_json` are the plain references."""
        src, dst = d.src, d.dst   # (not d.frame: watch's fast path parses it only when asked)
        dr = self._dirs.get((d.conv, src, dst)) or self._direction(d)
        ts = d.ts_ns
        if d.kind == "malformed":  # a frame that sets and shows nothing: its frames message only
            self._emit(dr, dr.typed, d.number, d.kind, d.checksum_ok, False, d.raw, ts, [], False)
            return
        if d.kind == "reply":  # its own values (never the direction's), no position (issue 40)
            own = [u for u in d.updates if u.text is not None]
            body = ", ".join([_fragment_of(u.name, u.text, u.type_code)[1] for u in own])  # type: ignore[arg-type]
            changed = [u.name for u in own if u.changed and not u.carried]
            self._emit(dr, dr.typed, d.number, d.kind, d.checksum_ok, d.late, d.raw, ts, changed,
                       ("{%s}" % body).encode())
            return
        vars_ = d.table.vars
        changed = [u.name for u in d.updates if u.changed and not u.carried and u.text is not None]
        typed = dr.typed
        if len(vars_) != dr.nvars or d.kind == "declaration":
            dr.nvars = len(vars_)
            dr.typed, dr.frags = typed, frags = {}, {}
            for n, v in vars_.items():
                if v.text is not None:
                    typed[n], frags[n] = _fragment(n, v)
            dr.values_json = ("{%s}" % ", ".join(frags.values())).encode()
        elif changed:
            frags = dr.frags
            for n in changed:
                v = vars_.get(n)
                if v is not None and v.text is not None:
                    typed[n], frags[n] = _fragment(n, v)
                else:  # (a reply's value stays on the reply: the table has none)
                    typed.pop(n, None)
                    frags.pop(n, None)
            dr.values_json = ("{%s}" % ", ".join(frags.values())).encode()
        self._emit(dr, typed, d.number, d.kind, d.checksum_ok, d.late, d.raw, ts, changed)

    def _emit(self, dr: _Direction, typed: dict[str, Any], number: int, kind: str, ok: bool | None, late: bool,
              raw: bytes, ts: int, changed: list[str], values: bool | bytes = True) -> None:
        """A frame's frames, values (``values``: True the direction's, bytes a reply's own, False
        none) and location messages (a data frame's), its direction's values up to date."""
        names = _names_json(changed) if changed else "[]"
        fmt = dr.rows.get((kind, ok, late)) or self._row_format(dr, kind, ok, late)
        row = fmt % (number, names, _jstr((raw[:-2] if raw.endswith(b"\r\n") else raw).decode("latin-1")))
        dr.log_frames(row.encode(), ts)
        if values is True:
            dr.log_values(dr.values_json, ts)
        elif values:
            dr.log_values(values, ts)
        else:
            dr.nmalformed += 1
        dr.nframes += 1
        if values is True and ok is not False and kind in VALUE_KINDS:
            fix = self._fix_bytes(dr, typed, ts, dr.pair)
            if fix is not None:
                if dr.location is None:
                    self._open_location(dr)
                dr.log_location(fix, ts)
                dr.nlocations += 1

    @staticmethod
    def _row_format(dr: _Direction, kind: str, ok: bool | None, late: bool) -> str:
        """The direction's frames row with its letters, kind, checksum and late filled in (made once)."""
        fmt = dr.rows.get((kind, ok, late))
        if fmt is None:
            fixed = [_jstr(dr.src), _jstr(dr.dst), kind, "none" if ok is None else ("good" if ok else "bad")]
            fmt = dr.rows[(kind, ok, late)] = _ROW % (*[f.replace("%", "%%") for f in fixed], "true" if late else "false")
        return fmt

    def _open_location(self, dr: _Direction) -> None:
        """The direction's location channel (LocationFixChannel's schema and encoding, fed bytes)."""
        self._open(1)
        dr.location = foxglove.Channel(dr.location_topic, schema=_FIX_SCHEMA, message_encoding="protobuf",
                                       metadata=dr.meta, context=self.ctx)
        dr.log_location = dr.location.base.log

    def columns(self, b: Columns) -> None:
        """The messages of a batch of the decoding core's columns mode (named data frames with
        a good checksum, their value rows without carried values), in capture order: what
        :meth:`frame` publishes for each of its frames (the tests compare the files).

        Hot path: the batch is walked in runs of frames of one direction (the whole batch when
        one direction sent it), the direction's columns bound once a run."""
        dirs = list(b.dirs.values())
        if len(dirs) == 1:
            runs = [(0, 0, b.frames)]
        else:  # (capture order: who sent each frame, then runs of one sender)
            owner = [0] * b.frames
            for k, c in enumerate(dirs):
                for o in c.ordinal:
                    owner[o] = k
            runs = []
            start = [0] * len(dirs)
            o = 0
            while o < b.frames:
                k = owner[o]
                e = o + 1
                while e < b.frames and owner[e] == k:
                    e += 1
                runs.append((k, start[k], start[k] + e - o))
                start[k] += e - o
                o = e
        at = [0] * len(dirs)
        for k, i0, i1 in runs:
            c = dirs[k]
            a0 = at[k]
            at[k] = self._run(c, i0, i1, a0)

    def _run(self, c: DirColumns, i0: int, i1: int, a0: int) -> int:
        """The messages of frames ``i0 .. i1 - 1`` of ``c`` (one direction's run), whose value
        rows start at ``a0``; returns where the next run's rows start. What :meth:`_emit` does
        for each frame, in three passes: the direction's state walked frame by frame (the
        changed rows' typed values and JSON members made for the whole run at once by
        :func:`_rows_typed`; each frame's changed names, values message and position kept),
        then the frames rows and the locations made for the whole run (:meth:`_locations`),
        then the messages logged, frame after frame."""
        dr = self._dirs[(c.conv, c.src, c.dst)]  # (a direction's first frame is never batched)
        typed, frags = dr.typed, dr.frags
        nv, nm, chg = c.nvalues, c.name, c.changed
        a1 = a0 + sum(nv[i0:i1])
        tv, fv = _rows_typed(nm, c.text, c.type_code, chg, a0, a1)
        o = self.opts
        olat, olon, ohead, ospeed = o.lat, o.lon, o.heading, o.speed
        values_json = dr.values_json
        names_l: list[str] = []
        values_l: list[bytes] = []
        lats: list[Any] = []
        lons: list[Any] = []
        heads: list[Any] = []
        speeds: list[Any] = []
        get = typed.get
        a = a0
        for n in nv[i0:i1]:
            names = "[]"
            if n:
                e = a + n
                if True in chg[a:e]:
                    changed = []
                    for j in range(a, e):
                        if chg[j]:
                            x = nm[j]
                            changed.append(x)
                            typed[x] = tv[j - a0]
                            frags[x] = fv[j - a0]
                    values_json = ("{%s}" % ", ".join(frags.values())).encode()
                    names = _names_json(changed)
                a = e
            names_l.append(names)
            values_l.append(values_json)
            lats.append(get(olat))
            lons.append(get(olon))
            heads.append(get(ohead))
            speeds.append(get(ospeed))
        dr.values_json = values_json
        fmts = {k: (self._row_format(dr, k, True, False), self._row_format(dr, k, True, True))
                for k in set(c.kind[i0:i1])}
        rows = [(fmts[k][lt] % (number, names, _jstr((r[:-2] if r[-2:] == b"\r\n" else r).decode("latin-1")))).encode()
                for k, lt, number, names, r in zip(c.kind[i0:i1], c.late[i0:i1], c.number[i0:i1], names_l, c.raw[i0:i1])]
        ts = c.ts_ns[i0:i1]
        fixes = self._locations(dr, ts, lats, lons, heads, speeds)
        log_frames, log_values = dr.log_frames, dr.log_values
        if fixes is None:
            for row, vj, t in zip(rows, values_l, ts):
                log_frames(row, t)
                log_values(vj, t)
        else:
            if dr.location is None:
                self._open_location(dr)
            log_location = dr.log_location
            for row, vj, fix, t in zip(rows, values_l, fixes, ts):
                log_frames(row, t)
                log_values(vj, t)
                if fix is not None:
                    log_location(fix, t)
            dr.nlocations += len(fixes) - fixes.count(None)
        dr.nframes += i1 - i0
        return a1

    def _locations(self, dr: _Direction, ts: list[int], lats: list[Any], lons: list[Any], heads: list[Any],
                   speeds: list[Any]) -> list[bytes | None] | None:
        """The run's LocationFix messages (None for a frame without a position; None for the
        whole run when no frame has one), as :meth:`_fix_bytes` makes each. Hot path, when
        every position is two non-zero doubles in range: the fields packed for the whole run,
        the tails looked up per (heading, speed) (:meth:`_tail`; a pair with a zero in it is
        never kept, so it is made as :meth:`_fix_bytes` does)."""
        pair = dr.pair
        if (_splice[0] is not True or set(map(type, lats)) != {float} or set(map(type, lons)) != {float}
                or 0.0 in lats or 0.0 in lons or min(lats) < -90.0 or max(lats) > 90.0 or min(lons) < -180.0
                or max(lons) > 180.0):
            typed: dict[str, Any] = {}
            o = self.opts
            out: list[bytes | None] = []
            for t, typed[o.lat], typed[o.lon], typed[o.heading], typed[o.speed] in zip(ts, lats, lons, heads, speeds):
                out.append(self._fix_bytes(dr, typed, t, pair))
            return None if out.count(None) == len(out) else out
        tails = list(map(self._tails.get, zip(repeat(pair), heads, speeds)))
        if None in tails:
            for k, tail in enumerate(tails):
                if tail is None:
                    head, speed = heads[k], speeds[k]
                    fx = dr.fix
                    if fx is None or fx[0] is not head or fx[1] is not speed or fx[2] != pair:
                        fx = dr.fix = (head, speed, pair, self._tail(dr, head, speed))
                    tails[k] = fx[3]
        stamps = _timestamp_bodies(ts)
        return list(map(b"".join, zip(map(_pack_lat_lon, repeat(9), lats, repeat(0x11), lons), repeat(_COVARIANCE_FIELD),
                                      map(_STAMP_HEAD.__getitem__, map(len, stamps)), stamps, tails)))  # type: ignore[arg-type]

    def _fix_bytes(self, dr: _Direction, typed: dict[str, Any], ts_ns: int, frame_id: str) -> bytes | None:
        """The direction's LocationFix after a frame, protobuf-encoded (None: no position), as
        foxglove-sdk encodes :meth:`_location`'s message (checked once per process against it,
        else that is used; the tests compare them on many values). Hot path: the fields that
        follow the timestamp (frame id, heading, velocity) are kept while heading, speed and
        frame id stay; latitude, longitude and the timestamp are packed per frame."""
        o = self.opts
        lat, lon = typed.get(o.lat), typed.get(o.lon)
        if type(lat) is not float or type(lon) is not float:  # (the common case: both doubles)
            if type(lat) not in _NUMERIC or type(lon) not in _NUMERIC:
                return None
            lat, lon = float(lat), float(lon)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return None
        head, speed = typed.get(o.heading), typed.get(o.speed)
        c = dr.fix
        if c is None or c[0] is not head or c[1] is not speed or c[2] != frame_id:
            c = dr.fix = (head, speed, frame_id, self._fix_tail(head, speed, frame_id))
        if lat != 0.0 and lon != 0.0:
            where = _pack_lat_lon(9, lat, 0x11, lon)
        else:
            where = (b"\x09" + _pack_double(lat) if lat != 0.0 else b"") + (b"\x11" + _pack_double(lon) if lon != 0.0 else b"")
        msg = b"".join((where, _COVARIANCE_FIELD, _timestamp_field(ts_ns), c[3]))
        if _splice[0] is not True:
            whole = self._location(typed, ts_ns, frame_id).encode()  # type: ignore[union-attr]
            if _splice[0] is None:
                _splice[0] = msg == whole
            return whole
        return msg

    def _tail(self, dr: _Direction, head: Any, speed: Any) -> bytes:
        """:meth:`_fix_tail` for the direction, kept per heading and speed value while both are
        not zero (equal non-zero numbers encode alike, 0.0 and -0.0 do not): a vehicle's
        headings and speeds repeat."""
        if not head or not speed:
            return self._fix_tail(head, speed, dr.pair)
        tails, key = self._tails, (dr.pair, head, speed)
        tail = tails.get(key)
        if tail is None:
            if len(tails) >= _TAILS_MAX:
                tails.clear()
            tail = tails[key] = self._fix_tail(head, speed, dr.pair)
        return tail

    def _fix_tail(self, head: Any, speed: Any, frame_id: str) -> bytes:
        """LocationFix's fields after the timestamp: frame_id (7), heading (10, radians) and
        velocity (11: Vector3 with x 1, y 2, z 3), as :meth:`_location` sets them; protobuf
        leaves out empty strings and zero numbers, not an optional field that is set."""
        head = float(head) if type(head) in _NUMERIC else None
        speed = float(speed) if type(speed) in _NUMERIC else None
        fid = frame_id.encode()
        out = b"\x3a" + _varint(len(fid)) + fid if fid else b""
        if head is not None:
            rad = math.radians(head)
            out += b"\x51" + _pack_double(rad)
            if speed is not None:
                ms = speed * self._speed_scale
                x, y = ms * math.sin(rad), ms * math.cos(rad)
                v = (b"\x09" + _pack_double(x) if x != 0.0 else b"") + (b"\x11" + _pack_double(y) if y != 0.0 else b"")
                out += b"\x5a" + _varint(len(v)) + v
        return out

    def location(self, d: Decoded) -> LocationFix | None:
        """The direction's position after ``d`` (None: no valid latitude and longitude)."""
        typed = {n: _typed(v) for n, v in d.table.vars.items() if v.text is not None}
        return self._location(typed, d.ts_ns, d.pair)

    def _location(self, typed: dict[str, Any], ts_ns: int, frame_id: str) -> LocationFix | None:
        o = self.opts
        # hot path (every frame): a number is an int or a float (not a bool), as a float
        lat, lon = typed.get(o.lat), typed.get(o.lon)
        if type(lat) not in _NUMERIC or type(lon) not in _NUMERIC:
            return None
        lat, lon = float(lat), float(lon)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return None
        head, speed = typed.get(o.heading), typed.get(o.speed)
        head = float(head) if type(head) in _NUMERIC else None
        speed = float(speed) if type(speed) in _NUMERIC else None
        velocity = None
        rad = math.radians(head) if head is not None else None
        if speed is not None and rad is not None:
            ms = speed * self._speed_scale
            velocity = Vector3(x=ms * math.sin(rad), y=ms * math.cos(rad), z=0.0)
        return LocationFix(timestamp=_stamp(ts_ns), frame_id=frame_id, latitude=lat, longitude=lon,
                           position_covariance=_NO_COVARIANCE, position_covariance_type=_UNKNOWN_COVARIANCE,
                           heading=rad, velocity=velocity)

    @property
    def counts(self) -> dict[str, int]:
        """Messages logged per topic."""
        out = dict(self._counts)
        for dr in self._dirs.values():
            out[dr.frames_topic] = dr.nframes
            out[dr.values_topic] = dr.nframes - dr.nmalformed + dr.ngaps
            if dr.location is not None:
                out[dr.location_topic] = dr.nlocations
        return out

    # -- P2OS and blackboard -----------------------------------------------------------------

    def _channel(self, m: SessionMessage, name: str, schema: Any) -> Any:
        key = (m.protocol, m.session)
        s = self._sessions.get(key)
        if s is None:
            s = self._sessions[key] = _Session(f"/{m.protocol}/{m.session}", {"session": m.label})
            self._labels.setdefault((m.protocol, m.label), s)
        ch = s.channels.get(name)
        if ch is None:
            self._open(1)
            topic = f"{s.prefix}/{name}"
            if schema is None:
                ch = PoseInFrameChannel(topic, metadata=s.metadata, context=self.ctx)
            else:
                ch = foxglove.Channel(topic, schema=schema, metadata=s.metadata, context=self.ctx)
            s.channels[name] = ch
            self._counts[topic] = 0
        return ch

    def _log(self, ch: Any, msg: Any, ts: int) -> None:
        ch.log(msg, log_time=ts)
        self._counts[ch.topic()] += 1

    def session(self, m: SessionMessage) -> None:
        """The messages of one P2OS packet or blackboard message."""
        base = {"number": m.number, "side": m.side, "checksum": _checksum(m.ok)}
        if m.protocol == "blackboard":
            self._log(self._channel(m, "messages", BLACKBOARD_SCHEMA), json.dumps({**base, **blackboard_json(m)}).encode(), m.ts_ns)
            return
        msg = m.message
        if isinstance(msg, p2os.Sip):
            self._log(self._channel(m, "pose", None), sip_pose(msg, m.ts_ns), m.ts_ns)
            row = {**base, **sip_json(msg)}
            self._log(self._channel(m, "sip", SIP_SCHEMA), json.dumps(row).encode(), m.ts_ns)
            self._sessions[(m.protocol, m.session)].sip = row
        elif isinstance(msg, p2os.Command):
            self._log(self._channel(m, "commands", COMMAND_SCHEMA), json.dumps({**base, **command_json(msg)}).encode(), m.ts_ns)
        else:
            row = {**base, **server_json(msg)}
            if m.error:
                row["error"] = m.error
            self._log(self._channel(m, "server", SERVER_SCHEMA), json.dumps(row).encode(), m.ts_ns)
