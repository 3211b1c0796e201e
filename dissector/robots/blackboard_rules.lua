-- Robot link module: the blackboard message rules, written once for blackboard.lua (over a
-- TCP/UDP/serial buffer) and serial.lua (over a serial direction's held bytes): which text is a
-- message and whether its checksum is good, where a message starts, and the binary answer a good
-- message expects.  Over a Lua string, positions 1-based.  Each is the twin of a Python function
-- (sharedlink.protocols.blackboard: parse_message, ack_ok, response_checksum/parse_response;
-- capture.serial_format.scan_blackboard's start), run side by side on the same bytes by
-- tests/dissector/test_lua_twins.py.
--
-- Loaded by blackboard.lua and serial.lua (robots/ beside them: each loads its own copy, so
-- either plugin loads alone or with the other, and they share no state); Wireshark also runs
-- every .lua file of a plugin folder's subfolders as a plugin of its own: this file then does
-- nothing.

local token = ...
if type(token) ~= "table" or token.robot_module ~= true then return end

local s_byte, s_sub, s_find, tonumber = string.byte, string.sub, string.find, tonumber
local B_COLON = 58 -- ":" a set message; ";" a request

local B = {}
-- the longest message: ":" or ";", 2 hex digits for each of 5 + 255 bytes, CR
B.MAX_TEXT = 1 + 2 * (5 + 255) + 1

function B.is_hex(b)
    return (b >= 48 and b <= 57) or (b >= 65 and b <= 70) or (b >= 97 and b <= 102)
end
local is_hex = B.is_hex

-- The message whose type character (":" or ";") is at a and whose CR is at cr: whether it is one
-- (an even number of hex digits, at least 5 bytes: a set 5 + its count, a request 5) and whether
-- its checksum is good (its bytes sum to 0 modulo 256).
function B.check(s, a, cr)
    local digits = cr - a - 1
    if digits % 2 == 1 then return false, false end
    for i = a + 1, cr - 1 do
        if not is_hex(s_byte(s, i)) then return false, false end
    end
    local nbytes = digits / 2
    if nbytes < 5 then return false, false end
    local sum, first = 0, nil
    for i = 0, nbytes - 1 do
        local v = tonumber(s_sub(s, a + 1 + 2 * i, a + 2 + 2 * i), 16)
        if i == 0 then first = v end
        sum = sum + v
    end
    local need = 5
    if s_byte(s, a) == B_COLON then need = 5 + first end
    if nbytes ~= need then return false, false end
    return true, sum % 256 == 0
end

-- Where the message whose CR is at cr starts: the last ":" or ";" in s[o .. cr - 1] (o holds
-- one; the text before it is outside any message).
function B.message_start(s, o, cr)
    local o2 = o
    local k = s_find(s, "[:;]", o + 1)
    while k and k < cr do
        o2 = k
        k = s_find(s, "[:;]", k + 1)
    end
    return o2
end

-- The answer a good message (type character at a, CR at cr) expects from the other side:
-- { kind "set" (1 byte: the message's checksum), "request" (count data bytes and a checksum
-- byte), len, checksum (the message's), sum (its count, address and node bytes, modulo 256: a
-- read response's checksum covers them) }; nil for a message that is not one or not good.
function B.expectation(s, a, cr)
    local valid, good = B.check(s, a, cr)
    if not valid or not good then return nil end
    local function byte_at(k) -- k-th decoded byte (1-based)
        return tonumber(s_sub(s, a + 1 + 2 * (k - 1), a + 2 * k), 16)
    end
    local count = byte_at(1)
    local e = {
        kind = "set", len = 1, checksum = byte_at((cr - a - 1) / 2),
        sum = (count + byte_at(2) + byte_at(3) + byte_at(4)) % 256,
    }
    if s_byte(s, a) ~= B_COLON then
        e.kind, e.len = "request", count + 1
    end
    return e
end

-- The checksum of bytes whose sum is sum: zero minus their 8-bit sum.
function B.checksum_of(sum)
    return (256 - sum % 256) % 256
end

-- A read response's checksum: that of its data s[at .. at + count - 1] and the request's bytes
-- (sum: expectation's).
function B.response_checksum(sum, s, at, count)
    for i = at, at + count - 1 do
        sum = sum + s_byte(s, i)
    end
    return B.checksum_of(sum)
end

-- Whether s holds, at position at, the whole answer e (expectation's) awaits, right: an ack equal
-- to the set's checksum; a read response whose checksum is right.
function B.answer_good(s, e, at)
    if #s - at + 1 < e.len then return false end
    if e.kind == "set" then return s_byte(s, at) == e.checksum end
    return B.response_checksum(e.sum, s, at, e.len - 1) == s_byte(s, at + e.len - 1)
end

return B
