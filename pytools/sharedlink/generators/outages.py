"""Planted outages (``gen --outage T:D``, issue 43): silences of D seconds from T seconds after
the session's start (``--start``: the beacon's first frame) in one direction of a generated session, for tests and demos of link health.

The direction silenced: the beacon's (its only one) on UDP; on a serial link the vehicle's
(vehicle to host: its data frames and its replies), as a radio fading out loses what the vehicle
sends first. A frame whose nominal time ``t`` (seconds from the start, before jitter)
falls in ``T <= t < T + D`` is not sent.

A P2OS or blackboard session (``--protocol p2os|blackboard``, :func:`cut_line`): the line is cut,
both directions: no packet or message sent in ``T <= t < T + D`` (from the session's first packet's
time, its start) is in the capture, and a blackboard answer goes with the message it answers.
"""

from __future__ import annotations

from collections.abc import Sequence

from sharedlink.capture.pcapio import NS

#: (start s, duration s) of each planted silence
Outages = Sequence[tuple[float, float]]


def parse_outage(text: str) -> tuple[float, float]:
    """``"T:D"`` -> (T, D); ValueError (with the reason) for anything else."""
    t, sep, d = text.partition(":")
    try:
        start, duration = float(t), float(d)
    except ValueError:
        raise ValueError(f"--outage {text!r}: give START:DURATION in seconds, e.g. 20:3") from None
    if not sep or start != start or duration != duration or abs(start) == float("inf") or abs(duration) == float("inf"):
        raise ValueError(f"--outage {text!r}: give START:DURATION in seconds, e.g. 20:3")
    if start < 0:
        raise ValueError(f"--outage {text!r}: the start must not be negative")
    if duration <= 0:
        raise ValueError(f"--outage {text!r}: the duration must be more than 0 s")
    return start, duration


def check_outages(outages: Outages, length_s: float) -> None:
    """Each planted silence ends within the session (``length_s`` seconds from its start)."""
    for start, duration in outages:
        if start + duration > length_s:
            raise ValueError(f"--outage {start:g}:{duration:g} ends at {start + duration:g} s, past the end of the "
                             f"session ({length_s:g} s)")


def windows(outages: Outages, t0_ns: int) -> list[tuple[int, int]]:
    """The silences as [start, end) in epoch ns, sorted."""
    return sorted((t0_ns + round(s * NS), t0_ns + round((s + d) * NS)) for s, d in outages)


def silenced(ts_ns: int, wins: list[tuple[int, int]]) -> bool:
    for a, b in wins:
        if a <= ts_ns < b:
            return True
    return False


def cut_line(events: Sequence[tuple], outages: Outages, t0_ns: int, answers: bool = False) -> tuple[list, int]:
    """A P2OS or blackboard session's events (time ns first, whether the client's or master's
    second) without those in the planted silences, and how many were left out. ``answers``
    (blackboard): an event of the other side (a slave's answer) is left out with the message
    before it."""
    wins = windows(outages, t0_ns)
    if not wins:
        return list(events), 0
    out = []
    dropped = False
    for e in events:
        if e[1] or not answers:
            dropped = silenced(e[0], wins)
        if not dropped:
            out.append(e)
    return out, len(events) - len(out)
