"""Link health of P2OS and blackboard links (issue 43, issue 42 item 3): the robot sessions'
messages (:class:`~sharedlink.analysis.sessions.SessionMessage`) fed into the same
:class:`~sharedlink.analysis.health.Health` as the SharedLink frames, so that ``stats`` (its
table, ``--json``'s ``"links"`` and ``"outages"``) lists their links and outages too.

A robot link is one side of one session: ``link`` is the protocol and the session's label
(``"p2os tcp 127.0.0.1:45678 - 127.0.0.1:8101"``, ``"blackboard serial interface 0"``), ``pair``
the direction by side (``robot>client``, ``client>robot``; ``master>slave``, ``slave>master``).
Every link-health output takes robot links through this module (the one definition: :mod:`health`'s
functions, fed here): ``stats`` (:func:`feed_session`), ``health`` (its table, rows and strip),
``export --outages`` (:func:`session_outages`), ``ingest``'s ``links`` and ``outages`` tables,
``watch``'s robot panel (:func:`robot_link`, LINK DOWN) and the ``link_quality`` topics of
``export --format mcap`` and ``watch --foxglove`` (:mod:`~sharedlink.analysis.foxglove_health`); the Wireshark tap's twin is
``dissector/sharedlink/health.lua``'s ``H.robot``, fed by p2os.lua and blackboard.lua.

The definition is SharedLink's (learnt rate, threshold, outages, checksum habit), on the links
that keep a pace: the P2OS robot's (its SIPs, about 10 a second, are P2OS's heartbeat) and both
sides of a blackboard session (the master polls, the slave answers). A P2OS client sends
commands when it has some and a PULSE now and then (about 1.1 s apart in MobileSim's sessions):
no pace to learn an outage from (a burst of commands, then a pulse, read as an outage), so it is
left out.
"""

from __future__ import annotations

from sharedlink.analysis.health import MAX_LINKS, Health, LinkHealth, Outage, OutageFeed, SecondCounts
from sharedlink.analysis.sessions import SessionMessage

#: the other side of each side
OTHER_SIDE = {"client": "robot", "robot": "client", "master": "slave", "slave": "master"}


def robot_key(m: SessionMessage) -> tuple:
    """The :class:`Health` key of a robot message's link (whichever side)."""
    return ("robot", m.protocol, m.label), m.side, ""


def is_robot_key(key: tuple) -> bool:
    """Whether a :class:`Health` key is a robot link's (:func:`robot_key`)."""
    conv = key[0]
    return type(conv) is tuple and len(conv) == 3 and conv[0] == "robot"


def robot_link(health: Health, m: SessionMessage) -> LinkHealth | None:
    """The link of ``m`` 's side in ``health`` (None: not fed yet, or a P2OS client's)."""
    return health.links.get(robot_key(m))


def feed_session(health: Health, m: SessionMessage) -> LinkHealth | None:
    """One P2OS packet or blackboard message (its checksum verdict: ``m.ok``); a P2OS client's
    are left out (see the module doc). The link it moved, or None."""
    if m.side == "client":
        return None
    key = robot_key(m)
    if key not in health.links and len(health.links) < MAX_LINKS:
        h = health.links[key] = LinkHealth(f"{m.protocol} {m.label}", f"{m.side}>{OTHER_SIDE.get(m.side, '?')}")
        if health.timeline:
            h.seconds = SecondCounts()
    h = health.link(*key)
    if m.ok is None and m.message is None:  # a malformed message: alive, nothing of the habit
        had, h.had_checksum = h.had_checksum, False
        health.frame(h, m.ts_ns, None)
        h.had_checksum = had
        return h
    health.frame(h, m.ts_ns, m.ok)
    return h


def session_outages(feed: OutageFeed, m: SessionMessage) -> list[Outage]:
    """``export --outages``: the outages robot message ``m`` ends (:class:`OutageFeed` 's, beside
    the SharedLink frames it is fed)."""
    h = robot_link(feed.health, m)
    n = len(h.outages) if h is not None else 0
    h = feed_session(feed.health, m)
    return h.outages[n:] if h is not None and len(h.outages) > n else []
