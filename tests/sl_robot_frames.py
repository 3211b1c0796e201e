"""P2OS and blackboard messages frame by frame as each decoder gives them, for the tests that
compare the two (test_robot_frames_agree.py, the robot vectors): tshark with p2os.lua,
blackboard.lua and serial.lua (two passes), the Python session reader (``iter_sessions``) and
the decoding core's robot links (``Decoder.capture`` with ``RobotLinks(messages=True)``, what
``stats``, ``export``, ``ingest`` read). Each gives ``{frame number: [message, ...]}`` with a
message ``(protocol, kind, checksum verdict)``: P2OS ``("p2os", "client" | "robot", ok)``,
blackboard ``("blackboard", "set" | "request" | "ack" | "response", ok)``, a malformed blackboard
message's kind with ``" malformed"`` after it; ok None where there is no verdict; the frames with
none left out."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

from sl_robots import OTHERS, SERIAL

import tshark_util as tu
from sharedlink.analysis.decode import Decoder
from sharedlink.analysis.robots import RobotLinks
from sharedlink.analysis.sessions import Ack, SessionMessage, iter_sessions

Frames = dict[int, list[tuple[str, str, bool | None]]]

#: p2os.direction -> the Python reader's side
P2OS_SIDES = {"0": "client", "1": "robot"}
#: a read response blackboard.lua shows cut off at a datagram's end: noise to the Python reader
#: (docs/fields-p2os-blackboard.md, "Over UDP"), left out of both
TRUNCATED = "blackboard.response.truncated"
#: blackboard.lua's experts of a malformed message (docs/fields-p2os-blackboard.md, "Malformed messages")
MALFORMED = {"blackboard.non_hex", "blackboard.odd_digits", "blackboard.too_short", "blackboard.count.wrong",
             "blackboard.no_cr"}
STATUS = {"1": True, "0": False}


def _experts(tree: dict) -> set[str]:
    return {k for e in tu.walk(tree, "_ws.expert") if isinstance(e, dict) for k in e if not k.startswith("_ws.")}


def _lua_message(proto: str, t: dict) -> tuple[str, str, bool | None] | None:
    status = next((STATUS.get(v) for v in tu.as_list(t.get(f"{proto}.checksum.status"))), None)
    if proto == "p2os":
        if "p2os.direction" not in t:
            return None  # (bytes outside any packet; a header whose count is below 2: noise to Python)
        return "p2os", P2OS_SIDES[t["p2os.direction"]], status
    experts = _experts(t)
    if TRUNCATED in experts:
        return None
    kind = t.get("blackboard.type")
    if kind is None:
        return None
    return "blackboard", kind + (" malformed" if experts & MALFORMED else ""), status


def lua_frames(path: Path, prefs: dict | None = None) -> Frames:
    """tshark's messages a frame (serial.lua's USER0 preference on a pcapng file)."""
    if prefs is None and path.suffix == ".pcapng":
        prefs = SERIAL
    out: Frames = {}
    for n, p in enumerate(tu.json_packets(path, prefs=prefs, two_pass=True, extra=OTHERS), 1):
        layers = p["_source"]["layers"]
        msgs = [m for proto in ("p2os", "blackboard") for t in tu.as_list(layers.get(proto)) if isinstance(t, dict)
                for m in [_lua_message(proto, t)] if m is not None]
        if msgs:
            out[n] = msgs
    return out


def message_kind(m: SessionMessage) -> tuple[str, str, bool | None]:
    """A Python message as :func:`lua_frames` names it."""
    if m.protocol == "p2os":
        return "p2os", m.side, m.ok
    if m.side == "slave":
        return "blackboard", "ack" if isinstance(m.message, Ack) else "response", m.ok
    kind = "set" if m.raw[:1] == b":" else "request"
    return "blackboard", kind if m.message is not None else f"{kind} malformed", m.ok


def _by_frame(msgs: list[SessionMessage]) -> Frames:
    out: Frames = defaultdict(list)
    for m in msgs:
        out[m.number].append(message_kind(m))
    return dict(out)


def python_frames(path: Path) -> Frames:
    """The Python session reader's messages a frame."""
    return _by_frame(list(iter_sessions(path)))


def core_frames(path: Path) -> Frames:
    """The decoding core's robot links' messages a frame."""
    dec = Decoder(carried=False)
    dec.robots = RobotLinks(messages=True)  # type: ignore[attr-defined]
    return _by_frame([x for x in dec.capture(path) if isinstance(x, SessionMessage)])


def differences(a: Frames, b: Frames) -> dict[int, tuple[list, list]]:
    """The frames whose messages differ: number -> (a's, b's)."""
    return {n: (a.get(n, []), b.get(n, [])) for n in sorted(set(a) | set(b)) if a.get(n, []) != b.get(n, [])}
