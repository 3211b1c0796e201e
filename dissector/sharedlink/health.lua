-- SharedLink dissector module: health, link health (issue 43): per link its learnt rate and its
-- outages, the sharedlink.outage expert on the first frame after one, and the link table the
-- -z sharedlink,stats tap reports.  Loaded by sharedlink.lua (load_module); Wireshark also runs
-- every .lua file of a plugin folder's subfolders as a plugin of its own: this file then does nothing.
--
-- The definition is docs/fields-sharedlink.md, "Link health"; its Python twin is
-- pytools/sharedlink/analysis/health.py (tests/dissector/test_health_tap.py holds them together):
--  * a link: one direction of one conversation (addresses and ports, the capture direction where no
--    port tells it, and the letter pair);
--  * an interval: the time from the link's latest frame so far to a later frame; the learnt period:
--    the median (the upper middle one of an even count) of its last WINDOW intervals;
--  * an outage: an interval longer than the threshold, a fixed outage_after preference (seconds)
--    when set, else the larger of FLOOR seconds and PERIODS learnt periods (none before the first
--    interval: a link's first interval is never an outage); from the frame before the silence to
--    the frame after it; a link silent past its threshold at the capture's end: open, to that end.
-- First pass only: each frame's link moves on (H.frame); the expert of a frame that ends an outage
-- is kept per frame (marks) and shown on every pass (later ones: H.marked).  Times are pinfo.rel_ts (seconds, a double:
-- exact to far below a nanosecond over a day); comparisons allow half a nanosecond (EPS), as the
-- Python twin compares integer nanoseconds.

local token, M = ...
if type(token) ~= "table" or token.sharedlink_module ~= true then return end

local U, PG, TI, F = M.util, M.wsapi.PG, M.wsapi.TI, M.parse.F
local hf, ei, sl = M.fields.hf, M.fields.ei, M.proto
local tostring, s_format, s_char, s_byte, t_sort, floor = tostring, string.format, string.char, string.byte, table.sort,
    math.floor
local ARROW = U.ARROW

------------------------------------------------------------------------------
-- The definition (twin: analysis/health.py)
------------------------------------------------------------------------------
local FLOOR = 1.0     -- seconds: the shortest outage under the learnt rule
local PERIODS = 3     -- learnt periods of silence that make an outage
local WINDOW = 16     -- intervals the learnt period is the median of
local EPS = 0.5e-9    -- half a nanosecond: what a double's rounding may add to an interval

hf.outage_duration = ProtoField.double("sharedlink.outage.duration", "Outage duration (s)")
ei.outage = ProtoExpert.new("sharedlink.outage", "Link silent", expert.group.SEQUENCE, expert.severity.WARN)

sl.prefs.outage_after = Pref.string("Outage after (s)", "",
    "A silence longer than this many seconds in one direction of a conversation is an outage; empty: the "
    .. "larger of 1 s and 3 periods of the link's learnt rate")

local H = {}
local links, order, marks, fixed, low
local l_num, l_key   -- the current packet's address and port key (made once a packet)
local r_num, r_label -- robot links (H.robot): the current packet's session label (made once a packet)
local r_marks        -- [frame] = { [where] = the outage duration the robot packet at where ends }

-- The threshold from the preference: a number of seconds above 0, else the learnt rule (nil); a
-- text that is no such number is reported once and the learnt rule used.
local function read_threshold()
    local text = tostring(sl.prefs.outage_after or ""):gsub("^%s+", ""):gsub("%s+$", "")
    if text == "" then return nil end
    local s = tonumber(text)
    if not s or s ~= s or s <= 0 or s > 86400 then
        report_failure("SharedLink: outage_after preference " .. text ..
            ": give seconds above 0 and at most 86400 (or nothing: learnt from each link's rate)")
        return nil
    end
    return s
end

function H.reset()
    links, order, marks, r_marks = {}, {}, {}, {}
    l_num, l_key, r_num, r_label = nil, nil, nil, nil
    fixed = read_threshold()
    low = (fixed or FLOOR) + EPS   -- no interval at most this long is an outage
end

-- The link's name as Python's link_name writes it.
local DIRNAME = { [1] = "inbound", [0] = "outbound" }
local function link_name(pinfo, sport, dport)
    if sport == 0 and dport == 0 then return "serial " .. (DIRNAME[PG.p2p_dir(pinfo)] or "unknown") end
    local a, b = tostring(PG.src(pinfo)), tostring(PG.dst(pinfo))
    if a:find(":", 1, true) then a = "[" .. a .. "]" end
    if b:find(":", 1, true) then b = "[" .. b .. "]" end
    return a .. ":" .. sport .. " > " .. b .. ":" .. dport
end

local function packet_key(pinfo, num)
    if l_num ~= num then
        local sport, dport = PG.src_port(pinfo), PG.dst_port(pinfo)
        l_key = link_name(pinfo, sport, dport)
        l_num = num
    end
    return l_key
end

local function letter(b) return b and s_char(b) or "?" end

-- The link named name with pair, made on its first frame (past max_conversations links: the one
-- link "(links past the limit)").  Its frames: n + skip, n the intervals it had (the last WINDOW
-- of them in the ring win, the newest at (n - 1) % WINDOW + 1), skip its frames that added
-- none (its first, and any not later than its latest); last its latest frame's time.
local function link_named(name, pair)
    local key = name .. "\t" .. pair
    local L = links[key]
    if not L and #order >= M.prefs.LIM.max_conversations then   -- (as analysis/health.py's MAX_LINKS)
        name, pair, key = "(links past the limit)", "*", "*"
        L = links[key]
    end
    if not L then
        L = { name = name, pair = pair, n = 0, skip = 0, win = {}, outages = {}, bad = 0, late = 0,
            had_cs = false, cs_missing = 0, fast = false }
        links[key] = L
        order[#order + 1] = key
    end
    return L
end

-- The link of a frame (its address bytes F.dstb, F.srcb), by its key (and kept as its direction's
-- d.hl when the state keeps one).
local function link_of(pinfo, num, d)
    local L = link_named(packet_key(pinfo, num), letter(F.srcb) .. ">" .. letter(F.dstb))
    if d then d.hl = L end
    return L
end

local function median(L)
    local w, n = {}, math.min(L.n, WINDOW)
    for k = 1, n do w[k] = L.win[k] end
    t_sort(w)
    return w[floor(n / 2) + 1]
end

-- The longest interval that is no outage now (nil: none is one yet).
local function threshold(L)
    if fixed then return fixed end
    if L.n == 0 then return nil end
    local p = PERIODS * median(L)
    return p < FLOOR and FLOOR or p
end

-- gap past the link's threshold?  (only an interval longer than FLOOR or the fixed threshold can be)
local function is_outage(L, gap)
    if gap <= low then return false end
    local limit = threshold(L)
    return limit ~= nil and gap > limit + EPS
end

-- The rarer parts of a frame (first pass): a checksum other than good, a late frame, a frame before
-- its link's latest, an outage.  Returns the outage it ends (seconds), or nil.
local function frame_slow(L, t, cs_status, late, kind)
    if cs_status == 2 then   -- no checksum field (a malformed frame says nothing of the habit)
        if L.had_cs and kind ~= "malformed" then L.cs_missing = L.cs_missing + 1 end
    elseif cs_status == 0 then
        L.had_cs, L.bad = true, L.bad + 1
    elseif cs_status and kind ~= "malformed" then
        L.had_cs = true
    end
    if late then L.late = L.late + 1 end
    local last = L.last
    if not last then L.first, L.last, L.skip = t, t, L.skip + 1; return nil end
    local gap = t - last
    if gap <= 0 then L.skip = L.skip + 1; return nil end
    local out = nil
    if is_outage(L, gap) then
        L.outages[#L.outages + 1] = { start = last, stop = t, dur = gap }
        out = gap
    end
    local n = L.n + 1
    L.win[(n - 1) % WINDOW + 1], L.n, L.last = gap, n, t
    L.fast = L.had_cs and n >= WINDOW   -- (H.frame's common path may take its next frame)
    return out
end

-- The outage duration out a frame ends, kept for later passes: into t[num][key] (t: marks, or
-- r_marks for a robot link's packet).
local function keep_mark(t, num, key, out)
    local m = t[num]
    if not m then m = {}; t[num] = m end
    m[key] = out
end

-- A frame H.frame's common path does not take (first pass): frame_slow with its link, the outage
-- it ends kept for later passes (marks).
local function frame_other(pinfo, num, sk, d, t, cs_status, rec, kind)
    local L = d and d.hl or link_of(pinfo, num, d)
    local out = frame_slow(L, t or PG.rel_ts(pinfo), cs_status, rec and rec.late, kind)
    if out then keep_mark(marks, num, sk, out) end
    return out
end

-- Every frame of the first pass: its link moves on; the outage duration it ends (seconds), or nil.
-- d: the direction state the state module gave (nil: none), t: the packet's time it read (nil: it
-- read none; a full frame's is its direction's sync clock, so no second wslua call reads it).  The
-- common frame (a good checksum on a link that had one, not late, later than the link's latest by
-- no more than the lowest threshold, a full window: L.fast) adds its interval here (speed trick,
-- measured: frame_slow is the plain path, and does the same).  A frame's link and address bytes:
-- its direction's d.hl, else F.dstb, F.srcb (link_of).
function H.frame(pinfo, num, sk, d, t, cs_status, rec, kind)
    local L = d and d.hl
    if L and t and cs_status == 1 and L.fast and not (rec and rec.late) then
        local gap = t - L.last
        if gap > 0 and gap <= low then
            local n = L.n + 1
            L.win[(n - 1) % WINDOW + 1], L.n, L.last = gap, n, t
            return nil
        end
    end
    return frame_other(pinfo, num, sk, d, t, cs_status, rec, kind)
end

-- A later pass: the outage duration the frame (num, sk) ends, as the first pass found it, or nil.
function H.marked(num, sk)
    local m = marks[num]
    return m and m[sk]
end

-- The expert and the generated duration on tree (the packet's, or the root Wireshark gave when
-- there is no tree: then the expert alone). One expert summary for every outage, "Link silent"
-- (issue 41: -z expert lists one row per problem); the duration is the field's value, its item
-- reads "Link silent for 4.20 s".  field, expert: a robot link's own (p2os.lua's, blackboard.lua's
-- outage field and expert), else SharedLink's.
function H.mark(tree, root, dur, field, expert)
    expert = expert or ei.outage
    if tree then
        local ti = tree:add(field or hf.outage_duration, dur)
        ti:set_text(s_format("Link silent for %.2f s", dur))
        ti:set_generated()
        TI.add_proto_expert_info(ti, expert)
    elseif root then
        TI.add_proto_expert_info(root, expert)
    end
end

------------------------------------------------------------------------------
-- Robot links (issue 42; twin: analysis/robot_health.py): p2os.lua and blackboard.lua, plugins of
-- their own, find this module as package.loaded["sharedlink.health"] (when sharedlink.lua is
-- loaded) and give it each packet of a paced side: the P2OS robot's (its SIPs are P2OS's
-- heartbeat; the client's commands keep no pace and are left out) and both blackboard sides.  A
-- link is named as Python names it: the protocol and the session ("p2os tcp 10.0.0.1:8101 -
-- 10.0.0.2:45678", the lower address and port first; "blackboard serial interface 0": serial.lua
-- knows no other interface), its pair the side ("robot>client", "master>slave", "slave>master").
------------------------------------------------------------------------------
local OTHER_SIDE = { robot = "client", master = "slave", slave = "master" }
local PT_TCP = 2   -- pinfo.port_type of a TCP segment (epan's port_type enum; 4.0 to 4.6)

-- byte order, whatever the locale (Lua's < on strings is strcoll's)
local function bytes_less(a, b)
    for i = 1, math.min(#a, #b) do
        local x, y = s_byte(a, i), s_byte(b, i)
        if x ~= y then return x < y end
    end
    return #a < #b
end

local function istr(n) return tostring(floor(n)) end

local function session_label(pinfo)
    local sport, dport = pinfo.src_port, pinfo.dst_port
    if sport == 0 and dport == 0 then return "serial interface 0" end
    local a, b = tostring(pinfo.src), tostring(pinfo.dst)
    if bytes_less(b, a) or (a == b and dport < sport) then a, b, sport, dport = b, a, dport, sport end
    local proto = pinfo.port_type == PT_TCP and "tcp " or "udp "
    return proto .. a .. ":" .. istr(sport) .. " - " .. b .. ":" .. istr(dport)
end

-- One P2OS packet or blackboard message of a paced side (side: "robot", "master", "slave"), its
-- checksum status (1 good, 0 bad); where: the packet's place in the frame (a text the caller
-- makes the same on every pass).  The outage it ends (seconds), or nil; on every pass.
function H.robot(pinfo, where, protocol, side, cs_status)
    local num = pinfo.number
    if pinfo.visited then
        local m = r_marks[num]
        return m and m[where]
    end
    if r_num ~= num then r_num, r_label = num, session_label(pinfo) end
    local L = link_named(protocol .. " " .. r_label, side .. ">" .. (OTHER_SIDE[side] or "?"))
    local out = frame_slow(L, pinfo.rel_ts, cs_status, nil, nil)
    if out then keep_mark(r_marks, num, where, out) end
    return out
end

------------------------------------------------------------------------------
-- The link table (the tap's report)
------------------------------------------------------------------------------
-- Links in the order Python sorts them (name, then pair), each with its figures at the capture's
-- end (the latest frame): open outages included.
function H.links()
    local out = {}
    local keys = {}
    local last_end = nil   -- the capture's latest frame: every frame's time is at most its link's latest
    for k = 1, #order do
        keys[k] = order[k]
        local t = links[order[k]].last
        if t and (not last_end or t > last_end) then last_end = t end
    end
    t_sort(keys)
    for _, key in ipairs(keys) do
        local L = links[key]
        local outs = {}
        for k, o in ipairs(L.outages) do outs[k] = o end
        local gap = last_end and L.last and last_end - L.last
        if gap and is_outage(L, gap) then outs[#outs + 1] = { start = L.last, dur = gap, open = true } end
        local total, longest = 0, 0
        for _, o in ipairs(outs) do
            total = total + o.dur
            if o.dur > longest then longest = o.dur end
        end
        local span = last_end - L.first
        local avail = span > 0 and math.max(0, 1 - total / span) or 1
        local med = L.n > 0 and median(L) or nil
        out[#out + 1] = { name = L.name, pair = L.pair, frames = L.n + L.skip, rate = med and 1 / med, outages = outs,
            total = total, longest = longest, avail = avail, bad = L.bad, late = L.late, cs_missing = L.cs_missing }
    end
    return out
end

-- The link health section of the tap's report, appended to out (lines), with table_lines its
-- table writer.
function H.report(out, table_lines)
    local ls = H.links()
    out[#out + 1] = ""
    out[#out + 1] = "Link health"
    local rows = { { "Link", "Pair", "Frames", "Rate Hz", "Outages", "Outage s", "Longest s", "Available %",
        "Bad checksum %", "Sync late frames" } }
    local outages = { { "Link", "Pair", "Start s", "Duration s", "" } }
    for _, L in ipairs(ls) do
        rows[#rows + 1] = { L.name, (L.pair:gsub(">", ARROW)), tostring(L.frames),
            L.rate and s_format("%.3f", L.rate) or "", tostring(#L.outages), s_format("%.3f", L.total),
            s_format("%.3f", L.longest), s_format("%.2f", 100 * L.avail),
            s_format("%.2f", L.frames > 0 and 100 * L.bad / L.frames or 0), tostring(L.late) }
        for _, o in ipairs(L.outages) do
            outages[#outages + 1] = { L.name, (L.pair:gsub(">", ARROW)), s_format("%.6f", o.start),
                s_format("%.6f", o.dur), o.open and "(open)" or "" }
        end
    end
    table_lines(out, rows, { "l", "l", "r", "r", "r", "r", "r", "r", "r", "r" })
    out[#out + 1] = ""
    out[#out + 1] = "Outages (start: seconds from the first packet)"
    table_lines(out, outages, { "l", "l", "r", "r", "l" })
    for _, L in ipairs(ls) do
        if L.cs_missing > 0 then
            out[#out + 1] = s_format("  Note: %s %s: checksum missing on a link that carries them (%d frames)",
                L.name, (L.pair:gsub(">", ARROW)), L.cs_missing)
        end
    end
end

package.loaded["sharedlink.health"] = H   -- (the tap's way in: sharedlink_stats.lua)
return H
