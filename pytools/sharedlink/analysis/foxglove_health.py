"""Link health as Foxglove channels (issue 43): one ``link_quality`` topic per SharedLink link,
beside the direction's ``values`` and ``frames`` (``/sharedlink/B_to_A/link_quality``; a second
conversation carrying the pair: ``B_to_A_2``, as :class:`~sharedlink.analysis.foxglove_channels.FoxgloveChannels`
names it; a paced P2OS or blackboard link's below its session's topics, by its pair:
``/p2os/1/robot_to_client/link_quality``, fed by :mod:`~sharedlink.analysis.robot_health`), one JSON message per second (log time: the second's start, epoch-aligned) with the
Shepherd link quality of :func:`sharedlink.analysis.health.quality`::

    {"frames": 5, "quality": 5, "state": "up", "down_s": null}
    {"frames": 0, "quality": 2.0, "state": "down", "down_s": 2.0}

``frames`` and ``quality`` plot as lines in Foxglove's Plot panel, ``state`` in its State
Transitions panel. ``export --format mcap`` writes them when the capture is done
(:func:`publish_quality`); ``watch --foxglove`` sends each second once it has ended, by the
frame after it or by the clock while the link is silent (:class:`LiveQuality`): the same
messages, but for the last second, never ended.

No line across an outage: plotting tools join a series' samples by straight lines, which would
draw a silence as data. Each outage of a link puts one *gap* message on its direction's
``values`` topic, 1 ns after the outage's start (the last frame before the silence), with every
variable whose value is a number as the text ``"NaN"`` (:data:`GAP_VALUE`; JSON has no NaN):
Foxglove's Plot (the open-source Studio and its fork Lichtblick: getChartValue) reads a string as a
number, ``"NaN"`` as NaN, and leaves its line open there (PlotJuggler not checked),
from the last sample before the silence to the first after it (a P2OS robot's link: on its
session's ``sip`` topic, the numbers of the SIP message before it; :func:`log_sip_gap`). ``export`` writes them after the
pass (:func:`publish_gaps`); ``watch --foxglove`` once a silence becomes an outage by the clock,
or before the frame that ends one the clock did not see (:meth:`LiveQuality.gap`).
"""

from __future__ import annotations

import json
from collections import Counter
from typing import Any

import foxglove

from sharedlink.analysis.health import FLOOR_S, Health, LinkHealth, Second, feed_decoded, quality
from sharedlink.analysis.robot_health import feed_session, is_robot_key, robot_key
from sharedlink.capture.pcapio import NS

LINK_QUALITY_SCHEMA = {
    "type": "object",
    "title": "sharedlink.LinkQuality",
    "properties": {
        "frames": {"type": "integer", "minimum": 0},
        "quality": {"type": "number", "minimum": 0},
        "state": {"type": "string", "enum": ["up", "down"]},
        "down_s": {"type": ["number", "null"]},
    },
    "required": ["frames", "quality", "state", "down_s"],
}


def second_json(s: Second) -> bytes:
    return json.dumps({"frames": s.frames, "quality": s.quality, "state": s.state, "down_s": s.down_s}).encode()


def _pair_topic(pair: str) -> str:
    """``B>A`` -> ``B_to_A``, ``robot>client`` -> ``robot_to_client`` (the links past the limit: ``other``)."""
    return pair.replace(">", "_to_").replace("*", "other")


def _session(channels: Any, protocol: str, label: str) -> Any:
    """The channels of the robot session ``label`` (None: refused, past the channels' limit)."""
    return channels._labels.get((protocol, label))


def _session_prefix(channels: Any, protocol: str, label: str) -> str:
    """The topics' prefix of the robot session ``label`` (``/p2os/1``), as its channels have it."""
    s = _session(channels, protocol, label)
    return s.prefix if s is not None else f"/{protocol}/other"


def link_topic(channels: Any, key: tuple, h: LinkHealth) -> str:
    """The link's topic: below its direction's channels when it has them, else by its pair; a
    robot link's (:func:`~sharedlink.analysis.robot_health.robot_key`): below its session's
    channels, by its pair (``/p2os/1/robot_to_client/link_quality``)."""
    dr = channels._dirs.get(key)  # (conv, src, dst): the directions' key, the links' too
    if dr is not None:
        return dr.frames_topic.rsplit("/", 1)[0] + "/link_quality"
    conv = key[0]
    if is_robot_key(key):
        return f"{_session_prefix(channels, conv[1], conv[2])}/{_pair_topic(h.pair)}/link_quality"
    return "/sharedlink/" + _pair_topic(h.pair) + "/link_quality"


def quality_channel(channels: Any, key: tuple, h: LinkHealth) -> Any:
    """A new ``link_quality`` channel of ``channels``' context, counted with its channels."""
    channels._open(1)
    conv, src, dst = key
    topic = link_topic(channels, key, h)
    if is_robot_key(key):  # (src, dst: the sides; the session's label as its channels have it)
        src, _, dst = h.pair.partition(">")
        meta = {"src": src, "dst": dst, "link": h.link, "session": conv[2]}
    else:
        meta = {"src": src, "dst": dst, "link": h.link, "conversation": " ".join(map(str, conv or ()))}
    ch = foxglove.Channel(topic, schema=LINK_QUALITY_SCHEMA, metadata=meta, context=channels.ctx)
    channels._counts[topic] = 0
    return ch


def publish_quality(channels: Any, health: Health) -> None:
    """Every link's per-second quality (``health`` kept a timeline), onto ``channels``' context."""
    health.finish_once()
    for key, h in sorted(health.links.items(), key=lambda kv: (kv[1].link, kv[1].pair)):
        ch = quality_channel(channels, key, h)
        topic = ch.topic()
        for s in quality(h):
            ch.log(second_json(s), log_time=s.second * NS)
            channels._counts[topic] += 1


#: a numeric variable's value in a gap message
GAP_VALUE = "NaN"
_NUMBER = (int, float)


def gap_json(typed: dict[str, Any]) -> bytes | None:
    """The gap message of a direction whose last typed values are ``typed`` (None: no number)."""
    names = [n for n, v in typed.items() if type(v) in _NUMBER]
    return json.dumps(dict.fromkeys(names, GAP_VALUE)).encode() if names else None


def log_gap(channels: Any, key: tuple, start_ns: int) -> bool:
    """A gap message on the values topic of direction ``key`` for an outage from ``start_ns``
    (a P2OS robot's link: on its session's ``sip`` topic, :func:`log_sip_gap`)."""
    if is_robot_key(key):
        return log_sip_gap(channels, key, start_ns)
    dr = channels._dirs.get(key)
    body = gap_json(dr.typed) if dr is not None else None
    if body is None:
        return False
    dr.log_values(body, start_ns + 1)
    dr.ngaps += 1
    return True


def log_sip_gap(channels: Any, key: tuple, start_ns: int) -> bool:
    """A P2OS robot link's outage: a gap message on its session's ``sip`` topic, every number of
    the last SIP message (position, velocities, battery, ...) as ``"NaN"``, so its plotted lines break
    there too. Blackboard links get none: their one ``messages`` topic mixes the master's
    messages and the slave's answers (no series to break)."""
    conv, side, _ = key
    s = _session(channels, conv[1], conv[2])
    ch = s.channels.get("sip") if s is not None and side == "robot" else None
    body = gap_json(s.sip) if ch is not None else None
    if body is None:
        return False
    ch.log(body, log_time=start_ns + 1)
    channels._counts[ch.topic()] += 1
    return True


def publish_gaps(channels: Any, health: Health) -> None:
    """A gap message for every outage of every link (``health`` finished: the open ones too)."""
    health.finish_once()
    for key, h in health.links.items():
        for o in h.outages:
            log_gap(channels, key, o.start_ns)


#: the key of Health's link past its limit (Health.link)
OTHER_KEY = ("", "", "*")
#: seconds sent at most at once for one link (a clock that jumps: the latest are sent)
LIVE_BACKLOG_S = 3600


class LiveQuality:
    """``watch --foxglove``'s link quality: :meth:`frame` after the channels' own frame (so the
    direction's topic is known), :meth:`tick` with the clock (capture time for ``--from``). A
    second is sent once it has ended: its frames, or (none) down when the silence at its end is
    an outage by the link's threshold then (the rule of :func:`~sharedlink.analysis.health.quality`)."""

    def __init__(self, channels: Any) -> None:
        self.channels = channels
        self.health = Health()
        self.low_ns = int(FLOOR_S * NS)
        #: id(link) -> [channel, the next second to send, frames per second not sent yet]
        self.links: dict[int, list] = {}
        #: id(link) -> the start (ns) of the last outage whose gap message was sent
        self.gapped: dict[int, int] = {}

    def _silent(self, h: LinkHealth, now_ns: int) -> bool:
        """Whether the link's silence up to ``now_ns`` is an outage by its threshold then."""
        if h.last_ns is None:
            return False
        gap = now_ns - h.last_ns
        limit = h.threshold_ns(None)
        return gap > self.low_ns and limit is not None and gap > limit

    def _gap(self, h: LinkHealth, key: tuple) -> None:
        """The gap message of the link's current silence, once (its start: the link's last frame)."""
        if self.gapped.get(id(h)) != h.last_ns and log_gap(self.channels, key, h.last_ns):  # type: ignore[arg-type]
            self.gapped[id(h)] = h.last_ns  # type: ignore[assignment]

    def gap(self, d: Any) -> None:
        """Before the channels' own frame: a frame that ends an outage the clock did not see
        (a silence shorter than the ticks, a capture sent fast) sends its gap message first."""
        h = self.health.links.get((d.conv, d.src, d.dst))
        if h is not None and self._silent(h, d.ts_ns):
            self._gap(h, (d.conv, d.src, d.dst))

    def _state(self, h: LinkHealth, key: tuple, ts_ns: int) -> list:
        """The link's [channel, next second, counts]; the seconds a frame at ``ts_ns`` ends sent
        (judged before it counts)."""
        st = self.links.get(id(h))
        if st is None:
            st = self.links[id(h)] = [quality_channel(self.channels, key, h), ts_ns // NS, Counter()]
        else:
            self._send(h, st, ts_ns // NS)
        return st

    @staticmethod
    def _count(st: list, ts_ns: int) -> None:
        sec = ts_ns // NS
        if sec >= st[1]:
            st[2][sec] += 1

    def frame(self, d: Any) -> None:
        key = (d.conv, d.src, d.dst)
        st = self._state(self.health.link(*key), key, d.ts_ns)
        feed_decoded(self.health, d)
        self._count(st, d.ts_ns)

    def session_gap(self, m: Any) -> None:
        """Before the channels' own message: a robot packet that ends an outage the clock did not
        see sends the link's gap message first (:meth:`gap`'s rule)."""
        key = robot_key(m)
        h = self.health.links.get(key)
        if h is not None and self._silent(h, m.ts_ns):
            self._gap(h, key)

    def session(self, m: Any) -> None:
        """A P2OS packet or blackboard message (after the channels' own, so its session's topics
        are known): the paced robot links' quality (robot_health.py's links; a P2OS client's: none)."""
        key = robot_key(m)
        h = self.health.links.get(key)
        st = self._state(h, key, m.ts_ns) if h is not None else None
        h = feed_session(self.health, m)
        if h is None:
            return
        if st is None:  # (its first message, or a link past the limit: Health's other links)
            st = self._state(h, key if self.health.links.get(key) is h else OTHER_KEY, m.ts_ns)
        self._count(st, m.ts_ns)

    def tick(self, now_ns: int) -> None:
        for key, h in list(self.health.links.items()):
            st = self.links.get(id(h))
            if st is not None:
                self._send(h, st, now_ns // NS)
                if self._silent(h, now_ns):
                    self._gap(h, key)

    def _send(self, h: LinkHealth, st: list, until: int) -> None:
        """Send the link's seconds before ``until``."""
        ch, sec, counts = st
        if until <= sec:
            return
        sec = max(sec, until - LIVE_BACKLOG_S)
        topic = ch.topic()
        for s in range(sec, until):
            frames = counts.pop(s, 0)
            at = (s + 1) * NS
            down = None
            gap = at - h.last_ns if h.last_ns is not None else 0
            limit = h.threshold_ns(None)
            if not frames and gap > self.low_ns and limit is not None and gap > limit:
                down = round(gap / NS, 3)
            ch.log(second_json(Second(h.link, h.pair, s, frames, down)), log_time=s * NS)
            self.channels._counts[topic] += 1
        for s in [k for k in counts if k < until]:
            del counts[s]
        st[1] = until
