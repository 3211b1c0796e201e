"""P2OS (Pioneer robot) packet codec: packets, client commands and server information packets.

A packet on the wire (serial, or TCP to the MobileSim simulator on port 8101)::

    FA FB  count  payload ...  checksum(2, high byte first)

``count`` is the number of bytes after it, checksum included (so ``len(payload) + 2``). The
checksum adds the payload as big-endian 16-bit pairs (16 bits kept) and XORs an odd last byte
into the low byte. Integers in the payload are little-endian: 2 bytes (int) or 4 (word).

Client command payload: the command number, then optionally an argument, ``0x3B`` + u16
(positive int), ``0x1B`` + u16 (negative int, magnitude) or ``0x2B`` + length + bytes (string).
Server information packets start with a type byte: 0x32 / 0x33 standard SIP (motors stopped /
moving), 0x20 CONFIG, 0x90 ENCODER, and 0x00..0x02 the SYNC echoes of the connection handshake.

Parsing never raises anything but :class:`P2osError` (carrying the byte offset and the reason),
whatever the input. Unit conventions (ours where the manual is silent, ARIA's defaults):
positions in mm, velocities in mm/s, heading in 4096ths of a turn, battery in 0.1 V, sonar
ranges in mm, compass in 2-degree units.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Union

from sharedlink.errors import DecodeError

HEADER = b"\xfa\xfb"
#: P2OS ignores a client command packet whose count exceeds this (server packets run to 255)
MAX_COUNT = 200
#: the simulator's TCP port
MOBILESIM_PORT = 8101

ARG_POSITIVE = 0x3B
ARG_NEGATIVE = 0x1B
ARG_STRING = 0x2B
ARG_TYPES = {ARG_POSITIVE: "positive int", ARG_NEGATIVE: "negative int", ARG_STRING: "string"}

#: client command numbers (ARIA's ArCommands.h); 0..2 double as SYNC0..SYNC2 before OPEN
COMMANDS: dict[int, str] = {
    0: "PULSE",
    1: "OPEN",
    2: "CLOSE",
    3: "POLLING",
    4: "ENABLE",
    5: "SETA",
    6: "SETV",
    7: "SETO",
    8: "MOVE",
    9: "ROTATE",
    10: "SETRV",
    11: "VEL",
    12: "HEAD",
    13: "DHEAD",
    15: "SAY",
    17: "JOYREQUEST",
    18: "CONFIG",
    19: "ENCODER",
    20: "SETRVDIR",
    21: "RVEL",
    22: "DCHEAD",
    23: "SETRA",
    28: "SONAR",
    29: "STOP",
    30: "DIGOUT",
    32: "VEL2",
    33: "GRIPPER",
    35: "ADSEL",
    36: "GRIPPERVAL",
    37: "GRIPREQUEST",
    40: "IOREQUEST",
    41: "PTUPOS",
    42: "TTY2",
    43: "GETAUX",
    44: "BUMPSTALL",
    45: "TCM2",
    47: "JOYDRIVE",
    48: "SONARCYCLE",
    50: "HOSTBAUD",
    51: "AUX1BAUD",
    52: "AUX2BAUD",
    53: "AUX3BAUD",
    55: "E_STOP",
    56: "M_STALL",
    58: "GYROREQUEST",
    59: "LCDWRITE",
    60: "TTY4",
    61: "GETAUX3",
}
COMMAND_NUMBERS = {name: num for num, name in COMMANDS.items()}

TYPE_SYNC0, TYPE_SYNC1, TYPE_SYNC2 = 0x00, 0x01, 0x02
TYPE_CONFIG = 0x20
TYPE_SIP_STOPPED = 0x32
TYPE_SIP_MOVING = 0x33
TYPE_ENCODER = 0x90
SERVER_TYPES: dict[int, str] = {
    TYPE_SYNC0: "SYNC0 echo",
    TYPE_SYNC1: "SYNC1 echo",
    TYPE_SYNC2: "SYNC2 echo",
    TYPE_CONFIG: "CONFIG",
    TYPE_SIP_STOPPED: "standard SIP (stopped)",
    TYPE_SIP_MOVING: "standard SIP (moving)",
    0x80: "VISION",
    TYPE_ENCODER: "ENCODER",
    0x8D: "JOYSTICK",
    0xE0: "GRIPPER",
    0xF0: "IO",
}

#: heading unit: 4096ths of a full turn (ARIA's AngleConvFactor 0.001534 rad)
DEGREES_PER_ANGLE_UNIT = 360.0 / 4096.0


class P2osError(DecodeError):
    """Bytes that are not a P2OS packet (or payload). ``offset`` is relative to the input."""


def checksum(payload: bytes) -> int:
    """The P2OS checksum of ``payload`` (the bytes between count and checksum)."""
    n = len(payload)
    even = n & ~1
    c = 0
    if even:
        # sum of big-endian 16-bit words mod 2**16 (the C loop keeps 16 bits at each step)
        c = sum(struct.unpack(">%dH" % (even // 2), payload[:even])) & 0xFFFF
    if n & 1:
        c ^= payload[-1]
    return c


def build_packet(payload: bytes) -> bytes:
    """Header, count, payload and checksum. A payload longer than 253 bytes cannot be framed."""
    if len(payload) > 253:
        raise P2osError(0, f"payload of {len(payload)} bytes does not fit a one-byte count")
    return HEADER + bytes((len(payload) + 2,)) + payload + checksum(payload).to_bytes(2, "big")


@dataclass(slots=True)  # (not frozen: a frozen dataclass's __init__ is 3-5x slower, and one is made a packet)
class Packet:
    """One framed packet. Equality compares the payload only."""

    payload: bytes
    written: int | None = field(default=None, compare=False)  # the checksum as sent
    calculated: int | None = field(default=None, compare=False)

    @property
    def ok(self) -> bool | None:
        """True good checksum, False bad, None not parsed from the wire."""
        if self.written is None:
            return None
        return self.written == self.calculated

    @property
    def count(self) -> int:
        return len(self.payload) + 2

    @property
    def too_long(self) -> bool:
        """A count over 200 (over the robot's limit if it is a client command: see :meth:`ignored`)."""
        return self.count > MAX_COUNT

    def ignored(self, from_client: bool) -> bool:
        """Whether the robot ignores this packet: a client command with a count over 200. The
        limit is the robot's, for what it reads; ARIA reads server packets with counts up to 255."""
        return from_client and self.count > MAX_COUNT

    def encode(self) -> bytes:
        return build_packet(self.payload)


def parse_packet(data: bytes) -> Packet:
    """Exactly one packet. A bad checksum is reported (``Packet.ok``), not raised."""
    data = bytes(data)
    n = len(data)
    if n < 2 or data[:2] != HEADER:
        raise P2osError(0, "no FA FB header")
    if n < 3:
        raise P2osError(2, "truncated before the count")
    count = data[2]
    if count < 2:
        raise P2osError(2, f"count {count} leaves no room for the checksum")
    if n < 3 + count:
        raise P2osError(n, f"truncated: count {count} needs {3 + count} bytes, {n} present")
    if n > 3 + count:
        raise P2osError(3 + count, f"{n - 3 - count} bytes after the packet")
    payload = data[3 : 1 + count]
    written = int.from_bytes(data[1 + count : 3 + count], "big")
    return Packet(payload, written, checksum(payload))


@dataclass(frozen=True)
class Chunk:
    """A piece of a byte stream: a packet (``packet`` set) or bytes that are none (noise, a
    bad count, a truncated tail). ``offset`` is where it starts in the buffer."""

    offset: int
    data: bytes
    packet: Packet | None
    reason: str = ""


def _good_at(buf: bytes, h: int) -> bool:
    """Whether a whole packet with a good checksum starts at ``h`` (an FA FB there)."""
    n = len(buf)
    if h + 3 > n or buf[h + 2] < 2 or h + 3 + buf[h + 2] > n:
        return False
    end = h + 3 + buf[h + 2]
    return checksum(buf[h + 3 : end - 2]) == int.from_bytes(buf[end - 2 : end], "big")


def resync_at(buf: bytes, h: int, final: bool = True) -> int:
    """Where a cut-off header at ``h`` ends: the first FA FB that starts inside the span its
    count claims (its FA in the span; on the span's last byte, its FB just after it) and starts
    a whole packet with a good checksum, when the packet at ``h`` is not itself whole and good
    (``FA FB`` cut off before a packet reads its header's FA as a count of 250 and would swallow
    the packets after it; a span ending on the next header's FA would swallow that packet); -1
    when there is none; -2 (only when not ``final``) when an FA FB before any such one starts a
    packet not all there yet, or the span ends on an FA that is the last byte so far (more bytes
    decide). p2os.lua and serial.lua apply the same rule (docs/fields-p2os-blackboard.md,
    "Resynchronisation")."""
    n = len(buf)
    if h + 3 > n:
        return -1
    last = h + 2 + buf[h + 2]  # the claimed span's last byte
    k = buf.find(HEADER, h + 1, min(last + 2, n))
    edge = not final and last == n - 1 and buf[last] == 0xFA  # an FA whose FB is yet to come
    if (k < 0 and not edge) or _good_at(buf, h):  # no FA FB inside: the checksum is not needed
        return -1
    while k >= 0:
        if not final and (k + 3 > n or k + 3 + buf[k + 2] > n):
            return -2
        if _good_at(buf, k):
            return k
        k = buf.find(HEADER, k + 1, min(last + 2, n))
    return -2 if edge else -1


def iter_chunks(buf: bytes, final: bool = True) -> Iterator[Chunk]:
    """Split a byte stream into packets and the bytes between them; nothing is lost: the
    chunks' data concatenated is ``buf``. A truncated last packet comes out as noise; a header
    cut off before a packet (:func:`resync_at`) too. Not ``final`` (more bytes may follow): a
    packet whose cut-off header only more bytes can tell comes out as truncated."""
    buf = bytes(buf)
    n = len(buf)
    i = 0
    while i < n:
        h = buf.find(HEADER, i)
        if h < 0:
            yield Chunk(i, buf[i:], None, "no FA FB header")
            return
        if h > i:
            yield Chunk(i, buf[i:h], None, "bytes before an FA FB header")
        if h + 3 > n:
            yield Chunk(h, buf[h:], None, "truncated before the count")
            return
        count = buf[h + 2]
        if count < 2:
            yield Chunk(h, buf[h : h + 3], None, f"count {count} leaves no room for the checksum")
            i = h + 3
            continue
        k = resync_at(buf, h, final)
        if k == -2:
            yield Chunk(h, buf[h:], None, "truncated: a packet inside it not all there yet")
            return
        if k > 0:
            yield Chunk(h, buf[h:k], None, "a header cut off before a packet")
            i = k
            continue
        end = h + 3 + count
        if end > n:
            yield Chunk(h, buf[h:], None, f"truncated: count {count} needs {3 + count} bytes")
            return
        payload = buf[h + 3 : end - 2]
        yield Chunk(h, buf[h:end], Packet(payload, int.from_bytes(buf[end - 2 : end], "big"), checksum(payload)))
        i = end


# ---------------------------------------------------------------------------------------------
# client commands

Arg = Union[int, bytes, None]


@dataclass(frozen=True)
class Command:
    """A client command. ``argtype`` is 0x3B, 0x1B, 0x2B or None; ``value`` the signed
    integer (a 0x1B argument's value is minus its magnitude) or the string's bytes."""

    number: int
    argtype: int | None = None
    value: int | bytes | None = None
    extra: bytes = b""  # bytes after the argument (not sent by well-behaved clients)

    @property
    def name(self) -> str:
        return COMMANDS.get(self.number, f"command {self.number}")

    def encode(self) -> bytes:
        return encode_command(self)


def command(name_or_number: str | int, arg: Arg = None) -> Command:
    """A command with its argument typed the usual way: an int >= 0 as 0x3B, < 0 as 0x1B, bytes
    (or str) as a 0x2B string."""
    num = COMMAND_NUMBERS[name_or_number] if isinstance(name_or_number, str) else name_or_number
    if arg is None:
        return Command(num)
    if isinstance(arg, str):
        arg = arg.encode("latin-1")
    if isinstance(arg, (bytes, bytearray)):
        return Command(num, ARG_STRING, bytes(arg))
    return Command(num, ARG_POSITIVE if arg >= 0 else ARG_NEGATIVE, int(arg))


def encode_command(cmd: Command) -> bytes:
    """The payload of a command packet."""
    if not 0 <= cmd.number <= 255:
        raise P2osError(0, f"command number {cmd.number} is not a byte")
    out = bytes((cmd.number,))
    t, v = cmd.argtype, cmd.value
    if t is None:
        pass
    elif t == ARG_STRING:
        if not isinstance(v, (bytes, bytearray)) or len(v) > 255:
            raise P2osError(1, "a string argument must be at most 255 bytes")
        out += bytes((t, len(v))) + bytes(v)
    elif t in (ARG_POSITIVE, ARG_NEGATIVE):
        if not isinstance(v, int):
            raise P2osError(1, "an int argument needs an integer value")
        mag = -v if t == ARG_NEGATIVE else v
        if not 0 <= mag <= 0xFFFF:
            raise P2osError(1, f"argument {v} does not fit a {ARG_TYPES[t]}")
        out += bytes((t,)) + mag.to_bytes(2, "little")
    else:
        if not 0 <= t <= 255 or not isinstance(v, (bytes, bytearray)):
            raise P2osError(1, "unknown argument type needs raw bytes")
        out += bytes((t,)) + bytes(v)
    return out + cmd.extra


def decode_command(payload: bytes) -> Command:
    """A command packet's payload. Truncated arguments raise :class:`P2osError`; an unknown
    argument type keeps the remaining bytes as ``value``."""
    p = bytes(payload)
    if not p:
        raise P2osError(0, "empty payload: no command number")
    num = p[0]
    if len(p) == 1:
        return Command(num)
    t = p[1]
    if t in (ARG_POSITIVE, ARG_NEGATIVE):
        if len(p) < 4:
            raise P2osError(len(p), f"{ARG_TYPES[t]} argument truncated")
        mag = p[2] | p[3] << 8
        return Command(num, t, -mag if t == ARG_NEGATIVE else mag, p[4:])
    if t == ARG_STRING:
        if len(p) < 3:
            raise P2osError(2, "string argument without its length")
        ln = p[2]
        if len(p) < 3 + ln:
            raise P2osError(len(p), f"string argument of {ln} bytes truncated")
        return Command(num, t, p[3 : 3 + ln], p[3 + ln :])
    return Command(num, t, p[2:])


# ---------------------------------------------------------------------------------------------
# server information packets


@dataclass(slots=True)  # (not frozen: a frozen dataclass's __init__ is 3-5x slower, and one is made a packet)
class Sip:
    """A standard server information packet (type 0x32 stopped, 0x33 moving)."""

    moving: bool = False
    xpos: int = 0  # mm (u16, wraps)
    ypos: int = 0  # mm (u16, wraps)
    thpos: int = 0  # 4096ths of a turn (s16)
    lvel: int = 0  # mm/s
    rvel: int = 0  # mm/s
    battery: int = 0  # 0.1 V
    stall_bumpers: int = 0
    control: int = 0
    flags: int = 0
    compass: int = 0  # 2-degree units
    sonars: tuple[tuple[int, int], ...] = ()  # (sonar number, range mm)
    grip_state: int = 0
    anport: int = 0
    analog: int = 0
    digin: int = 0
    digout: int = 0
    extra: bytes = b""  # newer optional fields, kept raw

    @property
    def type(self) -> int:
        return TYPE_SIP_MOVING if self.moving else TYPE_SIP_STOPPED

    @property
    def heading_deg(self) -> float:
        return self.thpos * DEGREES_PER_ANGLE_UNIT

    @property
    def volts(self) -> float:
        return self.battery / 10.0

    def encode(self) -> bytes:
        return encode_sip(self)


_SIP_HEAD = struct.Struct("<BHHhhhBHhHBB")  # type .. compass, sonar count
_SIP_TAIL = struct.Struct("<BBBBB")


def encode_sip(s: Sip) -> bytes:
    try:
        head = _SIP_HEAD.pack(
            s.type, s.xpos, s.ypos, s.thpos, s.lvel, s.rvel, s.battery, s.stall_bumpers, s.control,
            s.flags, s.compass, len(s.sonars),
        )
        son = b"".join(struct.pack("<BH", num, rng) for num, rng in s.sonars)
        tail = _SIP_TAIL.pack(s.grip_state, s.anport, s.analog, s.digin, s.digout)
    except struct.error as exc:
        raise P2osError(0, f"SIP field out of range: {exc}") from None
    return head + son + tail + s.extra


def decode_sip(payload: bytes) -> Sip:
    p = bytes(payload)
    if len(p) < _SIP_HEAD.size:
        raise P2osError(len(p), f"standard SIP truncated: {len(p)} of {_SIP_HEAD.size + _SIP_TAIL.size} bytes")
    t, x, y, th, lv, rv, bat, sb, ctl, fl, comp, nson = _SIP_HEAD.unpack_from(p)
    if t not in (TYPE_SIP_STOPPED, TYPE_SIP_MOVING):
        raise P2osError(0, f"type 0x{t:02X} is not a standard SIP")
    off = _SIP_HEAD.size
    if len(p) < off + 3 * nson:
        raise P2osError(len(p), f"{nson} sonar readings truncated")
    if nson:
        v = struct.unpack_from("<" + "BH" * nson, p, off)
        sonars = tuple(zip(v[::2], v[1::2]))
    else:
        sonars = ()
    off += 3 * nson
    if len(p) < off + _SIP_TAIL.size:
        raise P2osError(len(p), "standard SIP truncated after the sonar readings")
    grip, anport, analog, digin, digout = _SIP_TAIL.unpack_from(p, off)
    return Sip(
        t == TYPE_SIP_MOVING, x, y, th, lv, rv, bat, sb, ctl, fl, comp, sonars, grip, anport, analog, digin,
        digout, p[off + _SIP_TAIL.size :],
    )


@dataclass(frozen=True)
class SyncReply:
    """The server's echo of SYNC0/1/2; the SYNC2 echo carries the robot's name, class and
    subclass as NUL-terminated strings."""

    number: int
    strings: tuple[bytes, ...] = ()
    extra: bytes = b""  # bytes after the last NUL

    def encode(self) -> bytes:
        return bytes((self.number,)) + b"".join(s + b"\0" for s in self.strings) + self.extra


def decode_sync(payload: bytes) -> SyncReply:
    p = bytes(payload)
    if not p or p[0] > 2:
        raise P2osError(0, "not a SYNC echo")
    parts = p[1:].split(b"\0")
    return SyncReply(p[0], tuple(parts[:-1]), parts[-1])


@dataclass(slots=True)  # (not frozen: a frozen dataclass's __init__ is 3-5x slower, and one is made a packet)
class Encoder:
    """ENCODER packet: the raw left and right encoder counts (two s32)."""

    left: int = 0
    right: int = 0
    extra: bytes = b""

    def encode(self) -> bytes:
        try:
            return struct.pack("<Bii", TYPE_ENCODER, self.left, self.right) + self.extra
        except struct.error as exc:
            raise P2osError(1, f"encoder count out of range: {exc}") from None


def decode_encoder(payload: bytes) -> Encoder:
    p = bytes(payload)
    if not p or p[0] != TYPE_ENCODER:
        raise P2osError(0, "not an ENCODER packet")
    if len(p) < 9:
        raise P2osError(len(p), "ENCODER packet truncated")
    left, right = struct.unpack_from("<ii", p, 1)
    return Encoder(left, right, p[9:])


#: CONFIG packet: the leading fields we decode (ARIA's ArRobotConfigPacketReader order)
CONFIG_FIELDS: tuple[tuple[str, str], ...] = (
    ("robot_type", "s"),
    ("subtype", "s"),
    ("serial", "s"),
    ("four_mots", "B"),
    ("rotvel_top", "H"),
    ("transvel_top", "H"),
    ("rotaccel_top", "H"),
    ("transaccel_top", "H"),
    ("pwm_max", "H"),
    ("name", "s"),
    ("sip_cycle", "B"),
    ("host_baud", "B"),
    ("aux_baud", "B"),
    ("gripper", "H"),
    ("front_sonar", "H"),
    ("rear_sonar", "B"),
    ("low_battery", "H"),
    ("revcount", "H"),
    ("watchdog", "H"),
)


@dataclass(frozen=True)
class Config:
    """CONFIG packet: the leading fields in order (as many as present) and the rest raw."""

    values: tuple[tuple[str, int | bytes], ...] = ()
    extra: bytes = b""

    def encode(self) -> bytes:
        out = bytearray((TYPE_CONFIG,))
        for (name, kind), (vname, v) in zip(CONFIG_FIELDS, self.values):
            if name != vname:
                raise P2osError(len(out), f"CONFIG field {vname} out of order (expected {name})")
            if kind == "s":
                if not isinstance(v, bytes) or b"\0" in v:
                    raise P2osError(len(out), f"CONFIG {name} must be bytes without NUL")
                out += v + b"\0"
            else:
                try:
                    out += struct.pack("<" + kind, v)
                except struct.error as exc:
                    raise P2osError(len(out), f"CONFIG {name}: {exc}") from None
        return bytes(out) + self.extra

    def get(self, name: str) -> int | bytes | None:
        return dict(self.values).get(name)


def decode_config(payload: bytes) -> Config:
    p = bytes(payload)
    if not p or p[0] != TYPE_CONFIG:
        raise P2osError(0, "not a CONFIG packet")
    off = 1
    values: list[tuple[str, int | bytes]] = []
    for name, kind in CONFIG_FIELDS:
        if kind == "s":
            end = p.find(b"\0", off)
            if end < 0:
                break
            values.append((name, p[off:end]))
            off = end + 1
        else:
            size = struct.calcsize(kind)
            if off + size > len(p):
                break
            values.append((name, struct.unpack_from("<" + kind, p, off)[0]))
            off += size
    return Config(tuple(values), p[off:])


@dataclass(frozen=True)
class Raw:
    """A server packet of a type we do not decode."""

    data: bytes

    @property
    def type(self) -> int | None:
        return self.data[0] if self.data else None

    def encode(self) -> bytes:
        return self.data


Message = Union[Command, Sip, SyncReply, Encoder, Config, Raw]


def decode_payload(payload: bytes, from_client: bool) -> Message:
    """What a packet says, given its direction. Damaged payloads raise :class:`P2osError`."""
    if from_client:
        return decode_command(payload)
    p = bytes(payload)
    if not p:
        raise P2osError(0, "empty server packet")
    t = p[0]
    if t in (TYPE_SIP_STOPPED, TYPE_SIP_MOVING):
        return decode_sip(p)
    if t <= TYPE_SYNC2:
        return decode_sync(p)
    if t == TYPE_ENCODER:
        return decode_encoder(p)
    if t == TYPE_CONFIG:
        return decode_config(p)
    return Raw(p)


def guess_from_client(payload: bytes) -> bool:
    """Direction from the payload alone (serial captures without direction flags): server
    packet types and SYNC2 echoes carrying strings are the robot's; the rest commands."""
    if not payload:
        return True
    t = payload[0]
    if t in (TYPE_SIP_STOPPED, TYPE_SIP_MOVING, TYPE_CONFIG, TYPE_ENCODER, 0x80, 0x8D, 0xE0, 0xF0):
        return False
    return not (t == TYPE_SYNC2 and len(payload) > 1 and payload[1] not in (ARG_POSITIVE, ARG_NEGATIVE, ARG_STRING))


def encode_message(msg: Message) -> bytes:
    """The packet (header to checksum) carrying ``msg``."""
    return build_packet(msg.encode())
