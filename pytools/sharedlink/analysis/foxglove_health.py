"""Link health as Foxglove channels (issue 43): one ``link_quality`` topic per SharedLink link,
beside the direction's ``values`` and ``frames`` (``/sharedlink/B_to_A/link_quality``; a second
conversation carrying the pair: ``B_to_A_2``, as :class:`~sharedlink.analysis.foxglove_channels.FoxgloveChannels`
names it), one JSON message per second (log time: the second's start, epoch-aligned) with the
Shepherd link quality of :func:`sharedlink.analysis.health.quality`::

    {"frames": 5, "quality": 5, "state": "up", "down_s": null}
    {"frames": 0, "quality": 2.0, "state": "down", "down_s": 2.0}

``frames`` and ``quality`` plot as lines in Foxglove's Plot panel, ``state`` in its State
Transitions panel. ``export --format mcap`` writes them when the capture is done
(:func:`publish_quality`).
"""

from __future__ import annotations

import json
from typing import Any

import foxglove

from sharedlink.analysis.health import Health, LinkHealth, Second, quality
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
    return json.dumps({"frames": s.frames, "quality": s.quality, "state": "up" if s.down_s is None else "down",
                       "down_s": s.down_s}).encode()


def link_topic(channels: Any, key: tuple, h: LinkHealth) -> str:
    """The link's topic: below its direction's channels when it has them, else by its pair."""
    dr = channels._dirs.get(key)  # (conv, src, dst): the directions' key, the links' too
    if dr is not None:
        return dr.frames_topic.rsplit("/", 1)[0] + "/link_quality"
    return "/sharedlink/" + h.pair.replace(">", "_to_").replace("*", "other") + "/link_quality"


def quality_channel(channels: Any, key: tuple, h: LinkHealth) -> Any:
    """A new ``link_quality`` channel of ``channels``' context, counted with its channels."""
    channels._open(1)
    conv, src, dst = key
    topic = link_topic(channels, key, h)
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
