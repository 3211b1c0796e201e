-- SharedLink dissector module: util, the constants and small pure helpers every other module uses
-- (byte values, sums, number parsing).  Loaded by sharedlink.lua (load_module); Wireshark also runs
-- every .lua file of a plugin folder's subfolders as a plugin of its own: this file then does nothing.

local token = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local s_byte, s_sub, s_find, s_format, s_gsub = string.byte, string.sub, string.find, string.format, string.gsub
local floor = math.floor
local t_concat = table.concat

local U = {}
U.ARROW = "\226\134\146"     -- U+2192
U.ELLIPSIS = "\226\128\166"  -- U+2026
U.INFO_MAX = 120
U.CTRL = "[\0-\31\127]"   -- control characters (not to be shown in the Info column)
U.SYNC_SLACK = 0.5 -- seconds added to the sync interval before sync.late fires
-- " (+n carried)", made once for n up to 64 (a delta's Info tail)
U.CARRIED_TAIL = {}
for k = 1, 64 do U.CARRIED_TAIL[k] = " (+" .. k .. " carried)" end

-- byte values: brackets and separators, line ends, the node letters' range, the field letters
U.B_LBRACK, U.B_RBRACK, U.B_PIPE, U.B_COLON = 91, 93, 124, 58
U.B_CR, U.B_LF = 13, 10
U.B_A, U.B_P = 65, 80
U.L_N, U.L_T, U.L_Q, U.L_R, U.L_D, U.L_C, U.L_L, U.L_E, U.L_M, U.L_P, U.L_G = 78, 84, 81, 82, 68, 67, 76, 69, 77, 80, 71

-- SUM_OF[n](b1, ..., bn): the sum of its n arguments (n = 0 to 40: n - 1 adds), each made on its
-- first use: a capture sums values of a few lengths (the bench's beacon capture 9, compressed 16),
-- and all 41 made at load held 30 KB of live heap, which the collector walks (docs/perf-log.md,
-- 7 December 2026).
-- Speed trick (measured): bytes are summed as s_byte returns them, up to 40 a call.
local SUM_OF = setmetatable({}, { __index = function(t, n)
    local args = {}
    for k = 1, n do args[k] = "b" .. k end
    local f = assert(load("return function(" .. t_concat(args, ", ") .. ") return " ..
        (n > 0 and t_concat(args, " + ") or "0") .. " end", "=SUM_OF", "t", {}))()
    rawset(t, n, f)
    return f
end })
U.SUM_OF = SUM_OF
local SUM_40 = SUM_OF[40]

-- Sum of the bytes s[i..j], not reduced.
local function byte_sum(s, i, j)
    local sum = 0
    while i + 39 <= j do
        sum = sum + SUM_40(s_byte(s, i, i + 39))
        i = i + 40
    end
    if i <= j then sum = sum + SUM_OF[j - i + 1](s_byte(s, i, j)) end
    return sum
end
U.byte_sum = byte_sum

-- Sum of the bytes of a value.  Speed trick (measured): the fast paths check a checksum
-- as the shape's fixed sum plus the sums of the values, one s_byte call per value.
local function str_sum(v)
    local n = #v
    if n > 40 then return byte_sum(v, 1, n) end
    return SUM_OF[n](s_byte(v, 1, n))
end
U.str_sum = str_sum

-- Checksum texts of two upper-case hex digits (the form without sharedlink.checksum.format) ->
-- their value: the common case without a pattern match, one table (a table of the lower-case
-- forms too cost 47 KB of live heap, which the collector walks: time, not instructions)
local UHEXV = {}
U.UHEXV = UHEXV
do
    local digits = "0123456789ABCDEF"
    for i = 1, 16 do
        for j = 1, 16 do
            local t = s_sub(digits, i, i) .. s_sub(digits, j, j)
            UHEXV[t] = tonumber(t, 16)
        end
    end
end

-- The value of a checksum text (nil: not 1 to 8 hex digits).
function U.checksum_value(ctext)
    local v = UHEXV[ctext]
    if v then return v end
    if #ctext >= 1 and #ctext <= 8 and not s_find(ctext, "[^0-9A-Fa-f]") then return tonumber(ctext, 16) end
    return nil
end

local INT64_MAX = "9223372036854775807"

-- Parse a decimal long; returns an Int64, or nil if not an integer / out of range.
function U.parse_long(text)
    local sign, digits = text:match("^%s*([+-]?)(%d+)%s*$")
    if not digits then return nil end
    digits = digits:match("^0*(%d.-)$") or digits
    if #digits <= 15 then
        local v = tonumber(digits)
        if sign == "-" then v = -v end
        return Int64.new(v)
    end
    if #digits > 19 or (#digits == 19 and digits > INT64_MAX) then return nil end
    local head, tail = s_sub(digits, 1, #digits - 9), s_sub(digits, #digits - 8)
    local v = Int64(tonumber(head)) * 1000000000 + tonumber(tail)
    if sign == "-" then v = -v end
    return v
end

-- An ordinal as a non-negative integer (0 when not a number).
function U.to_ordinal(text)
    local o = tonumber(text)
    if not o or o ~= o or o < 0 or o >= 2147483647 then return 0 end
    return floor(o)
end

function U.nstime_of(d)
    if d < 0 then d = 0 end
    local secs = floor(d)
    local ns = floor((d - secs) * 1e9 + 0.5)
    if ns >= 1000000000 then ns = 999999999 end
    return NSTime.new(secs, ns)
end

-- byte -> its letter as the tree and Info show it (a control byte as \xNN; no byte: "?"), made
-- on first use (a capture uses a few: less live heap, which the collector walks)
local LETTER = setmetatable({}, { __index = function(t, b)
    if b == nil then return "?" end   -- (cut short)
    local l = (b >= 32 and b <= 126) and string.char(b) or s_format("\\x%02x", b)
    rawset(t, b, l)
    return l
end })
U.LETTER = LETTER

-- A positional slot's name: its list's (list[index + 1]), else "#index" (docs/fields-sharedlink.md,
-- "Names from an a-priori list").  The one place a slot is named.
function U.slot_name(list, index)
    return list[index + 1] or ("#" .. index)
end

-- A T field's text as its type number (0-255), nil when it is not one.  Speed trick
-- (measured, -V): the texts seen are remembered (a few distinct ones a capture, up to 256).
local VALID_TYPE, valid_type_n = {}, 0
function U.valid_type(t)
    local v = VALID_TYPE[t]
    if v ~= nil then return v or nil end
    local n = tonumber(t)
    v = (n and n >= 0 and n <= 255 and n == floor(n)) and floor(n) or false
    if valid_type_n < 256 and type(t) == "string" then
        VALID_TYPE[t], valid_type_n = v, valid_type_n + 1
    end
    return v or nil
end

-- A zero-length range at off, kept inside the tvb.
function U.zrange(tvb, off)
    local n = tvb:len()
    if off >= n then off = n - 1 end
    if off < 0 then off = 0 end
    return tvb(off, 0)
end

-- text with the pattern magic characters escaped
function U.pat_escape(text)
    return (s_gsub(text, "[%^%$%(%)%%%.%[%]%*%+%-%?]", "%%%0"))
end

return U
