-- Robot link module: serial.lua's dissection (the per-direction state, the framing, the first
-- pass, the display), split from serial.lua so that its code is compiled only on the first serial
-- record: a capture without one never holds it in the live Lua heap, whose size sets the
-- collector's work for every plugin (docs/perf-log.md, 7 December 2026). serial.lua keeps the
-- Proto, the fields, the experts, the preferences, the interface field and the registration,
-- all made at load time, and hands them over in C.
--
-- Run by serial.lua alone (dissection(): robots/ beside it); Wireshark also runs every .lua file
-- of a plugin folder's subfolders as a plugin of its own: this file then does nothing.

local token, C = ...
if type(token) ~= "table" or token.robot_module ~= true then return end

local D = {} -- what serial.lua calls: D.dissector, D.init
local slserial, hf, ei, R, BB = C.proto, C.hf, C.ei, C.R, C.BB
local record_interface, MAX_HELD_DEFAULT = C.record_interface, C.MAX_HELD_DEFAULT
local is_hex = BB.is_hex

local s_byte, s_sub, s_find = string.byte, string.sub, string.find
local tonumber, pcall, ipairs = tonumber, pcall, ipairs

local MAX_UNDETECTED = 4096
local UNDETECTED_KEEP = 512
local ADOPT_AFTER = 64

local B_RBR, B_PIPE, B_COLON = 93, 124, 58
local B_CR, B_LF, B_C, B_SEMI = 13, 10, 67, 59

local PROTO_NAMES = { "sharedlink", "p2os", "blackboard" }
local PROTO_LABELS = { sharedlink = "SharedLink", p2os = "P2OS", blackboard = "Blackboard" }
local DIR_NAMES = { [0] = "outbound", [1] = "inbound" }
-- the Source and Destination columns for each direction (the capture is taken at the host)
local DIR_ENDS = { [0] = { "host", "device" }, [1] = { "device", "host" } }
local dirs = {}
local max_held -- the max_held_bytes preference, read at each capture's start (and at the module's)
local results = {}  -- [record number] = result table (see first_pass; shared by a run of held records)

local function stream_key(iface, dir)
    return iface * 4 + dir + 1
end

function D.init()
    dirs, results = {}, {}
    max_held = tonumber(slserial.prefs.max_held_bytes) or MAX_HELD_DEFAULT
end
D.init()

------------------------------------------------------------------------------
-- Framing (1-based string positions). Each scanner returns pieces
-- { {start, length, is_frame}, ... } covering s[1 .. hold-1], and hold (#s + 1: none held).
------------------------------------------------------------------------------
local function add_piece(pieces, a, len, is_frame)
    if len > 0 then pieces[#pieces + 1] = { a, len, is_frame } end
end

-- SharedLink: the structural checks of codec._parse_inner for "[" at a and "]" at c
local function sl_valid(s, a, c)
    local len = c - a - 1
    if len < 3 or s_byte(s, a + 1) ~= B_COLON then return false end
    local d, r = s_byte(s, a + 2), s_byte(s, a + 3)
    if d == B_PIPE or d == B_RBR or r == B_PIPE or r == B_RBR then return false end
    if len > 3 and s_byte(s, a + 4) ~= B_PIPE then return false end
    return true
end

-- checksum good: the last field is C<hex>, the byte sum from ':' through that 'C' matches
local function sl_good(s, a, len)
    local c = s_find(s, "]", a, true)
    if not c then return false end
    local p, k = nil, s_find(s, "|", a, true)
    while k and k < c do
        p = k
        k = s_find(s, "|", k + 1, true)
    end
    if not p or s_byte(s, p + 1) ~= B_C then return false end
    local text = s_sub(s, p + 2, c - 1)
    if #text == 0 or #text > 2 then return false end
    local v = tonumber(text, 16)
    if not v then return false end
    local sum = 0
    for i = a + 1, p + 1 do
        sum = sum + s_byte(s, i)
    end
    return v == sum % 256 and len > 0
end

-- the last "[" in s[o .. c - 1] (o holds one)
local function last_open(s, o, c)
    local o2 = o
    local k = s_find(s, "[", o + 1, true)
    while k and k < c do
        o2 = k
        k = s_find(s, "[", k + 1, true)
    end
    return o2
end

-- the last "[" at or after from with no "]" after it (it may start a frame), or nil
local function unclosed_open(s, from)
    local last
    local k = s_find(s, "[", from, true)
    while k do
        last = k
        k = s_find(s, "[", k + 1, true)
    end
    if last and not s_find(s, "]", last, true) then return last end
    return nil
end

local function scan_sharedlink(s, final)
    local n = #s
    local pieces = {}
    local pos, noise, hold = 1, 1, n + 1
    while pos <= n do
        local o = s_find(s, "[", pos, true)
        if not o then break end
        local c = s_find(s, "]", o + 1, true)
        if not c then break end
        local o2 = last_open(s, o, c)
        if sl_valid(s, o2, c) then
            local crlf = s_byte(s, c + 1) == B_CR and s_byte(s, c + 2) == B_LF
            if not final and not crlf and (c == n or (c + 1 == n and s_byte(s, n) == B_CR)) then
                hold = o2 -- its CR LF may come with the next bytes
                break
            end
            local e = crlf and c + 2 or c
            add_piece(pieces, noise, o2 - noise, false)
            add_piece(pieces, o2, e - o2 + 1, true)
            noise, pos = e + 1, e + 1
        else
            pos = c + 1
        end
    end
    if hold == n + 1 and not final then
        hold = unclosed_open(s, noise) or hold
    end
    local over = n + 1 - hold > max_held
    if over then hold = n + 1 end
    add_piece(pieces, noise, hold - noise, false)
    return pieces, hold, over
end

local function scan_p2os(s, final)
    local n = #s
    local pieces = {}
    local pos, noise, hold, over = 1, 1, n + 1, false
    while pos <= n do
        local h = s_find(s, "\250\251", pos, true)
        if not h then break end
        if h + 2 > n then
            if not final then hold = h end
            break
        end
        local count = s_byte(s, h + 2)
        local k = count >= 2 and R.resync_at(s, h, final)
        if count < 2 then
            pos = h + 3
        elseif k == "wait" then
            hold = h
            break
        elseif k then
            pos = k -- (h .. k - 1 stays noise)
        else
            local e = h + 2 + count
            if e > n then
                over = not final and n - h + 1 > max_held
                if not final and not over then hold = h end
                break
            end
            add_piece(pieces, noise, h - noise, false)
            add_piece(pieces, h, e - h + 1, true)
            noise, pos = e + 1, e + 1
        end
    end
    if hold == n + 1 and not final and n > 0 and noise <= n and s_byte(s, n) == 0xFA then
        hold = n -- may start a header
    end
    add_piece(pieces, noise, hold - noise, false)
    return pieces, hold, over
end

local function scan_blackboard(s, final)
    local n = #s
    local pieces = {}
    local pos, noise, hold, over = 1, 1, n + 1, false
    while pos <= n do
        local o = s_find(s, "[:;]", pos)
        if not o then break end
        local cr = s_find(s, "\r", o + 1, true)
        if not cr then
            over = not final and n - o + 1 > max_held
            if not final and not over then hold = o end
            break
        end
        local o2 = BB.message_start(s, o, cr)
        local e = cr -- ends at its CR; an LF that came with it is taken, a later one is noise
        if s_byte(s, cr + 1) == B_LF then e = cr + 1 end
        if BB.check(s, o2, cr) then
            add_piece(pieces, noise, o2 - noise, false)
            add_piece(pieces, o2, e - o2 + 1, true)
            noise, pos = e + 1, e + 1
        else
            pos = cr + 1
        end
    end
    add_piece(pieces, noise, hold - noise, false)
    return pieces, hold, over
end

local SCANNERS = { sharedlink = scan_sharedlink, p2os = scan_p2os, blackboard = scan_blackboard }

-- Blackboard binary answers. A good message from the master (a text frame found in one
-- direction) makes the other direction expect its answer (st.expect: BB.expectation's, and at,
-- its position in that direction's buffer where the answer starts); a later good message
-- replaces it.

-- where an unfinished text message that may still complete starts: the ":" or ";" before the
-- hex digits that run to the end of s (no CR yet), or nil
local function text_prefix_start(s)
    local i = #s
    while i >= 1 and is_hex(s_byte(s, i)) do
        i = i - 1
    end
    local c = i >= 1 and s_byte(s, i)
    if c == B_COLON or c == B_SEMI then return i end
    return nil
end

-- blackboard direction: the expected answer (held until all its bytes are in) is a frame;
-- text and noise before and after it as scan_blackboard finds them. Text wins: bytes where the
-- answer would be that belong to a whole text message are that message, and the answer is
-- still awaited after it (the side talks, then answers: blackboard.lua and the Python reader
-- alike); a wrong answer that may still become a message (":" or ";" and hex digits so far)
-- waits for more bytes.
local function scan_bb_stream(st, s)
    local e = st.expect
    if not e then return scan_blackboard(s, false) end
    local n = #s
    local text = scan_blackboard(s, false)
    for _, p in ipairs(text) do
        if p[3] and p[1] <= e.at + e.len - 1 and p[1] + p[2] - 1 >= e.at then
            e.at = p[1] + p[2]
        end
    end
    local at = e.at
    if at > n + 1 then at = n + 1 end
    local last = at + e.len - 1
    local wait = n < last
    local from = at
    if wait or not BB.answer_good(s, e, at) then
        local p = text_prefix_start(s)
        if p and p <= last and (p < at or not wait) then
            wait, from = true, p < at and p or at
        end
    end
    local pieces = {}
    if from > 1 then
        pieces = scan_blackboard(s_sub(s, 1, from - 1), true)
    end
    if wait then
        return pieces, from
    end
    add_piece(pieces, at, e.len, true)
    pieces[#pieces][4] = true -- an answer, not a message
    st.expect = nil
    local base = at + e.len - 1
    local rest, hold, over = scan_blackboard(s_sub(s, base + 1), false)
    for _, p in ipairs(rest) do
        pieces[#pieces + 1] = { p[1] + base, p[2], p[3] }
    end
    return pieces, hold + base, over
end

local function piece_good(name, s, a, len)
    if name == "sharedlink" then
        return sl_good(s, a, len)
    elseif name == "p2os" then
        local count = s_byte(s, a + 2)
        local plen = count - 2
        -- the 200-byte limit is the robot's for client commands; server packets run to 255
        if count > R.MAX_COUNT and R.from_client(s, a + 3, plen) then return false end
        return R.good_at(s, a)
    else
        local cr = s_find(s, "\r", a, true)
        local _, good = BB.check(s, a, cr)
        return good
    end
end

local function detect(s)
    local best, best_at
    for _, name in ipairs(PROTO_NAMES) do
        local pieces = SCANNERS[name](s, false)
        for _, p in ipairs(pieces) do
            if p[3] and piece_good(name, s, p[1], p[2]) then
                if not best_at or p[1] < best_at then best, best_at = name, p[1] end
                break
            end
        end
    end
    return best
end

------------------------------------------------------------------------------
-- First pass: feed this record's bytes to its direction's stream
------------------------------------------------------------------------------
local function fixed_protocol()
    local p = slserial.prefs.protocol
    if p and p > 0 then return PROTO_NAMES[p] end
    return nil
end

local function dir_state(iface, dir)
    local key = stream_key(iface, dir)
    local st = dirs[key]
    if not st then
        st = { held = {}, hlen = 0, recs = {}, proto = fixed_protocol(), iface = iface }
        dirs[key] = st
    end
    return st
end

-- whether the next bytes may simply be appended to the held ones: the held bytes are one
-- unfinished frame that only a byte of finish[proto] in the new bytes can end or move (a
-- SharedLink frame waits for its "]", a new "[" starts another; a blackboard message for its
-- CR); a frame held for anything else is scanned again with every record
local FINISH = { sharedlink = "[%[%]]", blackboard = "\r" }

local function can_append(st, s)
    if st.hlen == 0 then return false end
    if st.proto == "sharedlink" then
        return s_byte(s, 1) == 91 and not s_find(s, "[%[%]]", 2)
    elseif st.proto == "blackboard" then
        return (s_byte(s, 1) == B_COLON or s_byte(s, 1) == B_SEMI) and not s_find(s, "\r", 1, true)
    end
    return false
end

-- a record that only lengthens the held frame: kept as it is, nothing scanned again; the records
-- of such a run share one result (what they show is the same: the stream, its protocol, and the
-- record completing them; issue 44: a table each cost about 1.8 KB a record sent byte by byte)
local NO_PIECES = {}
local function append_held(st, raw, dir, num)
    local finish = FINISH[st.proto]
    if not st.append or st.expect or not finish or st.hlen + #raw > max_held or s_find(raw, finish) then
        return nil
    end
    local prefix_len = st.hlen
    st.held[#st.held + 1] = raw
    st.hlen = prefix_len + #raw
    st.recs[#st.recs + 1] = { num, prefix_len + 1, st.hlen }
    local run = st.run
    if not run then
        run = { dir = dir, proto = st.proto, pieces = NO_PIECES, region_len = 0, held_from = 0 }
        st.run = run
    end
    return run
end

local function detect_protocol(st, s, n)
    st.proto = detect(s)
    if not st.proto and st.expect and BB.answer_good(s, st.expect, st.expect.at) then
        -- a blackboard slave: its first answer is right (the master's direction is blackboard)
        st.proto = "blackboard"
    end
    if not st.proto and n >= ADOPT_AFTER then
        -- nothing recognisable of its own (e.g. a blackboard slave's binary answers):
        -- the protocol of another direction (lowest direction number first)
        for _, d in ipairs({ -1, 0, 1 }) do
            local other = dirs[stream_key(st.iface, d)]
            if other and other.proto then
                st.proto = other.proto
                break
            end
        end
    end
end

-- good messages make the other direction expect their answers (a later one replaces the
-- expectation). Master and slave are roles of one exchange, not of a direction
-- (docs/fields-p2os-blackboard.md, "Both directions"): a direction that talks may still answer,
-- so its answer is held until whole wherever the records cut it, as blackboard.lua and the
-- Python reader read it (before, a talking direction was never expected to answer, and an answer
-- cut across its records reached blackboard.lua in pieces: a truncated response)
local function expect_answers(st, s, dir, pieces)
    for _, p in ipairs(pieces) do
        local c = s_byte(s, p[1])
        local cr = p[3] and not p[4] and (c == B_COLON or c == B_SEMI) and s_find(s, "\r", p[1], true)
        local e = cr and BB.expectation(s, p[1], cr)
        if e then
            local other = (dir == 0 or dir == 1) and dir_state(st.iface, 1 - dir) or nil
            if other and (other.proto == nil or other.proto == "blackboard") then
                e.at = other.hlen + 1
                other.expect = e
            end
        end
    end
end

-- the pieces of the direction's bytes s and where the held tail starts (and whether an
-- unfinished frame was given up at max_held)
local function scan_direction(st, s, n, dir)
    if st.proto == "blackboard" then
        local pieces, hold, over = scan_bb_stream(st, s)
        expect_answers(st, s, dir, pieces)
        return pieces, hold, over
    elseif st.proto then
        return SCANNERS[st.proto](s, false)
    elseif n > MAX_UNDETECTED then
        local hold = n - UNDETECTED_KEEP + 1
        return { { 1, hold - 1, false } }, hold, false
    end
    return {}, 1, false
end

-- the record's result: the region its bytes complete (from the held bytes on), its pieces,
-- and each earlier record's share of the region
local function region_result(st, s, dir, num, pieces, hold, prefix_len)
    local region_len = hold - 1
    local res = {
        dir = dir, proto = st.proto, pieces = pieces, region_len = region_len,
        held_from = region_len > prefix_len and region_len - prefix_len or 0,
    }
    if prefix_len > 0 and region_len > 0 then
        res.region = s_sub(s, 1, region_len)
        -- each record's share, in order (the shares are contiguous from the region's start), as
        -- the subtree's text lists them: "#12(26), #13(18), #14(8)" (a string: about 8 bytes a
        -- record, where a table of numbers took 110 with frames sent a byte a record). A record
        -- whose first bytes completed an earlier region shares from the region's start.
        local list, count = {}, 0
        for _, r in ipairs(st.recs) do
            if r[2] <= region_len then
                local first = r[2] > 1 and r[2] or 1
                local last = r[3] < region_len and r[3] or region_len
                count = count + 1
                list[count] = "#" .. r[1] .. "(" .. (last - first + 1) .. ")"
            end
        end
        res.frags, res.nfrags = table.concat(list, ", "), count
    end
    -- records whose held bytes complete here learn where
    if region_len > 0 then
        for _, r in ipairs(st.recs) do
            if r[1] ~= num and r[2] <= region_len then
                local other = results[r[1]]
                if other and not other.completed_in then other.completed_in = num end
            end
        end
    end
    return res
end

-- keep the held tail (from hold on) and the records it holds bytes of
local function keep_tail(st, s, hold)
    local tail = s_sub(s, hold)
    st.held, st.hlen, st.run = { tail }, #tail, nil
    st.append = can_append(st, tail)
    if st.expect then
        st.expect.at = st.expect.at - (hold - 1)
        if st.expect.at < 1 then st.expect = nil end
    end
    local region_len = hold - 1
    local recs = {}
    for _, r in ipairs(st.recs) do
        if r[3] >= hold then
            recs[#recs + 1] = { r[1], r[2] - region_len, r[3] - region_len }
        end
    end
    st.recs = recs
end

local function first_pass(raw, dir, num, iface)
    local st = dir_state(iface, dir)
    local res = append_held(st, raw, dir, num)
    if res then return res end
    local prefix_len = st.hlen
    st.held[#st.held + 1] = raw
    local s = table.concat(st.held)
    local n = #s
    st.recs[#st.recs + 1] = { num, prefix_len + 1, n }
    if not st.proto then detect_protocol(st, s, n) end
    local pieces, hold, over = scan_direction(st, s, n, dir)
    local run = st.run
    res = region_result(st, s, dir, num, pieces, hold, prefix_len)
    if over then res.over = true end -- (set only then: a result of 8 fields has a hash of 8)
    keep_tail(st, s, hold)
    if hold == 1 and not over then
        -- nothing completed, every byte held: the record joins the run of held records (their
        -- frame's end completes them all), as an appended one does
        if run and run.proto == res.proto and run.dir == dir then res = run end
        st.run = res
    end
    return res
end

------------------------------------------------------------------------------
-- Display
------------------------------------------------------------------------------
local function lookup(name)
    if not name then return nil end
    local ok, d = pcall(Dissector.get, name)
    if ok and d then return d end
    return nil
end

local function show_as_data(rtvb, pinfo, tree)
    local d = lookup("data")
    if d then d:call(rtvb, pinfo, tree) end
end

local function plural(n, word)
    return n .. " " .. word .. (n == 1 and "" or "s")
end

-- Wireshark's fragment subtree, as TCP and IP show it: "[3 Reassembled fragments (52 bytes):
-- #12(26), #13(18), #14(8)]", a "[Frame: N, payload: a-b (n bytes)]" row per record, the
-- count and the length
local function add_fragments(t, rtvb, res)
    local count = res.nfrags
    local ft = t:add(hf.fragments, rtvb:range(0, res.region_len))
    ft:set_generated()
    ft:set_text(count .. " Reassembled fragments (" .. plural(res.region_len, "byte") .. "): " .. res.frags)
    local off = 0
    for num, len in string.gmatch(res.frags, "#(%d+)%((%d+)%)") do
        num, len = tonumber(num), tonumber(len)
        local fi = ft:add(hf.fragment, rtvb:range(off, len), num)
        fi:set_generated()
        fi:append_text(", payload: " .. off .. "-" .. (off + len - 1) .. " (" .. plural(len, "byte") .. ")")
        off = off + len
    end
    ft:add(hf.fragment_count, count):set_generated()
    ft:add(hf.reassembled_length, res.region_len):set_generated()
end

-- the frames and noise of the region; returns the number of frames
local function add_pieces(t, rtvb, res, sub, label)
    local nframes = 0
    for _, p in ipairs(res.pieces) do
        local r = rtvb:range(p[1] - 1, p[2])
        if p[4] then -- a blackboard slave's binary answer: no framing of its own, held until whole
            nframes = nframes + 1
            t:add(hf.answer, r):set_text(label .. " answer: " .. plural(p[2], "byte"))
        elseif p[3] then
            nframes = nframes + 1
            t:add(hf.frame, r):set_text(label .. " frame: " .. plural(p[2], "byte"))
        else
            local ni = t:add(hf.noise, r)
            -- the protocol dissector reports noise itself; without it, report it here
            if not sub then ni:add_proto_expert_info(ei.noise, p[2] .. " bytes outside any frame") end
        end
    end
    return nframes
end

-- "26 bytes held, part of a SharedLink frame completed in record 14" (the record only on a
-- second pass; bytes held before the protocol was recognised take the protocol of the record
-- completing them)
local function held_text(held, res, label)
    local done = res.completed_in and results[res.completed_in]
    if not res.proto and done and done.proto then label = PROTO_LABELS[done.proto] end
    if not (res.proto or (done and done.proto)) then
        return plural(held, "byte") .. " held, protocol not recognised yet"
    end
    return plural(held, "byte") .. " held, part of a " .. label .. " frame" ..
        (res.completed_in and (" completed in record " .. res.completed_in) or "")
end

local function first_pass_result(tvb, pinfo, n, dir)
    local num = pinfo.number
    local res = results[num]
    if res then return res end
    local iface = record_interface()
    if pinfo.visited then
        -- a record the first pass never saw (should not happen): dissect it alone
        local saved = dirs
        dirs = {}
        res = first_pass(tvb:raw(0, n), dir, num, iface)
        dirs = saved
        return res
    end
    res = first_pass(tvb:raw(0, n), dir, num, iface)
    results[num] = res
    return res
end

-- the record's own tree: direction, protocol (with its warnings)
local function add_record(tvb, tree, n, dir, res)
    local t = tree:add(slserial, tvb:range(0, n))
    t:append_text(", " .. (DIR_NAMES[dir] or "direction unknown") .. ", " .. plural(n, "byte"))
    t:add(hf.direction, dir):set_generated()
    local pi = t:add(hf.protocol, res.proto or "")
    pi:set_generated()
    -- bytes merely held until the protocol is known are not (yet) a finding
    if not res.proto and res.region_len > 0 then pi:add_proto_expert_info(ei.undetected) end
    if res.over then
        t:add_proto_expert_info(ei.limit, "Limit exceeded: an unfinished frame of over " .. max_held
            .. " bytes given up as noise (slserial.max_held_bytes)")
    end
    return t
end

-- the region the record completes (a tvb of its own when earlier records' bytes are in it),
-- its fragments and pieces; returns the tvb (nil: none) and the number of frames
local function add_region(tvb, t, res, sub, label)
    if res.region_len <= 0 then return nil, 0 end
    local rtvb
    if res.region then
        rtvb = ByteArray.new(res.region, true):tvb("Reassembled " .. label)
        add_fragments(t, rtvb, res)
    else
        rtvb = tvb:range(0, res.region_len):tvb()
    end
    return rtvb, add_pieces(t, rtvb, res, sub, label)
end

-- the completed bytes to the protocol's dissector, or as data with a warning
-- the blackboard answers of a region, "offset:length" from 0, for blackboard.lua
-- (pinfo.private "slserial.answers": where the answers are is this dispatcher's framing)
local function answers_text(res)
    local list = {}
    for _, p in ipairs(res.pieces) do
        if p[4] then list[#list + 1] = (p[1] - 1) .. ":" .. p[2] end
    end
    return table.concat(list, ",")
end

local function hand_over(rtvb, pinfo, tree, t, res, sub)
    if sub and res.proto == "blackboard" then
        pinfo.private["slserial.answers"] = answers_text(res)
        sub:call(rtvb, pinfo, tree)
        pinfo.private["slserial.answers"] = nil
        return
    elseif sub then
        sub:call(rtvb, pinfo, tree)
        return
    end
    if res.proto then
        t:add_proto_expert_info(ei.missing, "No dissector named \"" .. res.proto .. "\" is loaded; shown as data")
    end
    show_as_data(rtvb, pinfo, tree)
end

local function dissect(tvb, pinfo, tree)
    local n = tvb:len()
    if n <= 0 then return 0 end
    local dir = pinfo.p2p_dir
    if dir ~= 0 and dir ~= 1 then dir = -1 end
    local res = first_pass_result(tvb, pinfo, n, dir)

    pinfo.cols.protocol = "Serial"
    local ends = DIR_ENDS[dir]
    if ends then
        pinfo.cols.src = ends[1]
        pinfo.cols.dst = ends[2]
    end
    local label = PROTO_LABELS[res.proto or ""] or "not recognised"
    local held = n - res.held_from
    local t = add_record(tvb, tree, n, dir, res)
    local sub = lookup(res.proto)
    local rtvb, nframes = add_region(tvb, t, res, sub, label)
    t:add(hf.frames, nframes):set_generated()
    if nframes > 0 then
        t:append_text(", completes " .. plural(nframes, label .. " frame") ..
            (res.region and (" (" .. plural(res.region_len, "byte") .. " reassembled from " ..
                plural(res.nfrags, "record") .. ")") or ""))
    elseif not res.proto then
        t:append_text(", protocol not recognised yet")
    end
    if held > 0 then
        -- one row for the held bytes; the record completing them inside it (second pass)
        local hi = t:add(hf.held, tvb:range(res.held_from, held))
        hi:set_text(held_text(held, res, label))
        if res.completed_in then
            hi:add(hf.completed_in, res.completed_in):set_generated()
        end
    end
    if rtvb then
        hand_over(rtvb, pinfo, tree, t, res, sub)
    else
        pinfo.cols.info = held > 0 and ("[" .. held_text(held, res, label) .. "]")
            or ((DIR_NAMES[dir] or "unknown direction") .. ": " .. plural(n, "byte"))
    end
    return n
end

D.dissector = dissect
return D
