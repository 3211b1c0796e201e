"""The one record walker (capture/pcap_blocks.py) on pcapng files: every cut of a file of two
sections (each byte order), three interfaces, obsolete and simple packet blocks, a numbered
custom block and a skipped one gives the records whose blocks are whole and then the error the
cut's place calls for; any block size of the walk gives the same records; the core reads a
pcapng file through the same walker (serial captures are pcapng)."""

from __future__ import annotations

import io
import struct
from itertools import accumulate

import pytest

from sharedlink.analysis.core.records import capture_records
from sharedlink.capture.pcap_blocks import walk_pcapng
from sharedlink.capture.pcapio import CaptureError, Record, read_records
from sharedlink.capture.serial_format import SerialCaptureWriter


def _block(endian: str, btype: int, body: bytes) -> bytes:
    body += b"\0" * ((-len(body)) & 3)
    return struct.pack(endian + "II", btype, 12 + len(body)) + body + struct.pack(endian + "I", 12 + len(body))


def _opt(endian: str, code: int, val: bytes) -> bytes:
    return struct.pack(endian + "HH", code, len(val)) + val + b"\0" * ((-len(val)) & 3)


def _section(endian: str, first: int) -> list[tuple[str, bytes]]:
    """(kind, block) of one section: its header, two interfaces, packets of each kind."""
    out = [("shb", _block(endian, 0x0A0D0D0A, struct.pack(endian + "IHHq", 0x1A2B3C4D, 1, 0, -1))),
           ("idb", _block(endian, 1, struct.pack(endian + "HHI", 1, 0, 0) + _opt(endian, 9, b"\x09") + _opt(endian, 0, b""))),
           ("idb", _block(endian, 1, struct.pack(endian + "HHI", 147, 0, 9)))]
    for i in range(first, first + 4):
        data = bytes(range(i, i + 10 + i % 4))
        ts = 10**18 + i
        flags = _opt(endian, 2, struct.pack(endian + "I", 2)) + _opt(endian, 0, b"") if i % 2 else b""
        out.append(("packet", _block(endian, 6, struct.pack(endian + "IIIII", i % 2, ts >> 32, ts & 0xFFFFFFFF,
                                                              len(data), len(data)) + data + b"\0" * ((-len(data)) & 3) + flags)))
    out.append(("frame", _block(endian, 0x00000BAD, struct.pack(endian + "I", 32473) + b"custom")))
    out.append(("skip", _block(endian, 4, struct.pack(endian + "HH", 0, 0))))
    out.append(("packet", _block(endian, 2, struct.pack(endian + "HHIIII", 1, 0, 0, 5, 4, 4) + b"abcd")))
    out.append(("packet", _block(endian, 3, struct.pack(endian + "I", 12) + bytes(range(12)))))  # (SnapLen 0 on 0)
    return out


@pytest.fixture(scope="module")
def blocks() -> list[tuple[str, bytes]]:
    return _section("<", 0) + _section(">", 10)


def _expected_error(blocks: list[tuple[str, bytes]], cut: int) -> tuple[int | None, str] | None:
    """What a file cut after ``cut`` bytes fails with: (record, text), None at a block's end."""
    start = numbered = 0
    for i, (kind, b) in enumerate(blocks):
        end = start + len(b)
        if cut == start:
            return None
        if cut < end:
            at = cut - start
            where = None if i == 0 else numbered + 1
            if at < 8:
                return where, "truncated block header"
            if kind == "shb":
                return where, "truncated section header"
            return numbered + 1, f"truncated block ({at} of {len(b)} bytes)"
        numbered += kind in ("packet", "frame")
        start = end
    return None


def test_every_cut_gives_the_whole_blocks_records_then_the_right_error(tmp_path, blocks):
    data = b"".join(b for _k, b in blocks)
    path = tmp_path / "all.pcapng"
    path.write_bytes(data)
    every = list(read_records(path))
    assert len(every) == 12 and [r.number for r in every[:7]] == [1, 2, 3, 4, 6, 7, 8]  # (the custom block: 5)
    assert [r.linktype for r in every[:6]] == [1, 147, 1, 147, 147, 1] and every[1].flags == 2
    assert every[5].data == bytes(range(12)) and every[4].data == b"abcd"
    ends = list(accumulate(len(b) for _k, b in blocks))
    for cut in range(4, len(data)):
        p = tmp_path / "cut.pcapng"
        p.write_bytes(data[:cut])
        got: list[Record] = []
        want = _expected_error(blocks, cut)
        if want is None:
            got = list(read_records(p))
        else:
            with pytest.raises(CaptureError) as exc:
                for r in read_records(p):
                    got.append(r)
            assert (exc.value.record, exc.value.reason) == want, cut
        whole = sum(1 for (kind, _b), e in zip(blocks, ends) if kind == "packet" and e <= cut)
        assert got == every[:whole], cut


@pytest.mark.parametrize("size", [7, 64, 1000])
def test_any_block_size_gives_the_same_records(tmp_path, blocks, size):
    data = b"".join(b for _k, b in blocks)
    path = tmp_path / "all.pcapng"
    path.write_bytes(data)
    fh = io.BytesIO(data[4:])
    assert list(walk_pcapng(fh, "x", data[:4], records=True, size=size)) == list(read_records(path))


def test_damaged_lengths_and_byte_order(tmp_path, blocks):
    data = b"".join(b for _k, b in blocks)
    first = len(blocks[0][1])
    cases = {
        "bad block length 13 (damaged file)": data[:first + 4] + struct.pack("<I", 13) + data[first + 8 :],
        "bad pcapng byte-order magic": data[:8] + b"\0\0\0\0" + data[12:],
        "bad section header length 20": data[:4] + struct.pack("<I", 20) + data[8:],
    }
    for reason, bad in cases.items():
        p = tmp_path / "bad.pcapng"
        p.write_bytes(bad)
        with pytest.raises(CaptureError) as exc:
            list(read_records(p))
        assert exc.value.reason == reason


def test_the_core_reads_pcapng_and_serial_captures_through_the_walker(tmp_path, blocks):
    path = tmp_path / "all.pcapng"
    path.write_bytes(b"".join(b for _k, b in blocks))
    want = [(r.number, r.ts_ns, r.linktype, r.data, r.flags, r.interface) for r in read_records(path)]
    assert list(capture_records(path)) == want
    serial = tmp_path / "serial.pcapng"
    with open(serial, "wb") as fh:
        w = SerialCaptureWriter(fh)
        for i in range(5):
            w.write(b"[:AB|N0|C76]\r\n"[i : i + 9], 1 + i % 2, 10**18 + i)
    got = list(capture_records(serial))
    assert [(n, ts, lt, fl) for n, ts, lt, _d, fl, _i in got] == [(i + 1, 10**18 + i, 147, 1 + i % 2) for i in range(5)]
