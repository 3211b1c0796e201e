"""Lua twins: code that must exist in two self-contained dissector files is marked at each copy
with its twin's name (``-- <twin: FILE NAME ...>``), and the copies agree; rules shared by two
dissectors through a module of dissector/robots/ run beside their Python twins.

* ``istr`` and ``u8`` in p2os.lua and blackboard.lua: the same text;
* the P2OS framing rules, written once in dissector/robots/p2os_rules.lua for p2os.lua and
  serial.lua (``R.checksum``, ``R.good_at``, ``R.resync_at``, ``R.from_client``): run inside the
  real tshark's Lua (5.2 on Wireshark 4.0, with its ``bit`` library) on the same random streams
  as their Python twins (``sharedlink.protocols.p2os``: ``checksum``, ``_good_at``,
  ``resync_at``, ``guess_from_client``; PAIRS) and must give the same answers at every header.
"""

from __future__ import annotations

import random
import re
import subprocess
from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.protocols import p2os

DISSECTORS = Path(__file__).resolve().parents[2] / "dissector"
TWINS = [  # (file, function, twin file)
    ("p2os.lua", "istr", "blackboard.lua"),
    ("blackboard.lua", "istr", "p2os.lua"),
    ("p2os.lua", "u8", "blackboard.lua"),
    ("blackboard.lua", "u8", "p2os.lua"),
]


def function_source(file: str, name: str) -> tuple[str, str]:
    """(the comment block right above it, the text of ``local function NAME`` through its ``end``)."""
    text = (DISSECTORS / file).read_text()
    m = re.search(rf"((?:^--[^\n]*\n)*)(^local function {name}\(.*?^end\n)", text, re.M | re.S)
    assert m, f"{file}: no local function {name}"
    return m.group(1), m.group(2)


@pytest.mark.parametrize(("file", "name", "twin"), TWINS)
def test_each_copy_names_its_twin(file, name, twin):
    comment, _ = function_source(file, name)
    assert re.search(rf"<twin: {re.escape(twin)} {name}\b", comment), (file, name, comment)
    # and the file's header says where its twins are tested
    assert "test_lua_twins.py" in (DISSECTORS / file).read_text()[:4000], file


@pytest.mark.parametrize("name", ["istr", "u8"])
def test_shared_helpers_are_the_same_text(name):
    assert function_source("p2os.lua", name)[1] == function_source("blackboard.lua", name)[1]


# The Lua module's rules and their Python twins: a change to either side's rule makes the two
# answer differently on the streams below (test_p2os_rules_agree_with_python).
PAIRS = {
    "checksum": p2os.checksum,
    "good_at": p2os._good_at,
    "resync_at": p2os.resync_at,
    "from_client": p2os.guess_from_client,
}
RULES = DISSECTORS / "robots" / "p2os_rules.lua"

# Loads the module as p2os.lua and serial.lua do; for each stream (hex, one a line in STREAMS),
# one line: "=" then, for each FA FB at h (0-based), "h:good_at:resync_at(final):resync_at(not
# final)" (-1 for nil, -2 for "wait", else 0-based) and, when the count's bytes are all there,
# ":checksum:from_client" of the payload.
SCRIPT = """
local R = assert(loadfile("@RULES@"))({ robot_module = true })
local function at(k) if k == nil then return -1 elseif k == "wait" then return -2 end return k - 1 end
for hex in io.lines("@STREAMS@") do
    local s = (hex:gsub("%x%x", function(h) return string.char(tonumber(h, 16)) end))
    local out = { "=" }
    local h = string.find(s, "\\250\\251", 1, true)
    while h do
        out[#out + 1] = (h - 1) .. ":" .. (R.good_at(s, h) and 1 or 0) .. ":" .. at(R.resync_at(s, h, true))
            .. ":" .. at(R.resync_at(s, h, false))
        local count = s:byte(h + 2)
        if count and count >= 2 and h + 2 + count <= #s then
            out[#out] = out[#out] .. ":" .. R.checksum(s, h + 3, count - 2) .. ":"
                .. (R.from_client(s, h + 3, count - 2) and 1 or 0)
        end
        h = string.find(s, "\\250\\251", h + 1, true)
    end
    print(table.concat(out, " "))
end
"""


def python_line(buf: bytes) -> str:
    out = ["="]
    h = buf.find(p2os.HEADER)
    while h >= 0:
        final, more = (PAIRS["resync_at"](buf, h, final) for final in (True, False))
        out.append(f"{h}:{int(PAIRS['good_at'](buf, h))}:{final}:{more}")
        if h + 2 < len(buf) and buf[h + 2] >= 2 and h + 3 + buf[h + 2] <= len(buf):
            payload = buf[h + 3 : h + 1 + buf[h + 2]]
            out[-1] += f":{PAIRS['checksum'](payload)}:{int(PAIRS['from_client'](payload))}"
        h = buf.find(p2os.HEADER, h + 1)
    return " ".join(out)


def streams(rng: random.Random, n: int) -> list[bytes]:
    """P2OS streams that reach every branch of the rules: good packets (server types, SYNC2
    echoes, commands with arguments), packets cut at the front or back, bad checksums, counts
    below 2, lone FAs, random bytes; a stream may end anywhere."""
    def packet() -> bytes:
        first = rng.choice([0x02, 0x20, 0x32, 0x33, 0x90, 0x8D, 0xE0, 0xF0, 0x80, 0x01, 0x0B, rng.randrange(256)])
        payload = bytes([first]) + rng.choice([b"", bytes([rng.choice([0x3B, 0x1B, 0x2B, 0x41])])]) + rng.randbytes(
            rng.choice([0, 1, 2, 5, 30]))
        return p2os.build_packet(payload)

    def piece() -> bytes:
        pk = packet()
        kind = rng.randrange(8)
        if kind == 0:
            return pk[: rng.randrange(1, len(pk))]  # cut at the back
        if kind == 1:
            return pk[:2] + pk[rng.randrange(3, len(pk)):]  # a header cut off before the rest
        if kind == 2:
            return pk[:-1] + bytes([pk[-1] ^ 1])  # bad checksum
        if kind == 3:
            return rng.choice([b"\xfa", b"\xfa\xfb", b"\xfa\xfb\x01", b"\xfa\xfb\xfa"]) + rng.randbytes(rng.randrange(3))
        if kind == 4:
            return rng.randbytes(rng.randrange(1, 6))
        return pk

    out = [b"", b"\xfa", b"\xfa\xfb", b"\xfa\xfb\x02\x00\x00", b"\xff\xff\xff"]
    while len(out) < n:
        s = b"".join(piece() for _ in range(rng.randrange(1, 7)))
        out.append(s[: rng.randrange(len(s) + 1)] if rng.random() < 0.3 else s)
    return out


def test_p2os_rules_agree_with_python(tmp_path):
    data = streams(random.Random(13), 1500)
    (tmp_path / "streams.txt").write_text("".join(s.hex() + "\n" for s in data))
    script = SCRIPT.replace("@RULES@", str(RULES)).replace("@STREAMS@", str(tmp_path / "streams.txt"))
    (tmp_path / "twins.lua").write_text(script)
    # the script runs while tshark loads it (no capture needed): Wireshark's own Lua and bit
    r = subprocess.run([*tu.TSHARK_CMD, "-G", "protocols", "-X", f"lua_script:{tmp_path / 'twins.lua'}"],
                       capture_output=True, text=True, env=tu._clean_env(), timeout=120)
    assert r.returncode == 0, r.stderr
    tu.check_stderr(r.stderr)
    got = [ln for ln in r.stdout.splitlines() if ln.split(" ")[0] == "="]
    assert len(got) == len(data), r.stdout[:2000]
    for s, line in zip(data, got):
        assert line == python_line(s), s.hex()
    # the streams reach every answer of resync_at (a packet found, none, wait) and both of good_at
    parts = [part.split(":") for line in got for part in line.split()[1:]]
    assert {(p[2], p[3]) for p in parts} >= {("-1", "-1"), ("-1", "-2")}, parts
    assert any(p[2] not in ("-1", "-2") for p in parts) and {p[1] for p in parts} == {"0", "1"}
    assert {p[5] for p in parts if len(p) == 6} == {"0", "1"}


def test_p2os_and_serial_load_the_rules_module():
    """Both plugins take the framing rules from the one module (no copy of their own)."""
    for name in ("p2os.lua", "serial.lua"):
        text = (DISSECTORS / name).read_text()
        assert 'loadfile(here .. "robots/p2os_rules.lua")' in text, name
        assert not re.search(r"local function \w*(checksum|resync_at|good_at|from_client|guess_client)\(", text), name
