"""Lua twins: code that must exist in two self-contained dissector files is marked at each copy
with its twin's name (``-- <twin: FILE NAME ...>``), and the copies agree; rules shared by two
dissectors through a module of dissector/robots/ run beside their Python twins.

* ``istr`` and ``u8`` in p2os.lua and blackboard.lua: the same text;
* the P2OS framing rules, written once in dissector/robots/p2os_rules.lua for p2os.lua and
  serial.lua (``R.checksum``, ``R.good_at``, ``R.resync_at``, ``R.from_client``): run inside the
  real tshark's Lua (5.2 on Wireshark 4.0, with its ``bit`` library) on the same random streams
  as their Python twins (``sharedlink.protocols.p2os``: ``checksum``, ``_good_at``,
  ``resync_at``, ``guess_from_client``; PAIRS) and must give the same answers at every header;
* the blackboard message rules, written once in dissector/robots/blackboard_rules.lua for
  blackboard.lua and serial.lua (``B.check``, ``B.message_start``, ``B.expectation``,
  ``B.answer_good``): the same against ``sharedlink.protocols.blackboard`` (BB_PAIRS) at every
  type character of generated text.
"""

from __future__ import annotations

import random
import re
import subprocess
from pathlib import Path

import pytest

import tshark_util as tu
from sharedlink.protocols import blackboard as bbc
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


def lua_lines(tmp_path: Path, script: str, n: int) -> list[str]:
    """The ``=`` lines ``script`` prints, run inside the real tshark while it loads the script
    (no capture needed: Wireshark's own Lua and ``bit``), checked for errors; ``n`` of them."""
    (tmp_path / "twins.lua").write_text(script)
    r = subprocess.run([*tu.TSHARK_CMD, "-G", "protocols", "-X", f"lua_script:{tmp_path / 'twins.lua'}"],
                       capture_output=True, text=True, env=tu._clean_env(), timeout=120)
    assert r.returncode == 0, r.stderr
    tu.check_stderr(r.stderr)
    got = [ln for ln in r.stdout.splitlines() if ln.split(" ")[0] == "="]
    assert len(got) == n, r.stdout[:2000]
    return got


def test_p2os_rules_agree_with_python(tmp_path):
    data = streams(random.Random(13), 1500)
    (tmp_path / "streams.txt").write_text("".join(s.hex() + "\n" for s in data))
    got = lua_lines(tmp_path, SCRIPT.replace("@RULES@", str(RULES)).replace("@STREAMS@", str(tmp_path / "streams.txt")),
                    len(data))
    for s, line in zip(data, got):
        assert line == python_line(s), s.hex()
    # the streams reach every answer of resync_at (a packet found, none, wait) and both of good_at
    parts = [part.split(":") for line in got for part in line.split()[1:]]
    assert {(p[2], p[3]) for p in parts} >= {("-1", "-1"), ("-1", "-2")}, parts
    assert any(p[2] not in ("-1", "-2") for p in parts) and {p[1] for p in parts} == {"0", "1"}
    assert {p[5] for p in parts if len(p) == 6} == {"0", "1"}


#: how each plugin loads a module of dissector/robots/ (serial.lua loads two, by one function)
LOADS = {
    "p2os.lua": ['pcall(loadfile, HERE .. "robots/" .. name .. ".lua")', 'robot_chunk("p2os_rules")'],
    "blackboard.lua": ['pcall(loadfile, HERE .. "robots/" .. name .. ".lua")', 'robot_chunk("blackboard_rules")'],
    "serial.lua": ['pcall(loadfile, HERE .. "robots/" .. name .. ".lua")', 'rules("p2os_rules")',
                   'rules("blackboard_rules")'],
}


def plugin_text(name: str) -> str:
    """A plugin's text with its dissection module's (robots/NAME_dissect.lua, run on its first packet)."""
    module = DISSECTORS / "robots" / name.replace(".lua", "_dissect.lua")
    return (DISSECTORS / name).read_text() + (module.read_text() if module.exists() else "")


def test_p2os_and_serial_load_the_rules_module():
    """Both plugins take the framing rules from the one module (no copy of their own)."""
    for name in ("p2os.lua", "serial.lua"):
        text = plugin_text(name)
        assert all(s in text for s in LOADS[name]) and "p2os_rules" in "".join(LOADS[name]), name
        assert not re.search(r"local function \w*(checksum|resync_at|good_at|from_client|guess_client)\(", text), name


# -- blackboard: dissector/robots/blackboard_rules.lua (blackboard.lua and serial.lua) ------------

#: the Lua module's rules and their Python twins (``check``: parse_message raising or not, and
#: its ``ok``; ``expectation``: the answer a good message awaits; ``answer_good``: ack_ok and
#: parse_response's ``ok``)
BB_PAIRS = {
    "check": bbc.parse_message,
    "message_start": bbc.message_start,
    "answer_good": (bbc.ack_ok, bbc.parse_response),
    "response_checksum": bbc.response_checksum,
}
BB_RULES = DISSECTORS / "robots" / "blackboard_rules.lua"

# For each line "STREAM ANSWER" (hex) of @LINES@: "=" then, for each ":" or ";" at a (0-based)
# with a CR after it, "a:valid:good:start" and, for a good message, ":kind:len:checksum:sum:answer
# good" (the answer tried: ANSWER).
BB_SCRIPT = """
local B = assert(loadfile("@RULES@"))({ robot_module = true })
local function unhex(h) return (h:gsub("%x%x", function(x) return string.char(tonumber(x, 16)) end)) end
for line in io.lines("@LINES@") do
    local sh, ah = line:match("^(%x*) (%x*)$")
    local s, ans = unhex(sh), unhex(ah)
    local out = { "=" }
    local a = s:find("[:;]")
    while a do
        local cr = s:find("\\r", a + 1, true)
        if cr then
            local v, g = B.check(s, a, cr)
            local part = (a - 1) .. ":" .. (v and 1 or 0) .. ":" .. (g and 1 or 0) .. ":" .. (B.message_start(s, a, cr) - 1)
            local e = B.expectation(s, a, cr)
            if e then
                part = part .. ":" .. e.kind .. ":" .. e.len .. ":" .. e.checksum .. ":" .. e.sum .. ":"
                    .. (B.answer_good(ans, e, 1) and 1 or 0)
            end
            out[#out + 1] = part
        end
        a = s:find("[:;]", a + 1)
    end
    print(table.concat(out, " "))
end
"""


def bb_python_line(s: bytes, ans: bytes) -> str:
    out = ["="]
    for a in (i for i, c in enumerate(s) if c in b":;"):
        cr = s.find(b"\r", a + 1)
        if cr < 0:
            continue
        try:
            msg = BB_PAIRS["check"](s[a : cr + 1])
            valid, good = 1, int(bool(msg.ok))
        except bbc.BlackboardError:
            msg, valid, good = None, 0, 0
        part = f"{a}:{valid}:{good}:{BB_PAIRS['message_start'](s, a, cr)}"
        if msg is not None and good:
            ack_ok, parse_response = BB_PAIRS["answer_good"]
            if isinstance(msg, bbc.SetMessage):
                kind, want, right = "set", 1, len(ans) >= 1 and ack_ok(msg, ans[:1])
            else:
                want = msg.count + 1
                kind, right = "request", len(ans) >= want and parse_response(msg, ans[:want]).ok
                assert len(ans) < want or ans[want - 1] != BB_PAIRS["response_checksum"](msg, ans[: want - 1]) or right
            part += f":{kind}:{want}:{msg.crc}:{sum(msg.body[:4]) % 256}:{int(right)}"
        out.append(part)
    return " ".join(out)


def bb_lines(rng: random.Random, n: int) -> list[tuple[bytes, bytes]]:
    """Streams of blackboard text that reach every branch of the rules (good sets and requests,
    bad checksums, lower-case hex, odd and non-hex digits, wrong counts, short messages, a type
    character cut short by another, an LF after the CR, noise) and an answer to try on each
    (right or wrong acks, right, bad and truncated read responses)."""
    def message() -> tuple[bytes, bytes]:
        addr, node = rng.randrange(65536), rng.randrange(256)
        if rng.random() < 0.5:
            m = bbc.SetMessage(addr, node, rng.randbytes(rng.choice([0, 1, 3, 8])))
            text, right = m.encode(), m.ack
        else:
            r = bbc.RequestMessage(addr, node, rng.choice([0, 1, 4, 9]))
            text, right = r.encode(), r.response(rng.randbytes(r.count))
        kind = rng.randrange(12)
        if kind == 0:
            text = text[:-2] + (b"0" if text[-2:-1] != b"0" else b"1") + b"\r"  # bad checksum
        elif kind == 1:
            text = text.lower()
        elif kind == 2:
            text = text[:-2] + b"\r"  # odd digits
        elif kind == 3:
            i = rng.randrange(1, len(text) - 1)
            text = text[:i] + rng.choice([b"G", b"g", b"@", b"/", b" ", b":", b";"]) + text[i + 1 :]
        elif kind == 4:
            text = text[:1] + b"%02X" % rng.randrange(256) + text[3:]  # another count
        elif kind == 5:
            text = text[:1] + text[1:9] + b"\r"  # 4 bytes
        elif kind == 6:
            text = text + b"\n"
        elif kind == 7:
            text = rng.choice([b":0101", b";49", b"noise", b":"]) + text
        a = rng.randrange(6)
        ans = (right if a < 2 else right[:-1] + bytes([right[-1] ^ 1]) if a < 4 else right[: rng.randrange(len(right))]
               if a == 4 else rng.randbytes(rng.randrange(4)))
        return text, ans

    out = [(b"", b""), (b":\r", b""), (b";\r", b"\x00"), (b":0000000000\r", b"\x00")]
    while len(out) < n:
        parts = [message() for _ in range(rng.randrange(1, 4))]
        s = b"".join(p[0] for p in parts)
        out.append((s[: rng.randrange(len(s) + 1)] if rng.random() < 0.2 else s, parts[0][1]))
    return out


def test_blackboard_rules_agree_with_python(tmp_path):
    data = bb_lines(random.Random(17), 1500)
    (tmp_path / "lines.txt").write_text("".join(f"{s.hex()} {a.hex()}\n" for s, a in data))
    got = lua_lines(tmp_path, BB_SCRIPT.replace("@RULES@", str(BB_RULES)).replace("@LINES@", str(tmp_path / "lines.txt")),
                    len(data))
    for (s, a), line in zip(data, got):
        assert line == bb_python_line(s, a), (s, a.hex())
    # the lines reach every answer: invalid, valid with a bad checksum, good; a start moved by a
    # later type character; sets and requests answered right and wrong
    parts = [p.split(":") for line in got for p in line.split()[1:]]
    assert {(p[1], p[2]) for p in parts} == {("0", "0"), ("1", "0"), ("1", "1")}
    assert any(p[3] != p[0] for p in parts)
    assert {(p[4], p[8]) for p in parts if len(p) == 9} == {(k, g) for k in ("set", "request") for g in "01"}


def test_blackboard_and_serial_load_the_rules_module():
    """Both plugins take the message rules from the one module (no copy of their own)."""
    for name in ("blackboard.lua", "serial.lua"):
        text = plugin_text(name)
        assert all(s in text for s in LOADS[name]) and "blackboard_rules" in "".join(LOADS[name]), name
        assert not re.search(r"local function (bb_check|last_start|bb_expectation|bb_answer_good|is_hex)\(", text), name
        assert "1 + 2 * (5 + 255) + 1" not in text and "(256 - sum % 256) % 256" not in text, name


@pytest.mark.parametrize(("name", "module"), [("p2os.lua", "p2os_rules"), ("blackboard.lua", "blackboard_rules"),
                                              ("serial.lua", "p2os_rules")])
def test_a_plugin_copied_without_its_module_says_what_it_needs(tmp_path, name, module):
    """Loaded from a folder with no robots/ (a plugin copied alone), the plugin names the module
    it needs (Wireshark's loadfile raises where Lua's returns nil: the plugins catch it)."""
    (tmp_path / name).write_text((DISSECTORS / name).read_text())
    r = subprocess.run([*tu.TSHARK_CMD, "-G", "plugins", "-X", f"lua_script:{tmp_path / name}"],
                       capture_output=True, text=True, env=tu._clean_env(), timeout=120)
    assert f"{name} needs robots/{module}.lua beside it" in r.stderr, r.stderr
