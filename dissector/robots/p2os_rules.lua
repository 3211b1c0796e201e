-- Robot link module: the P2OS framing rules, written once for p2os.lua (over a TCP/UDP/serial
-- buffer) and serial.lua (over a serial direction's held bytes): the checksum, "a whole good
-- packet starts here", the resynchronisation after a cut-off header and the direction from the
-- content.  Over a Lua string, positions 1-based.  Each is the twin of a Python function
-- (sharedlink.protocols.p2os: checksum, _good_at, resync_at, guess_from_client), run side by side
-- on the same bytes by tests/dissector/test_lua_twins.py.
--
-- Loaded by p2os.lua and serial.lua (robots/ beside them: each loads its own copy, so either
-- plugin loads alone or with the other, and they share no state); Wireshark also runs every
-- .lua file of a plugin folder's subfolders as a plugin of its own: this file then does nothing.

local token = ...
if type(token) ~= "table" or token.robot_module ~= true then return end

local s_byte, s_find = string.byte, string.find
local bxor = bit.bxor

local R = {}
R.HEADER = "\250\251"
-- the robot ignores a client command with a count over 200 (the P2OS manual); a server packet
-- may count up to 255 (ARIA reads them)
R.MAX_COUNT = 200

-- the payload s[a .. a + len - 1] as big-endian 16-bit words added (16 bits kept); an odd last
-- byte XORed into the low byte
function R.checksum(s, a, len)
    local c, i, stop = 0, a, a + len - 1
    while i < stop do
        c = (c + s_byte(s, i) * 256 + s_byte(s, i + 1)) % 65536
        i = i + 2
    end
    if i == stop then c = bxor(c, s_byte(s, i)) end
    return c
end

-- whether a whole packet with a good checksum starts at h (an FA FB there)
local function good_at(s, h)
    local n = #s
    if h + 2 > n then return false end
    local count = s_byte(s, h + 2)
    if count < 2 or h + 2 + count > n then return false end
    local plen = count - 2
    return R.checksum(s, h + 3, plen) == s_byte(s, h + 3 + plen) * 256 + s_byte(s, h + 4 + plen)
end
R.good_at = good_at

-- A header cut off before a packet (its FA read as a count of 250 would swallow the packets
-- after it; a span ending on the next header's FA would swallow that packet): when the packet at
-- h is not whole and good, the first FA FB starting inside the span its count claims (its FA in
-- the span, its FB maybe just after it) that starts a whole good packet, or nil; "wait" (not
-- final: more bytes may come) when an FA FB before any such one starts a packet not all there
-- yet, or the span ends on an FA that is the last byte so far (docs/fields-p2os-blackboard.md,
-- "Resynchronisation").
function R.resync_at(s, h, final)
    local n = #s
    if h + 2 > n then return nil end
    local last = h + 2 + s_byte(s, h + 2) -- the claimed span's last byte
    local k = s_find(s, "\250\251", h + 1, true)
    if k and k > last then k = nil end
    local edge = not final and last == n and s_byte(s, n) == 0xFA -- its FB yet to come
    -- (no FA FB inside: nothing to resynchronise on, the checksum not needed)
    if (not k and not edge) or good_at(s, h) then return nil end
    while k and k <= last do
        if not final and (k + 2 > n or k + 2 + s_byte(s, k + 2) > n) then return "wait" end
        if good_at(s, k) then return k end
        k = s_find(s, "\250\251", k + 1, true)
    end
    if edge then return "wait" end
    return nil
end

-- the robot's packet types (a payload starting with one is a server packet)
local SERVER = { [0x20] = true, [0x32] = true, [0x33] = true, [0x80] = true, [0x8D] = true, [0x90] = true,
    [0xE0] = true, [0xF0] = true }
-- a command's argument types (0x3B positive int, 0x1B negative int, 0x2B string)
local ARG = { [0x3B] = true, [0x1B] = true, [0x2B] = true }

-- whether the payload s[off .. off + plen - 1] is a client command, from its content alone: the
-- robot's packet types and SYNC2 echoes carrying strings are the server's, the rest commands
function R.from_client(s, off, plen)
    if plen < 1 then return true end
    local t = s_byte(s, off)
    if SERVER[t] then return false end
    return not (t == 2 and plen > 1 and not ARG[s_byte(s, off + 1)])
end

return R
