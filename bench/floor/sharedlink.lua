-- The summary pass's floor (bench only, never installed): a dissector for the bench's beacon frame
-- ([:AB|N0|T2|QAutoGpsLat|D...|...|T2|QAutoGpsVel|D...|Cxx] from `sharedlink gen`) that makes only
-- the calls any Lua decoder of that frame on the documented wslua API makes, in one function with
-- no module, frame record or general case: tvb:raw, the Columns object, the protocol and Info
-- columns, the packet's number, visited flag, ports, both Address objects (compared with the last
-- packet's) and time, the layout's head found and its pattern matched (the dissector's DOUBLE and
-- CHECKSUM), the values joined and summed (SUM_OF), the Info made of the layout's pieces.  With
-- SHAREDLINK_FLOOR=state it also does what the state writer and link health do for such a frame:
-- the direction found by ports and letters, the four values and their frame stored by name, the
-- sync clock, the checksum verdict, the link's interval window.  SHAREDLINK_FLOOR_OFF leaves parts
-- out (comma list: addresses, match, sum, protocol), to price each by subtraction.
--   bench/bench_dissector.py --count-only --passes summary --dissectors bench/floor
-- docs/perf-log.md ("The summary pass's floor", 7 December 2026) has the figures.
local p = Proto("sharedlink", "SharedLink floor (bench)")
local s_find, s_match, s_byte, t_concat = string.find, string.match, string.byte, table.concat
local env = os.getenv("SHAREDLINK_FLOOR") or ""
local off = os.getenv("SHAREDLINK_FLOOR_OFF") or ""
local STATE = env == "state"
local ADDR, MATCH = not off:find("addresses", 1, true), not off:find("match", 1, true)
local SUM, PROTO = not off:find("sum", 1, true), not off:find("protocol", 1, true)

local HEAD = "[:AB|N0|T2|QAutoGpsLat|D"
local D = "(%-?[0-9]+%.?[0-9]*)"
local PAT = "^" .. D .. "|T2|QAutoGpsLon|D" .. D .. "|T2|QAutoGpsHead|D" .. D .. "|T2|QAutoGpsVel|D" .. D ..
    "|C([^]|[]*)%](\r?\n?)"
local AT = #HEAD + 1
local PAD = string.rep("\0", 20)
local P1, P2, P3, P4 = "B\226\134\146A full AutoGpsLat=", " AutoGpsLon=", " AutoGpsHead=", " AutoGpsVel="
local SUM_OF = {}
do
    local args = {}
    for i = 1, 40 do args[i] = "a" .. i end
    for n = 1, 40 do
        SUM_OF[n] = load("local " .. t_concat(args, ",", 1, n) .. " = ... return " .. t_concat(args, "+", 1, n))
    end
end
local UHEXV = {}
for i = 0, 255 do UHEXV[string.format("%02X", i)] = i end

local G, raw
local last_src, last_dst
local DIRS = {}

-- what the state writer and link health do for a calm full frame (SHAREDLINK_FLOOR=state)
local function state_step(sp, dp, num, t, sum, c, v1, v2, v3, v4)
    local key = (sp * 65536 + dp) * 65536 + 65 * 256 + 66
    local d = DIRS[key]
    if not d then
        d = { vals = {}, from = {}, hl = { win = {}, n = 0, last = 0 } }
        DIRS[key] = d
    end
    local vals, from = d.vals, d.from
    vals.AutoGpsLat, from.AutoGpsLat = v1, num
    vals.AutoGpsLon, from.AutoGpsLon = v2, num
    vals.AutoGpsHead, from.AutoGpsHead = v3, num
    vals.AutoGpsVel, from.AutoGpsVel = v4, num
    d.lastfull = t
    local good = UHEXV[c] == sum % 256
    local L = d.hl
    local gap = t - L.last
    if good and gap > 0 and gap < 100 then
        local n = L.n + 1
        L.win[(n - 1) % 16 + 1], L.n, L.last = gap, n, t
    end
end

function p.dissector(tvb, pinfo)
    if not G then G, raw = getmetatable(pinfo).__getters, Tvb.raw end
    local s = raw(tvb)
    local cols = G.cols(pinfo)
    if PROTO then cols.protocol = "SharedLink" end
    local num = G.number(pinfo)
    if G.visited(pinfo) then return #s end
    local sp, dp = G.src_port(pinfo), G.dst_port(pinfo)
    if ADDR then
        local a, b = G.src(pinfo), G.dst(pinfo)
        if a ~= last_src or b ~= last_dst then last_src, last_dst = a, b end
    end
    local t = G.rel_ts(pinfo)
    if s_find(s, HEAD, 1, true) ~= 1 then cols.info = "not the beacon's layout"; return #s end
    local v1, v2, v3, v4, c = "38.34698779", "-77.05734791", "57.0", "0.0", "B4"
    if MATCH then v1, v2, v3, v4, c = s_match(s, PAT, AT) end
    local sum = 0
    if SUM then
        local all = v1 .. v2 .. v3 .. v4 .. PAD
        local vlen = #all - 20
        sum = SUM_OF[vlen](s_byte(all, 1, vlen))
    end
    if STATE then state_step(sp, dp, num, t, sum, c, v1, v2, v3, v4) end
    cols.info = P1 .. v1 .. P2 .. v2 .. P3 .. v3 .. P4 .. v4
    return #s
end

DissectorTable.get("udp.port"):add(7013, p)
