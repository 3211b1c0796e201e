"""P2OS: codec (known-good packets, round trips, nothing but P2osError on any input), the
generated MobileSim session, and dissector/p2os.lua run by the real tshark on known-good
packets, the generated session, TCP reassembly, the heuristic, bare serial buffers and damage."""

from __future__ import annotations

import json
import math
import random
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sl_captures import examples
from sl_robots import write_tcp

from sharedlink.capture.packets import decode_packet, session_frames
from sharedlink.capture.pcapio import LINKTYPE_USER0, PcapngWriter, PcapWriter, read_records
from sharedlink.generators.p2os import P2osGenOptions, generate_p2os_file
from sharedlink.protocols import p2os
from sharedlink.protocols.p2os import (
    ARG_NEGATIVE,
    ARG_POSITIVE,
    ARG_STRING,
    Command,
    Encoder,
    P2osError,
    Sip,
    SyncReply,
    build_packet,
    checksum,
    command,
    decode_command,
    decode_payload,
    decode_sip,
    iter_chunks,
    parse_packet,
)
from tshark_util import fields

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "dissector" / "p2os.lua"
EXTRA = ["-X", f"lua_script:{SCRIPT}"]
USER0 = {"uat:user_dlts": '"User 0 (DLT=147)","p2os","0","","0",""'}

KNOWN_GOOD = [
    ("FA FB 03 00 00 00", Command(0)),
    ("FA FB 03 01 00 01", Command(1)),
    ("FA FB 06 04 3B 01 00 05 3B", Command(4, ARG_POSITIVE, 1)),
    ("FA FB 06 0B 3B 64 00 6F 3B", Command(11, ARG_POSITIVE, 100)),
    ("FA FB 06 05 1B E8 03 ED 1E", Command(5, ARG_NEGATIVE, -1000)),
]
WARN = 0x00600000  # expert severity: warning and above


def p2os_fields(capture: Path, names: list[str], prefs: dict | None = None, **kw):
    """tshark -T fields with p2os.lua loaded (tshark_util checks return code, Lua errors on
    stdout and stderr); the run must have decoded P2OS."""
    rows = fields(capture, ["frame.protocols", *names], prefs=prefs, extra=EXTRA, **kw)
    assert any("p2os" in ":".join(r["frame.protocols"]).split(":") for r in rows), "no P2OS decoded"
    return rows


# ---------------------------------------------------------------------------------------------
# codec


@pytest.mark.parametrize("hexbytes,cmd", KNOWN_GOOD)
def test_known_good_packets(hexbytes, cmd):
    raw = bytes.fromhex(hexbytes)
    pkt = parse_packet(raw)
    assert pkt.ok is True
    assert decode_command(pkt.payload) == cmd
    assert build_packet(cmd.encode()) == raw


def test_checksum_rules():
    # pairs high byte first, 16 bits kept, odd last byte XORed into the low byte
    assert checksum(b"") == 0
    assert checksum(b"\x04\x3b\x01\x00") == 0x053B
    assert checksum(b"\xff\xff\xff\xff") == 0xFFFE
    assert checksum(b"\x12\x34\x56") == 0x1234 ^ 0x56


def test_command_helper_types_the_argument():
    assert command("VEL", 100) == Command(11, ARG_POSITIVE, 100)
    assert command("SETA", -1000) == Command(5, ARG_NEGATIVE, -1000)
    assert command("SAY", b"\x05\x3c") == Command(15, ARG_STRING, b"\x05\x3c")
    assert command("OPEN") == Command(1)
    assert command("VEL", 100).name == "VEL"


def test_sync2_echo_and_sip():
    reply = SyncReply(2, (b"MobileSim", b"Pioneer", b"p3dx-sh"))
    assert decode_payload(reply.encode(), from_client=False) == reply
    sip = Sip(True, 5000, 4000, 512, 100, 120, 129, 0, 0, 3, 0, ((3, 1234), (4, 999)))
    assert decode_sip(sip.encode()) == sip
    assert sip.heading_deg == 45.0 and sip.volts == pytest.approx(12.9)
    assert decode_payload(Encoder(-5, 7).encode(), from_client=False) == Encoder(-5, 7)


def test_damage_raises_p2os_error_with_offset():
    with pytest.raises(P2osError) as e:
        parse_packet(bytes.fromhex("FAFB060B3B6400"))
    assert e.value.offset == 7 and "truncated" in e.value.reason
    with pytest.raises(P2osError):
        parse_packet(b"\xfa\xfb\x01\x00")
    with pytest.raises(P2osError) as e:
        decode_command(b"\x0b\x3b\x64")
    assert "truncated" in e.value.reason
    bad = parse_packet(bytes.fromhex("FAFB060B3B64006F3C"))
    assert bad.ok is False and bad.written == 0x6F3C and bad.calculated == 0x6F3B


def test_count_over_200_is_flagged():
    pkt = parse_packet(build_packet(b"\x0f" + bytes(200)))
    assert pkt.count == 203 and pkt.too_long


def test_iter_chunks_keeps_everything():
    buf = b"\x00\x01" + bytes.fromhex("FAFB03000000") + b"\xfa\xfb\x01" + bytes.fromhex("FAFB060B3B64006F3B") + b"\xfa\xfb\x09"
    chunks = list(iter_chunks(buf))
    assert b"".join(c.data for c in chunks) == buf
    assert [c.packet is not None for c in chunks] == [False, True, False, True, False]


commands = st.builds(
    Command,
    st.integers(0, 255),
    st.sampled_from([ARG_POSITIVE]),
    st.integers(0, 0xFFFF),
) | st.builds(
    Command, st.integers(0, 255), st.sampled_from([ARG_NEGATIVE]), st.integers(-0xFFFF, 0)
) | st.builds(
    Command, st.integers(0, 255), st.sampled_from([ARG_STRING]), st.binary(max_size=40)
) | st.builds(Command, st.integers(0, 255))

sips = st.builds(
    Sip,
    st.booleans(),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFF),
    st.integers(-32768, 32767),
    st.integers(-32768, 32767),
    st.integers(-32768, 32767),
    st.integers(0, 255),
    st.integers(0, 0xFFFF),
    st.integers(-32768, 32767),
    st.integers(0, 0xFFFF),
    st.integers(0, 255),
    st.lists(st.tuples(st.integers(0, 255), st.integers(0, 0xFFFF)), max_size=16).map(tuple),
    st.integers(0, 255),
    st.integers(0, 255),
    st.integers(0, 255),
    st.integers(0, 255),
    st.integers(0, 255),
    st.binary(max_size=8),
)


@settings(max_examples=examples(300), deadline=None)
@given(commands)
def test_command_round_trip(cmd):
    pkt = parse_packet(build_packet(cmd.encode()))
    assert pkt.ok and decode_command(pkt.payload) == cmd


@settings(max_examples=examples(200), deadline=None)
@given(sips)
def test_sip_round_trip(sip):
    pkt = parse_packet(build_packet(sip.encode()))
    assert pkt.ok and decode_payload(pkt.payload, from_client=False) == sip


@settings(max_examples=examples(300), deadline=None)
@given(st.binary(max_size=253))
def test_packet_round_trip(payload):
    assert parse_packet(build_packet(payload)).payload == payload


@settings(max_examples=examples(500), deadline=None)
@given(st.binary(max_size=300) | st.binary(max_size=40).map(lambda b: b"\xfa\xfb" + b))
def test_nothing_but_p2os_error_escapes(data):
    for fn in (parse_packet, decode_command, decode_sip, lambda d: decode_payload(d, False)):
        try:
            fn(data)
        except P2osError as exc:
            assert isinstance(exc.offset, int) and exc.reason
    assert b"".join(c.data for c in iter_chunks(data)) == data


# ---------------------------------------------------------------------------------------------
# generated session


def _tcp_streams(path: Path) -> dict[bool, bytes]:
    """The two TCP byte streams (by from_client), checking sequence numbers are contiguous."""
    streams: dict[bool, bytearray] = {True: bytearray(), False: bytearray()}
    next_seq: dict[bool, int] = {}
    for rec in read_records(path):
        d = decode_packet(rec.linktype, rec.data)
        assert d is not None and d.proto == "tcp"
        client = d.dport == p2os.MOBILESIM_PORT
        if d.tcp_flags & 0x02:  # SYN
            next_seq[client] = d.tcp_seq + 1
            continue
        if d.payload:
            assert d.tcp_seq == next_seq[client], "sequence gap"
            next_seq[client] += len(d.payload)
            streams[client] += d.payload
    return {k: bytes(v) for k, v in streams.items()}


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> tuple[Path, object]:
    path = tmp_path_factory.mktemp("p2os") / "session.pcap"
    stats = generate_p2os_file(P2osGenOptions(duration=20, seed=5), path)
    return path, stats


def test_generation_is_deterministic(tmp_path, session):
    path, _ = session
    again = tmp_path / "again.pcap"
    generate_p2os_file(P2osGenOptions(duration=20, seed=5), again)
    assert again.read_bytes() == path.read_bytes()
    other = tmp_path / "other.pcap"
    generate_p2os_file(P2osGenOptions(duration=20, seed=6), other)
    assert other.read_bytes() != path.read_bytes()


def test_session_is_a_plausible_conversation(session):
    path, stats = session
    streams = _tcp_streams(path)
    msgs = {}
    for side, data in streams.items():
        chunks = list(iter_chunks(data))
        assert all(c.packet is not None and c.packet.ok for c in chunks)
        msgs[side] = [decode_payload(c.packet.payload, side) for c in chunks]
    assert len(msgs[True]) + len(msgs[False]) == stats.packets
    client, server = msgs[True], msgs[False]
    # handshake: SYNC0, SYNC1, SYNC2 echoed, the SYNC2 echo naming the robot; then OPEN
    assert client[:4] == [Command(0), Command(1), Command(2), Command(1)]
    assert [m.number for m in server[:3]] == [0, 1, 2]
    assert server[2].strings == (b"MobileSim", b"Pioneer", b"p3dx-sh")
    names = [m.name for m in client]
    assert "ENABLE" in names and "VEL" in names and "PULSE" in names and names[-1] == "CLOSE"
    sips_ = [m for m in server if isinstance(m, Sip)]
    assert len(sips_) >= 190  # 100 ms cycle over 20 s
    assert any(s.moving for s in sips_) and not sips_[0].moving


def test_sips_trace_the_commanded_motion(session):
    path, _ = session
    streams = _tcp_streams(path)
    sips_ = [m for m in (decode_payload(c.packet.payload, False) for c in iter_chunks(streams[False])) if isinstance(m, Sip)]
    vels = [c.value for c in (decode_command(c.packet.payload) for c in iter_chunks(streams[True])) if c.name == "VEL"]
    top = max(max(s.lvel, s.rvel) for s in sips_)
    assert top <= max(vels) + 50  # wheel speeds never exceed what was commanded (plus turning)
    for a, b in zip(sips_, sips_[1:]):
        # the distance between two SIPs is what the reported speeds cover in 100 ms
        dist = math.hypot(b.xpos - a.xpos, b.ypos - a.ypos)
        v = (a.lvel + a.rvel + b.lvel + b.rvel) / 4
        assert abs(dist - abs(v) * 0.1) < 12, (a, b)
        assert 0 < b.xpos < 10_000 and 0 < b.ypos < 8_000  # inside the room
        assert b.battery <= a.battery


def test_session_decoded_end_to_end_by_tshark(session):
    path, stats = session
    rows = p2os_fields(
        path,
        ["p2os.checksum.status", "p2os.direction", "p2os.command.name", "p2os.sip.xpos", "p2os.robot.name",
         "_ws.expert.severity", "tcp.analysis.flags", "tcp.checksum.status", "ip.checksum.status"],
        prefs={"tcp.check_checksum": True, "ip.check_checksum": True},
    )
    statuses = [s for r in rows for s in r["p2os.checksum.status"]]
    assert len(statuses) == stats.packets and set(statuses) == {"1"}
    assert not any(r["tcp.analysis.flags"] for r in rows)
    assert {s for r in rows for s in r["tcp.checksum.status"]} == {"1"}  # Good
    assert {s for r in rows for s in r["ip.checksum.status"]} == {"1"}
    assert not [s for r in rows for s in r["_ws.expert.severity"] if int(s) >= WARN]
    names = [n for r in rows for n in r["p2os.command.name"]]
    assert names[:4] == ["SYNC0", "SYNC1", "SYNC2", "OPEN"] and names[-1] == "CLOSE"
    assert ["MobileSim"] in [r["p2os.robot.name"] for r in rows]
    xs = [int(x) for r in rows for x in r["p2os.sip.xpos"]]
    streams = _tcp_streams(path)
    expect = [m.xpos for m in (decode_payload(c.packet.payload, False) for c in iter_chunks(streams[False])) if isinstance(m, Sip)]
    assert xs == expect
    # direction from the port: commands to 8101, server packets from it
    for r in rows:
        if r["p2os.command.name"]:
            assert set(r["p2os.direction"]) == {"0"}


# ---------------------------------------------------------------------------------------------
# dissector on hand-made captures


def test_known_good_and_reassembly_over_tcp(tmp_path):
    """The known-good packets as one client byte stream cut at awkward places (inside the
    header, count and checksum, then at random) with several packets per segment."""
    one = b"".join(bytes.fromhex(h) for h, _ in KNOWN_GOOD)
    stream = one * 12
    rng = random.Random(3)
    cuts = sorted({1, 4, 8, 9, 20, 23, 30, *rng.sample(range(31, len(stream)), 40)}) + [len(stream)]
    pieces = [stream[a:b] for a, b in zip([0, *cuts], cuts)]
    path = tmp_path / "known.pcap"
    write_tcp(path, [(True, p) for p in pieces], 8101)
    rows = p2os_fields(path, ["p2os.command.name", "p2os.arg.int", "p2os.argtype", "p2os.checksum.status"])
    names = [n for r in rows for n in r["p2os.command.name"]]
    # the SYNC names hold until a SYNC2 echo is seen; none is in this stream
    assert names == ["SYNC0", "SYNC1", "ENABLE", "VEL", "SETA"] * 12
    assert [a for r in rows for a in r["p2os.arg.int"]] == ["1", "100", "-1000"] * 12
    assert [a for r in rows for a in r["p2os.argtype"]] == ["0x3b", "0x3b", "0x1b"] * 12
    assert {s for r in rows for s in r["p2os.checksum.status"]} == {"1"}


def test_heuristic_on_another_port_and_port_preference(tmp_path):
    path = tmp_path / "other.pcap"
    events = [(True, bytes.fromhex(h)) for h, _ in KNOWN_GOOD]
    events.insert(2, (False, build_packet(SyncReply(2, (b"Robbie", b"Pioneer", b"p2dx")).encode())))
    write_tcp(path, events, 9000)
    rows = p2os_fields(path, ["p2os.command.name", "p2os.robot.name"])
    assert [n for r in rows for n in r["p2os.command.name"]] == ["SYNC0", "SYNC1", "ENABLE", "VEL", "SETA"]
    assert [n for r in rows for n in r["p2os.robot.name"]] == ["Robbie"]
    # a packet with a bad checksum is not claimed by the heuristic ...
    bad = tmp_path / "bad.pcap"
    write_tcp(bad, [(True, bytes.fromhex("FAFB060B3B64006F3C"))] * 2, 9000)
    rows = fields(bad, ["p2os.checksum.status"], extra=EXTRA)
    assert not any(r["p2os.checksum.status"] for r in rows)
    # ... but the port preference decodes it, flagged
    rows = p2os_fields(bad, ["p2os.checksum.status", "_ws.expert.message"], prefs={"p2os.tcp_port": 9000})
    assert [s for r in rows for s in r["p2os.checksum.status"]] == ["0", "0"]
    assert any("Bad checksum" in m for r in rows for m in r["_ws.expert.message"])


def test_serial_buffers_direction_and_count_over_200(tmp_path):
    """Bare byte buffers (serial captures; the dissector called by name on the link type),
    with the pcapng direction flag telling commands (outbound) from server packets."""
    path = tmp_path / "serial.pcapng"
    sip = Sip(False, 100, 200, -1024, 0, 0, 125, 0, 0, 1, 0, ((0, 500),))
    records = [
        (2, bytes.fromhex("FAFB03000000")),  # SYNC0 sent
        (1, bytes.fromhex("FAFB03000000")),  # its echo, received
        (1, build_packet(sip.encode())),
        (2, build_packet(b"\x0f" + bytes(200))),  # count 203
        (0, bytes.fromhex("FAFB060B3B64006F3B")),  # no flag: direction from the content
    ]
    with open(path, "wb") as fh:
        w = PcapngWriter(fh, LINKTYPE_USER0)
        for i, (flag, data) in enumerate(records):
            w.write(10**18 + i * 1000, data, flag)
    rows = p2os_fields(
        path,
        ["p2os.direction", "p2os.type", "p2os.sip.heading", "p2os.sip.volts", "p2os.sip.sonar.range",
         "_ws.expert.message"],
        prefs=USER0,
    )
    assert [r["p2os.direction"] for r in rows] == [["0"], ["1"], ["1"], ["0"], ["0"]]
    assert rows[2]["p2os.sip.heading"] == ["-90"] and rows[2]["p2os.sip.volts"] == ["12.5"]
    assert rows[2]["p2os.sip.sonar.range"] == ["500"]
    assert any("over 200" in m for m in rows[3]["_ws.expert.message"])
    assert any("guessed" in m for m in rows[4]["_ws.expert.message"])


def _damaged_buffers(seed: int = 7) -> list[bytes]:
    """Truncations at every byte of a few packets, and random mutations the codec says are
    damage (so each must draw an expert info)."""
    rng = random.Random(seed)
    good = [bytes.fromhex(h) for h, _ in KNOWN_GOOD]
    good.append(build_packet(Sip(True, 1, 2, 3, 4, 5, 120, 0, 0, 1, 0, ((1, 300), (2, 400))).encode()))
    good.append(build_packet(SyncReply(2, (b"a", b"b", b"c")).encode()))
    good.append(build_packet(Encoder(1, 2).encode()))
    good.append(build_packet(command("SAY", b"\x01\x02\x03").encode()))
    out = [g[:k] for g in good for k in range(1, len(g))]
    for _ in range(400):
        g = bytearray(rng.choice(good))
        for _ in range(rng.randint(1, 3)):
            g[rng.randrange(len(g))] = rng.randrange(256)
        chunks = list(iter_chunks(bytes(g)))
        if all(c.packet is not None and c.packet.ok and not c.packet.too_long for c in chunks):
            continue  # still good packets: not damage
        out.append(bytes(g))
    return out


def test_every_damage_gives_expert_infos_and_no_lua_error(tmp_path):
    bufs = _damaged_buffers()
    path = tmp_path / "damage.pcapng"
    with open(path, "wb") as fh:
        w = PcapngWriter(fh, LINKTYPE_USER0)
        for i, b in enumerate(bufs):
            w.write(10**18 + i * 1000, b, 2 if i % 2 else 1)
    rows = p2os_fields(path, ["p2os.header", "_ws.expert.severity", "_ws.expert.message"], prefs=USER0)
    assert len(rows) == len(bufs)
    for buf, row in zip(bufs, rows):
        assert any(int(s) >= WARN for s in row["_ws.expert.severity"]), (buf.hex(), row)


def test_random_buffers_no_lua_error(tmp_path):
    rng = random.Random(11)
    bufs = [bytes(rng.randrange(256) for _ in range(rng.randint(1, 80))) for _ in range(300)]
    bufs += [b"\xfa\xfb" + bytes(rng.randrange(256) for _ in range(rng.randint(0, 60))) for _ in range(300)]
    path = tmp_path / "random.pcap"
    with open(path, "wb") as fh:
        w = PcapWriter(fh, LINKTYPE_USER0)
        for i, b in enumerate(bufs):
            w.write(10**18 + i * 1000, b)
    rows = p2os_fields(path, ["p2os.junk", "p2os.header"], prefs=USER0)
    assert len(rows) == len(bufs)


def test_cli_gen_protocol_p2os(tmp_path, capsys):
    from sharedlink.cli import main

    out = tmp_path / "cli.pcapng"
    assert main(["gen", str(out), "--protocol", "p2os", "--duration", "3", "--seed", "2", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["protocol"] == "p2os" and summary["transport"] == "tcp" and summary["port"] == 8101
    assert summary["kinds"]["SIP"] >= 28
    assert out.read_bytes()[:4] == b"\x0a\x0d\x0d\x0a"  # pcapng from the name
    assert main(["gen", str(tmp_path / "u.pcap"), "--protocol", "p2os", "--transport", "udp", "--duration", "3", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["transport"] == "udp"  # (test_p2os_udp.py: decoded alike)
    assert main(["gen", str(tmp_path / "x.pcap"), "--protocol", "p2os", "--transport", "serial", "--format", "pcap"]) == 2
    assert "pcapng" in capsys.readouterr().err


def test_fetched_by_name_on_a_bare_buffer(tmp_path):
    """What the serial dispatcher does: Dissector.get("p2os"):call(tvb, pinfo, tree)."""
    wrapper = tmp_path / "dispatch.lua"
    wrapper.write_text(
        'local p = Proto("dispatchtest", "dispatch test")\n'
        "function p.dissector(tvb, pinfo, tree)\n"
        '    return Dissector.get("p2os"):call(tvb, pinfo, tree)\n'
        "end\n"
    )
    path = tmp_path / "bare.pcap"
    with open(path, "wb") as fh:
        w = PcapWriter(fh, LINKTYPE_USER0)
        w.write(10**18, b"".join(bytes.fromhex(h) for h, _ in KNOWN_GOOD))
    rows = fields(path, ["p2os.command.name", "p2os.checksum.status"], extra=[*EXTRA, "-X", f"lua_script:{wrapper}"],
                  prefs={"uat:user_dlts": '"User 0 (DLT=147)","dispatchtest","0","","0",""'})
    assert rows[0]["p2os.command.name"] == ["SYNC0", "SYNC1", "ENABLE", "VEL", "SETA"]
    assert rows[0]["p2os.checksum.status"] == ["1"] * 5


def test_serial_session_decoded_through_the_dispatcher(tmp_path):
    """`gen --protocol p2os --transport serial`: the same session on a UART, chunked at random,
    reassembled by the serial dispatcher and decoded by p2os.lua with good checksums."""
    path = tmp_path / "p2os-serial.pcapng"
    stats = generate_p2os_file(P2osGenOptions(duration=6, seed=3, fmt="pcapng", transport="serial"), path)
    recs = list(read_records(path))
    assert recs and {r.linktype for r in recs} == {LINKTYPE_USER0} and {r.flags & 3 for r in recs} == {1, 2}
    extra = EXTRA + ["-X", f"lua_script:{REPO / 'dissector' / 'serial.lua'}"]
    rows = fields(path, ["frame.protocols", "p2os.checksum.status", "p2os.command.name", "_ws.expert.severity"], extra=extra)
    assert any("p2os" in ":".join(r["frame.protocols"]).split(":") for r in rows), "no P2OS decoded"
    statuses = [s for r in rows for s in r["p2os.checksum.status"]]
    assert len(statuses) == stats.packets and set(statuses) == {"1"}
    names = [n for r in rows for n in r["p2os.command.name"]]
    assert names[:3] == ["SYNC0", "SYNC1", "SYNC2"] and names[-1] == "CLOSE"
    assert not [s for r in rows for s in r["_ws.expert.severity"] if int(s) >= 0x00800000]  # no error


def _aria_com_str(command: int, argument: bytes) -> bytes:
    """A string command as ARIA builds it (ArRobotPacketSender::comStr): setID(command),
    uByteToBuf(STRARG = 0x2B), uByteToBuf(strlen(argument)), strToBuf(argument), which copies
    strlen + 1 bytes (the NUL too); finalizePacket: FA FB, the count of the bytes after it
    (checksum included), then ArRobotPacket::calcCheckSum high byte first (big-endian pairs
    added, 16 bits kept, an odd last byte XORed in)."""
    body = bytes([command, 0x2B, len(argument)]) + argument + b"\x00"
    c, i, n = 0, 0, len(body)
    while n > 1:
        c = (c + ((body[i] << 8) | body[i + 1])) & 0xFFFF
        n, i = n - 2, i + 2
    if n > 0:
        c ^= body[i]
    return b"\xfa\xfb" + bytes([len(body) + 2]) + body + bytes([c >> 8, c & 0xFF])


def test_aria_string_argument_ends_with_its_nul(tmp_path):
    """Issue 29 item 6: comStr(SAY, "\\x01\\x02") sends 0f 2b 02 01 02 00; the NUL after the
    counted characters is the string's terminator (p2os.arg.terminator), not "Bytes after the
    expected end". A byte after the NUL is still extra."""
    say = _aria_com_str(15, b"\x01\x02")
    assert say[3:9] == bytes.fromhex("0f2b02010200")
    tty = _aria_com_str(42, b"hello")
    extra = bytearray(say[:-2] + b"\x07")
    extra[2] += 1
    body = bytes(extra[3:])
    c, i, n = 0, 0, len(body)
    while n > 1:
        c = (c + ((body[i] << 8) | body[i + 1])) & 0xFFFF
        n, i = n - 2, i + 2
    if n > 0:
        c ^= body[i]
    extra += bytes([c >> 8, c & 0xFF])
    path = tmp_path / "aria.pcap"
    write_tcp(path, [(True, say), (True, tty), (True, bytes(extra))], 8101)
    rows = p2os_fields(path, ["p2os.command.name", "p2os.arg.string", "p2os.arg.terminator", "p2os.extra",
                              "p2os.checksum.status", "_ws.expert.message"])
    rows = [r for r in rows if r["p2os.command.name"]]
    assert [r["p2os.command.name"] for r in rows] == [["SAY"], ["TTY2"], ["SAY"]]
    # tshark 4.4+ escapes the backslash of a shown \x01 again in -T fields ("\\x01"); 4.0 does not
    strings = [[v.replace("\\\\", "\\") for v in r["p2os.arg.string"]] for r in rows]
    assert strings == [["\\x01\\x02"], ["hello"], ["\\x01\\x02"]]
    assert [r["p2os.arg.terminator"] for r in rows] == [["0x00"]] * 3
    assert [r["p2os.checksum.status"] for r in rows] == [["1"]] * 3
    assert not rows[0]["p2os.extra"] and not rows[1]["p2os.extra"]
    assert not any("after the expected end" in m for r in rows[:2] for m in r["_ws.expert.message"])
    assert rows[2]["p2os.extra"] == ["07"]
    assert any("after the expected end" in m for m in rows[2]["_ws.expert.message"])


def test_max_conversations_bounds_the_handshake_state(tmp_path):
    """Issue 31: the SYNC2 echo is remembered for at most p2os.max_conversations conversations;
    past it the echo says "Limit exceeded: ..." and that conversation's command 1 stays SYNC1."""
    echo = build_packet(SyncReply(2, (b"Robbie", b"Pioneer", b"p2dx")).encode())
    one = bytes.fromhex("FAFB03010001")  # command 1: SYNC1 in the handshake, OPEN after it
    path = tmp_path / "three.pcap"
    with open(path, "wb") as fh:
        w = PcapWriter(fh)
        ts = 10**18
        for client in (40001, 40002, 40003):
            evs = [(ts + i * 10_000_000, c, p) for i, (c, p) in enumerate([(False, echo), (True, one)])]
            ts += 10**9
            for t, _, frame in session_frames(evs, "tcp", ("127.0.0.1", client), ("127.0.0.1", 8101)):
                w.write(t, frame)
    names = ["p2os.command.name", "p2os.robot.name", "_ws.expert.message"]
    for two_pass in (False, True):
        rows = [r for r in p2os_fields(path, names, prefs={"p2os.max_conversations": 2}, two_pass=two_pass)
                if r["p2os.command.name"] or r["p2os.robot.name"]]
        assert [n for r in rows for n in r["p2os.command.name"]] == ["OPEN", "OPEN", "SYNC1"]
        limited = [r["p2os.robot.name"] for r in rows if any(m.startswith("Limit exceeded:") for m in r["_ws.expert.message"])]
        assert limited == [["Robbie"]]
    rows = p2os_fields(path, names)
    assert [n for r in rows for n in r["p2os.command.name"]] == ["OPEN"] * 3
