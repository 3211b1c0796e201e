"""A P2OS header cut off before a packet (``FA FB`` and then a whole packet): the header's
count byte is the next header's FA, a count of 250, which swallowed the packets after it in
both decoders. Both now resynchronise on the next FA FB inside the claimed span that starts a
whole packet with a good checksum (p2os.resync_at, serial.lua p2os_resync_at, p2os.lua
resync_at): serial.lua and the Python reader find the same frames however the stream is cut
into records, and p2os.lua over TCP decodes every packet after the cut header."""

from __future__ import annotations

from pathlib import Path

import pytest
from sl_robots import write_serial, write_tcp

import tshark_util as tu
from sharedlink.capture.serial_format import DIR_OUT, read_capture
from sharedlink.protocols import p2os

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = [a for s in sorted((REPO / "dissector").glob("*.lua")) if s.name != "sharedlink.lua"
           for a in ("-X", f"lua_script:{s}")]


def _packets() -> list[bytes]:
    return [p2os.encode_message(p2os.Command(p2os.COMMAND_NUMBERS["SETV"], p2os.ARG_POSITIVE, 100 + i))
            for i in range(6)]


def _stream() -> tuple[bytes, list[bytes]]:
    """Two packets, a cut-off header, four packets: six packets in all."""
    pk = _packets()
    return pk[0] + pk[1] + b"\xfa\xfb" + b"".join(pk[2:]), pk


def _capture(path: Path, chunks: list[bytes]) -> Path:
    return write_serial(path, [(c, DIR_OUT) for c in chunks])


def test_python_resynchronises_after_a_cut_header() -> None:
    data, pk = _stream()
    chunks = list(p2os.iter_chunks(data))
    assert [c.data for c in chunks if c.packet] == pk
    assert [c.data for c in chunks if not c.packet] == [b"\xfa\xfb"]
    # a whole packet with a good checksum that holds an FA FB is still one packet
    inner = p2os.encode_message(p2os.Command(p2os.COMMAND_NUMBERS["SAY"], p2os.ARG_STRING, b"\xfa\xfb" + pk[0]))
    assert [c.data for c in p2os.iter_chunks(inner)] == [inner]


@pytest.mark.parametrize("cut", [0, 1, 2, 5])
def test_serial_lua_and_python_resynchronise_alike(tmp_path: Path, cut: int) -> None:
    data, pk = _stream()
    # records of `cut` bytes (0: the whole stream in one record)
    chunks = [data] if cut == 0 else [data[i:i + cut] for i in range(0, len(data), cut)]
    cap = _capture(tmp_path / "cut.pcapng", chunks)
    py = [p.data for _r, _d, p in read_capture(cap) if p.is_frame]
    assert py == pk
    rows = tu.fields(cap, ["slserial.frame", "p2os.count"], extra=SCRIPTS, two_pass=True)
    lua = [bytes.fromhex(h.replace(":", "")) for r in rows for h in r["slserial.frame"]]
    assert lua == py
    assert sum(len(r["p2os.count"]) for r in rows) == len(pk)


@pytest.mark.parametrize("split", [19, 20, 22, 25])
def test_p2os_lua_over_tcp_resynchronises(tmp_path: Path, split: int) -> None:
    """Two TCP segments cut anywhere around the cut-off header (18..19; 22: the packet after it
    not all there yet, which TCP reassembly waits for)."""
    data, pk = _stream()
    cap = tmp_path / "tcp.pcap"
    write_tcp(cap, [(True, data[:split]), (True, data[split:])], p2os.MOBILESIM_PORT)
    rows = tu.fields(cap, ["p2os.count", "p2os.checksum.status", "p2os.junk"], extra=SCRIPTS, two_pass=True)
    assert [s for r in rows for s in r["p2os.checksum.status"]] == ["1"] * len(pk)
    assert [j.replace(":", "") for r in rows for j in r["p2os.junk"]] == ["fafb"]
