"""Lua twins: code that must exist in two self-contained dissector files is marked at each copy
with its twin's name (``-- <twin: FILE NAME ...>``), and the copies agree.

* ``p2os_checksum`` in p2os.lua (on a tvb) and serial.lua (on a Lua string): both run inside the
  real tshark's Lua (5.2 on Wireshark 4.0, with its ``bit`` library) on the same random payloads
  and must give the Python codec's checksum (``sharedlink.protocols.p2os.checksum``);
* ``istr`` and ``u8`` in p2os.lua and blackboard.lua: the same text.
"""

from __future__ import annotations

import random
import re
import subprocess
from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.protocols.p2os import checksum as py_checksum

DISSECTORS = Path(__file__).resolve().parents[2] / "dissector"
TWINS = [  # (file, function, twin file)
    ("p2os.lua", "p2os_checksum", "serial.lua"),
    ("serial.lua", "p2os_checksum", "p2os.lua"),
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


# Runs both checksums on the payloads given as hex lines in PAYLOADS; prints one line per
# payload: "<p2os.lua value> <serial.lua value>".
SCRIPT = """
local s_byte = string.byte
local tvb_from = function(s)
    return { range = function(_, off, len)
        return { uint = function() return s:byte(off + 1) end }
    end }
end
local function u8(tvb, off)
    return tvb:range(off, 1):uint()
end
@P2OS@
local p2os_tvb_checksum = p2os_checksum
@XOR8@
@SERIAL@
for hex in io.lines("@PAYLOADS@") do
    local s = (hex:gsub("%x%x", function(h) return string.char(tonumber(h, 16)) end))
    print(p2os_tvb_checksum(tvb_from(s), 0, #s) .. " " .. p2os_checksum("x" .. s, 2, #s))
end
"""


def test_p2os_checksums_agree_with_each_other_and_python(tmp_path):
    rng = random.Random(13)
    payloads = [b"", b"\x01", b"\xff\xff\xff"] + [rng.randbytes(rng.randrange(0, 201)) for _ in range(300)]
    (tmp_path / "payloads.txt").write_text("".join(p.hex() + "\n" for p in payloads))
    script = (SCRIPT.replace("@P2OS@", function_source("p2os.lua", "p2os_checksum")[1])
              .replace("@XOR8@", function_source("serial.lua", "xor8")[1])
              .replace("@SERIAL@", function_source("serial.lua", "p2os_checksum")[1])
              .replace("@PAYLOADS@", str(tmp_path / "payloads.txt")))
    (tmp_path / "twins.lua").write_text(script)
    # the script runs while tshark loads it (no capture needed): Wireshark's own Lua and bit
    r = subprocess.run([*tu.TSHARK_CMD, "-G", "protocols", "-X", f"lua_script:{tmp_path / 'twins.lua'}"],
                       capture_output=True, text=True, env=tu._clean_env(), timeout=120)
    assert r.returncode == 0, r.stderr
    tu.check_stderr(r.stderr)
    got = [tuple(int(x) for x in ln.split()) for ln in r.stdout.splitlines() if re.fullmatch(r"\d+ \d+", ln)]
    assert len(got) == len(payloads), r.stdout[:2000]
    for payload, (in_p2os, in_serial) in zip(payloads, got):
        assert in_p2os == in_serial == py_checksum(payload), payload.hex()
