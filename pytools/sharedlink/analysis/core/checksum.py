"""The one checksum rule of the core's fast tiers (the codec's :func:`~sharedlink.protocols.codec.checksum`
said once for frames taken whole).

A SharedLink frame ``[:`` ... ``|C`` *XX* ``]`` CR LF is right when the byte sum of ``:`` through
``C`` is *XX* modulo 256. With ``s`` the byte sum of the whole frame, that is ``1 + s - CKSUB[XX]``
= 0 modulo 256, :data:`CKSUB` holding for the two digits the 1, ``[`` (91), the digits, ``]`` CR
LF (116) and the value. ``zlib.adler32``'s low half is ``1 + s`` (modulo 65521) for a frame of up
to 256 bytes: the sum at C speed.
"""

from __future__ import annotations

from collections.abc import Callable
from zlib import adler32

#: checksum digits (str and bytes keys) -> what to take from (1 + the byte sum of the whole frame)
#: so that the rest is 0 mod 256 when the checksum is right
CKSUB: dict[str | bytes, int] = {}
for _i in range(256):
    _d = f"{_i:02X}"
    CKSUB[_d] = CKSUB[_d.encode()] = 1 + 91 + ord(_d[0]) + ord(_d[1]) + 116 + _i
#: frames of up to this many bytes are summed by ``adler32`` (its low half cannot wrap)
ADLER_MAX = 256


def frame_ok(raw: bytes, digits: str | bytes, _adler: Callable = adler32, _sub: dict = CKSUB) -> bool:
    """Whether ``raw`` (a whole frame, ``[:`` to CR LF, ``digits`` its two upper-case hex checksum
    digits) has a right checksum. (``_adler``, ``_sub``: bound once, no global look-up a frame.)"""
    s = (_adler(raw) & 0xFFFF) if len(raw) <= 256 else sum(raw) + 1  # (256: ADLER_MAX)
    return not (s - _sub[digits]) & 0xFF


def low_sum_table() -> bytearray:
    """The checksum digits as a little-endian 16-bit number -> the low byte of 1 + the byte sum
    of a frame whose checksum they are (0: not two upper-case hex digits): :data:`CKSUB` for the
    block tier's C-level passes."""
    out = bytearray(65536)
    for i in range(256):
        d = b"%02X" % i
        out[d[0] | d[1] << 8] = CKSUB[d] & 255
    return out
