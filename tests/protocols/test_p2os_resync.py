"""p2os.resync_at, the rule for a header cut off before a packet (the same in serial.lua and
p2os.lua: tests/dissector/test_p2os_cut_header.py runs those)."""

from __future__ import annotations

from sharedlink.protocols import p2os


def _pk(v: int) -> bytes:
    return p2os.encode_message(p2os.Command(p2os.COMMAND_NUMBERS["SETV"], p2os.ARG_POSITIVE, v))


def test_a_cut_header_ends_at_the_packet_it_claims() -> None:
    buf = b"\xfa\xfb" + _pk(1) + _pk(2)
    assert p2os.resync_at(buf, 0) == 2
    assert [c.data for c in p2os.iter_chunks(buf)] == [b"\xfa\xfb", _pk(1), _pk(2)]


def test_a_good_packet_is_never_cut() -> None:
    buf = _pk(1) + _pk(2)
    assert p2os.resync_at(buf, 0) == -1


def test_more_bytes_decide_when_the_packet_inside_is_not_all_there() -> None:
    buf = b"\xfa\xfb" + _pk(1)[:5]
    assert p2os.resync_at(buf, 0, final=False) == -2
    assert p2os.resync_at(buf, 0) == -1  # final: nothing good inside, the cut header is a truncated packet
    chunks = list(p2os.iter_chunks(buf, final=False))
    assert [(c.offset, c.packet, c.reason.split(":")[0]) for c in chunks] == [(0, None, "truncated")]


def test_a_bad_packet_with_a_good_one_inside_gives_way() -> None:
    inner = _pk(7)
    bad = bytearray(p2os.encode_message(p2os.Command(p2os.COMMAND_NUMBERS["SAY"], p2os.ARG_STRING, inner)))
    bad[-1] ^= 0xFF  # its own checksum wrong
    buf = bytes(bad)
    k = buf.index(inner)
    assert p2os.resync_at(buf, 0) == k
    assert [c.data for c in p2os.iter_chunks(buf) if c.packet] == [inner]


SYNC0 = bytes.fromhex("FAFB03000000")


def test_a_span_ending_on_the_next_headers_fa_gives_way() -> None:
    """The claimed span (9 bytes) ends on the FA of a good packet's header, its FB just after:
    the cut-off bytes are junk and the packet is kept (docs/fields-p2os-blackboard.md,
    "Resynchronisation"); it was one bad packet ``...00 fa`` and noise ``fb 03 00 00 00``."""
    cut = bytes.fromhex("FAFB06003B000000")
    buf = cut + SYNC0
    assert p2os.resync_at(buf, 0) == len(cut)
    assert [(c.data, c.packet is not None) for c in p2os.iter_chunks(buf)] == [(cut, False), (SYNC0, True)]


def test_more_bytes_decide_when_the_span_ends_on_the_last_fa() -> None:
    """Not final, the span's last byte an FA that is the last byte so far: wait; final, or the
    byte after it no FB: the packet as claimed (its checksum bad)."""
    buf = bytes.fromhex("FAFB06003B000000FA")
    assert p2os.resync_at(buf, 0, final=False) == -2
    assert p2os.resync_at(buf, 0) == -1
    assert p2os.resync_at(buf + b"\x00", 0, final=False) == -1
    bad_next = buf + bytes.fromhex("FB03000001")  # the header after it starts no good packet
    assert [(c.data.hex(), c.packet is not None) for c in p2os.iter_chunks(bad_next)] == [
        (buf.hex(), True), ("fb03000001", False)]


def test_a_good_packet_ending_in_fa_is_kept() -> None:
    good = p2os.build_packet(bytes.fromhex("063B00BF"))
    assert good[-1] == 0xFA and p2os.parse_packet(good).ok
    assert p2os.resync_at(good + SYNC0[1:], 0) == -1
    assert p2os.resync_at(good, 0, final=False) == -1  # a good packet does not wait
