"""The contents of the P2OS and blackboard messages on the Foxglove channels
(:meth:`~sharedlink.analysis.foxglove_channels.FoxgloveChannels.session`): a SIP's pose as a
``foxglove.PoseInFrame``, and the JSON of SIPs, client commands, the robot's other packets and
blackboard messages."""

from __future__ import annotations

import math
from typing import Any

from foxglove.messages import Pose, PoseInFrame, Quaternion, Timestamp, Vector3

from sharedlink.analysis.sessions import Ack, SessionMessage
from sharedlink.capture.pcapio import NS
from sharedlink.protocols import blackboard, p2os


def _text(b: bytes) -> str:
    return b.decode("latin-1")


def sip_pose(s: p2os.Sip, ts_ns: int) -> PoseInFrame:
    """A SIP's position (mm -> m) and heading (rotation about z) in frame ``odom``."""
    half = math.radians(s.heading_deg) / 2
    return PoseInFrame(
        timestamp=Timestamp(ts_ns // NS, ts_ns % NS),
        frame_id="odom",
        pose=Pose(position=Vector3(x=s.xpos / 1000.0, y=s.ypos / 1000.0, z=0.0),
                  orientation=Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))),
    )


def sip_json(s: p2os.Sip) -> dict[str, Any]:
    return {
        "moving": s.moving, "x_mm": s.xpos, "y_mm": s.ypos, "heading_deg": s.heading_deg, "lvel_mm_s": s.lvel,
        "rvel_mm_s": s.rvel, "battery_v": s.volts, "stall_bumpers": s.stall_bumpers, "control": s.control,
        "flags": s.flags, "compass": s.compass, "sonars": [{"number": n, "range_mm": r} for n, r in s.sonars],
        "grip_state": s.grip_state, "anport": s.anport, "analog": s.analog, "digin": s.digin, "digout": s.digout,
    }


def command_json(c: p2os.Command) -> dict[str, Any]:
    value: Any = _text(c.value) if isinstance(c.value, bytes) else c.value
    return {"command": c.number, "name": c.name, "argtype": p2os.ARG_TYPES.get(c.argtype or -1), "value": value}


def server_json(msg: Any) -> dict[str, Any]:
    if isinstance(msg, p2os.SyncReply):
        return {"type": "sync", "sync": msg.number, "strings": [_text(s) for s in msg.strings]}
    if isinstance(msg, p2os.Encoder):
        return {"type": "encoder", "left": msg.left, "right": msg.right}
    if isinstance(msg, p2os.Config):
        return {"type": "config", **{k: (_text(v) if isinstance(v, bytes) else v) for k, v in msg.values}}
    if isinstance(msg, p2os.Raw):
        return {"type": "raw", "type_byte": msg.type, "data": msg.data.hex()}
    return {"type": "undecoded"}


def blackboard_json(m: SessionMessage) -> dict[str, Any]:
    msg = m.message
    if isinstance(msg, blackboard.SetMessage):
        return {"type": "set", "address": msg.address, "node": msg.node, "data": msg.data.hex()}
    if isinstance(msg, blackboard.RequestMessage):
        return {"type": "request", "address": msg.address, "node": msg.node, "count": msg.count}
    req = m.request
    addr = req.address if req is not None else None
    if isinstance(msg, Ack):
        return {"type": "ack", "address": addr, "crc": msg.crc}
    if isinstance(msg, blackboard.ReadResponse):
        return {"type": "response", "address": addr, "data": msg.data.hex()}
    if msg is None:  # a malformed message (docs/fields-p2os-blackboard.md, "Malformed messages")
        return {"type": "malformed", "error": m.error, "data": m.raw.hex()}
    return {"type": "undecoded", "data": m.raw.hex()}
