"""``export --format mcap``: a capture as an MCAP file for Foxglove and PlotJuggler.

One streaming pass of the decoding core (:class:`sharedlink.analysis.decode.Decoder`, in its
columns mode: the frames its fast path takes come as rows, no per-frame object) publishes every
SharedLink frame on the channels of :class:`~sharedlink.analysis.foxglove_channels.FoxgloveChannels`, which
foxglove-sdk's MCAP writer (zstd chunks at level 1, indexed) records with log time = capture time (ns).
The P2OS and blackboard sessions come in the same pass, from the core's robot links
(:class:`sharedlink.analysis.robots.RobotLinks`, as ``stats`` and ``export jsonl`` read them).
Every link's per-second link quality (:mod:`sharedlink.analysis.foxglove_health`; the SharedLink
links' and the paced P2OS and blackboard links' of :mod:`sharedlink.analysis.robot_health`) and
the gap messages that break the SharedLink values' lines at each outage are written at the end.
"""

from __future__ import annotations

from pathlib import Path

import foxglove
from foxglove.mcap import MCAPWriteOptions

from sharedlink.analysis.decode import Columns, Decoded, Decoder
from sharedlink.analysis.export import ExportOptions, ExportResult
from sharedlink.analysis.foxglove_channels import ChannelOptions, FoxgloveChannels
from sharedlink.analysis.foxglove_health import publish_gaps, publish_quality
from sharedlink.analysis.health import Health, feed_columns, feed_decoded
from sharedlink.analysis.robot_health import feed_session
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import SessionMessage
from sharedlink.capture.pcapio import CaptureError, atomic_open
from sharedlink.errors import UsageError

PROFILE = "sharedlink"
#: zstd's level for the chunks: 1 (fastest) against the writer's default 3 costs about 2 % in file
#: size (23.7 MB against 23.2 MB on the bench's 200,000 compressed frames) and saves about 0.2 s
#: CPU of its 2.2 s (most of the writer's compression time)
ZSTD_LEVEL = 1
#: an MCAP channel id is a uint16 (and foxglove-sdk's writer does not use id 0)
MCAP_MAX_CHANNELS = 65535


def channel_options(opts: ExportOptions) -> ChannelOptions:
    return ChannelOptions(lat=opts.lat, lon=opts.lon, heading=opts.heading, speed=opts.velocity,
                          max_channels=MCAP_MAX_CHANNELS)


def publish_capture(path: str | Path, channels: FoxgloveChannels, opts: ExportOptions, result: ExportResult,
                    health: Health | None = None) -> None:
    """Every frame and session message of ``path`` onto ``channels`` (and its links' frames
    into ``health``); damage after the first record sets ``result.error`` (what came before it
    is published)."""
    seen = result.seen if opts.require else None
    try:
        dec = Decoder(opts.variables, opts.sync_interval, carried=False)
        dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
        for item in dec.capture(path, opts.progress, columns=True):
            t = type(item)
            if t is Columns:  # (the frames the core's fast path took: rows, no Decoded)
                result.frames += item.frames  # type: ignore[union-attr]
                channels.columns(item)  # type: ignore[arg-type]
                if health is not None:
                    feed_columns(health, item)
                if seen is not None:
                    for c in item.dirs.values():  # type: ignore[union-attr]
                        seen.update(c.name)
            elif t is Decoded:
                result.frames += 1
                channels.frame(item)  # type: ignore[arg-type]
                if health is not None:
                    feed_decoded(health, item)
                if seen is not None:
                    seen.update(u.name for u in item.updates if u.text is not None)  # type: ignore[union-attr]
            elif t is SessionMessage:  # P2OS, blackboard (the core's robot links)
                result.frames += 1
                channels.session(item)  # type: ignore[arg-type]
                if health is not None:  # (their paced links' health: robot_health.py)
                    feed_session(health, item)  # type: ignore[arg-type]
    except CaptureError as exc:
        if exc.record is None and result.frames == 0:
            raise
        result.error = str(exc)


def export_mcap(path: str | Path, dest: str | Path, opts: ExportOptions) -> ExportResult:
    """Write ``path`` as an MCAP file at ``dest`` (written beside it, renamed into place when
    complete). ``rows`` is the number of messages written; ``columns`` the topics."""
    result = ExportResult()
    ctx = foxglove.Context()
    channels = FoxgloveChannels(ctx, channel_options(opts))
    with atomic_open(dest, "wb") as fh:
        writer = foxglove.open_mcap(fh, context=ctx, writer_options=MCAPWriteOptions(profile=PROFILE, compression_level=ZSTD_LEVEL))
        try:
            health = Health(timeline=True)
            publish_capture(path, channels, opts, result, health)
            publish_quality(channels, health)  # (one link_quality topic per link: foxglove_health.py)
            publish_gaps(channels, health)  # (the values' lines broken at each outage)
            missing = [n for n in opts.require if n not in result.seen]
            if missing and result.error is None:  # the file is not left behind (atomic_open)
                have = ", ".join(sorted(result.seen)) or "none"
                raise UsageError(f"no variable {', '.join(missing)} in {path} (its variables: {have})")
        finally:
            writer.close()
    result.rows = sum(channels.counts.values())
    result.columns = sorted(channels.counts)
    return result
