"""Link health of P2OS and blackboard links (issue 43, issue 42 item 3): the robot sessions'
messages (:class:`~sharedlink.analysis.sessions.SessionMessage`) fed into the same
:class:`~sharedlink.analysis.health.Health` as the SharedLink frames, so that ``stats`` (its
table, ``--json``'s ``"links"`` and ``"outages"``) lists their links and outages too.

A robot link is one side of one session: ``link`` is the protocol and the session's label
(``"p2os tcp 127.0.0.1:45678 - 127.0.0.1:8101"``, ``"blackboard serial interface 0"``), ``pair``
the direction by side (``robot>client``, ``client>robot``; ``master>slave``, ``slave>master``).
The definition is SharedLink's (learnt rate, threshold, outages, checksum habit), on the links
that keep a pace: the P2OS robot's (its SIPs, about 10 a second, are P2OS's heartbeat) and both
sides of a blackboard session (the master polls, the slave answers). A P2OS client sends
commands when it has some and a PULSE now and then (about 1.1 s apart in MobileSim's sessions):
no pace to learn an outage from (a burst of commands, then a pulse, read as an outage), so it is
left out.
"""

from __future__ import annotations

from collections import Counter

from sharedlink.analysis.health import MAX_LINKS, Health, LinkHealth
from sharedlink.analysis.sessions import SessionMessage

#: the other side of each side
OTHER_SIDE = {"client": "robot", "robot": "client", "master": "slave", "slave": "master"}


def feed_session(health: Health, m: SessionMessage) -> None:
    """One P2OS packet or blackboard message (its checksum verdict: ``m.ok``); a P2OS client's
    are left out (see the module doc)."""
    if m.side == "client":
        return
    key = (("robot", m.protocol, m.label), m.side, "")
    if key not in health.links and len(health.links) < MAX_LINKS:
        h = health.links[key] = LinkHealth(f"{m.protocol} {m.label}", f"{m.side}>{OTHER_SIDE.get(m.side, '?')}")
        if health.timeline:
            h.seconds = Counter()
    health.frame(health.link(*key), m.ts_ns, m.ok)
