"""Write the golden inputs of test_golden_small.py (run once; the files are kept in the repo so
the golden outputs do not move when a generator changes): generated P2OS, blackboard and serial
sessions, hand-made edge cases for every branch of p2os.lua, blackboard.lua and serial.lua, and
editcap mutations of the sessions.  ``python tests/dissector/golden_small/make_inputs.py``."""

from __future__ import annotations

import random
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
sys.path.insert(0, str(REPO / "tests"))

from sl_captures import chunked, interleaved  # noqa: E402
from sl_robots import write_serial  # noqa: E402

from sharedlink.capture.serial_format import DIR_IN, DIR_OUT  # noqa: E402
from sharedlink.protocols import blackboard as bbc  # noqa: E402
from sharedlink.protocols import p2os as pc  # noqa: E402
from tshark_util import write_pcap  # noqa: E402

GEN = [
    ("p2os-tcp.pcap", ["--protocol", "p2os", "--duration", "2"]),
    ("p2os-serial.pcapng", ["--protocol", "p2os", "--transport", "serial", "--duration", "2", "--noise", "0.3"]),
    ("bb-udp.pcap", ["--protocol", "blackboard", "--duration", "2"]),
    ("bb-tcp.pcap", ["--protocol", "blackboard", "--transport", "tcp", "--duration", "2"]),
    ("bb-serial.pcapng", ["--protocol", "blackboard", "--transport", "serial", "--duration", "2", "--noise", "0.3"]),
    ("sl-serial.pcapng", ["--transport", "serial", "--duration", "3", "--noise", "0.3"]),
]


def pk(payload: bytes) -> bytes:
    return pc.build_packet(payload)


def p2os_edge() -> list[bytes]:
    cmd = [pk(pc.encode_command(pc.command(n, a))) for n, a in
           ((0, None), (1, None), (2, None), ("VEL", 200), ("RVEL", -15), ("SAY", b"\x01\x02"))]
    sync2 = pk(b"\x02MobileSim\x00Pioneer\x00p3dx-sh\x00")
    bad_ck = bytearray(cmd[3])
    bad_ck[-1] ^= 0x55
    return [
        *cmd[:2], sync2, *cmd[2:],
        bytes(bad_ck),
        b"junk" + cmd[0],                          # junk before a packet
        pk(b"\x0b\x3b\x05"),                       # integer argument truncated
        pk(b"\x0f\x2b\x09ab"),                     # string shorter than its length
        pk(b"\x0f\x2b"),                           # string without its length
        pk(b"\x0f\x2b\x02hi\x00"),                 # ARIA's NUL after the counted string
        pk(b"\x0f\x2b\x02hi\x00\x07"),             # NUL and a byte more
        pk(b"\x04\x77\x01\x00"),                   # unknown argument type
        pk(b"\x63"),                               # unknown command
        pk(b"\x04\x3b\x01\x00\x09"),               # bytes after the argument
        b"\xfa\xfb\x01\x00",                       # count below 2
        pk(b""),                                   # empty payload
        b"\xfa\xfb\xc9" + bytes(201),              # count over 200
        pk(b"\x32\x10\x00"),                       # SIP truncated
        pk(pc.encode_message(pc.Sip(moving=True, xpos=100, sonars=((1, 500), (2, 700))))[3:-2]),
        pk(b"\x90\x01\x00\x00\x00\xff\xff\xff\xff\x05"),  # ENCODER with an extra byte
        pk(b"\x90\x01\x00"),                       # ENCODER truncated
        pk(b"\x20P3DX\x00std\x00123\x00\x01\x2c\x01\x08\x07"),  # CONFIG cut short
        pk(b"\xe0\x01\x02"),                       # a type not decoded
        pk(b"\x01ab"),                             # SYNC1 echo with bytes after
        b"\xfa\xfb\x10\x01\x02",                   # truncated at the end
    ]


def bb_edge() -> list[bytes]:
    s = bbc.build_message(bbc.SetMessage(0x1F00, 1, bytes([1, 2, 3])))
    r = bbc.build_message(bbc.RequestMessage(0xE000, 1, 5))
    req = bbc.RequestMessage(0xE000, 1, 5)
    data = bytes([9, 8, 7, 6, 5])
    resp = data + bytes([bbc.response_checksum(req, data)])
    ack = bytes.fromhex(s[-3:-1].decode())  # the set message's checksum
    return [
        s, ack, r, resp,
        s, s,                                      # a repeat (no ack)
        r, s,                                      # superseded request
        b":03ZZ000101020300\r",                    # non-hex
        b":031F000101020\r",                       # odd digits
        b":0102\r",                                # too short
        b":051F0001010203D7\r\n",                  # count wrong
        s[:-2] + b"00\r",                          # bad checksum
        b"garbage",                                # bytes outside a message
        b"\r\n",                                   # line ends alone
        b":" + b"G" * 40 + b"\r",                  # many non-hex
        r, resp[:3],                               # truncated response
        r, resp[:-1] + b"\x00",                    # bad response checksum
        s, b"\x00",                                # wrong ack
        b";05E000011A",                            # no CR
    ]


def write_serial_edge(path: Path) -> None:
    rng = random.Random(7)
    p = b"".join(p2os_edge()[:8])
    b = b"".join(bb_edge()[:8])
    streams = {DIR_OUT: chunked(p, sorted(rng.sample(range(1, len(p)), 12))),
               DIR_IN: chunked(b"noise\r" + b, sorted(rng.sample(range(1, len(b)), 12)))}
    records, times = interleaved(streams, rng)
    write_serial(path, records, times=times)


def main() -> None:
    cli = REPO / ".venv" / "bin" / "sharedlink"
    for name, args in GEN:
        subprocess.run([str(cli), "gen", str(HERE / name), "--seed", "3", *args], check=True, capture_output=True)
    t = 1_700_000_000.0
    p = p2os_edge()
    write_pcap(HERE / "p2os-edge.pcap", [(t + i * 0.01, x, 40000 + (i % 2) * 0, 8101, "tcp", "10.0.0.1", "10.0.0.2")
                                         for i, x in enumerate(p)])
    b = bb_edge()
    write_pcap(HERE / "bb-edge.pcap", [(t + i * 0.01, x, 7100 if i % 2 else 7200, 7200 if i % 2 else 7100, "udp",
                                        "10.0.0.1" if i % 2 else "10.0.0.2", "10.0.0.2" if i % 2 else "10.0.0.1")
                                       for i, x in enumerate(b)])
    write_serial_edge(HERE / "serial-edge.pcapng")
    # the offset skips Ethernet, IP and TCP / UDP headers (a serial record is all data)
    for name, off in (("p2os-tcp.pcap", 54), ("bb-udp.pcap", 42), ("bb-serial.pcapng", 0), ("p2os-serial.pcapng", 0)):
        for seed in (1, 2):
            src = HERE / name
            dst = HERE / f"mut{seed}-{name}"
            subprocess.run(["editcap", "-E", "0.02", "--seed", str(seed), "-o", str(off), str(src), str(dst)],
                           check=True, capture_output=True)


if __name__ == "__main__":
    main()
