-- Robot link module: p2os.lua's dissection (its per-capture state, its helpers, the dissect
-- functions, the buffer dissector and the heuristic), split from p2os.lua so that its code is
-- compiled only on the first packet that needs it: a capture without P2OS never holds it in the
-- live Lua heap, whose size sets the collector's work for every plugin (docs/perf-log.md,
-- 7 December 2026). p2os.lua keeps the Proto, the fields, the experts, the preferences, the
-- twins (istr, u8) and the registration, all made at load time, and hands them over in C.
--
-- Run by p2os.lua alone (dissection(): robots/ beside it); Wireshark also runs every .lua file of
-- a plugin folder's subfolders as a plugin of its own: this file then does nothing.

local token, C = ...
if type(token) ~= "table" or token.robot_module ~= true then return end

local D = {}   -- what p2os.lua calls: D.dissector, D.heuristic, D.init
local p2os, pf, ex, config_pf, R, MAX_COUNT = C.proto, C.pf, C.ex, C.config_pf, C.R, C.R.MAX_COUNT
local istr, u8, CONFIG_FIELDS, DEGREES_PER_UNIT = C.istr, C.u8, C.CONFIG_FIELDS, C.DEGREES_PER_UNIT
local COMMANDS, SYNC_NAMES, SERVER_TYPES, DIRECTION_INFO = C.COMMANDS, C.SYNC_NAMES, C.SERVER_TYPES, C.DIRECTION_INFO
local ARG_POSITIVE, ARG_NEGATIVE, ARG_STRING = C.ARG_POSITIVE, C.ARG_NEGATIVE, C.ARG_STRING
local TYPE_CONFIG, TYPE_SIP_STOPPED, TYPE_SIP_MOVING, TYPE_ENCODER =
    C.TYPE_CONFIG, C.TYPE_SIP_STOPPED, C.TYPE_SIP_MOVING, C.TYPE_ENCODER
-- connection state: the frame of the first SYNC2 echo per conversation. Commands 0..2
-- without argument before it are SYNC0..SYNC2, after it PULSE, OPEN, CLOSE.
local sync2_frame = {}
local conversations = 0 -- keys in sync2_frame (bounded by max_conversations)
local not_kept = {} -- frame number -> true: a SYNC2 echo past max_conversations

function D.init()
    sync2_frame = {}
    conversations = 0
    not_kept = {}
end

-- first FA FB at or after off (both bytes present), or nil
local function find_header(tvb, off, n)
    local i = off
    while i + 1 < n do
        if u8(tvb, i) == 0xFA and u8(tvb, i + 1) == 0xFB then
            return i
        end
        i = i + 1
    end
    return nil
end

-- the P2OS checksum of the payload tvb[off .. off + len - 1] (robots/p2os_rules.lua)
local function checksum_at(tvb, off, len)
    if len == 0 then return 0 end
    return R.checksum(tvb:raw(off, len), 1, len)
end

local function to_signed16(v)
    if v >= 32768 then
        return v - 65536
    end
    return v
end

-- a NUL-terminated string at off (before stop): returns its length (without NUL) and whether
-- the NUL was found
local function cstring_len(tvb, off, stop)
    local i = off
    while i < stop do
        if u8(tvb, i) == 0 then
            return i - off, true
        end
        i = i + 1
    end
    return stop - off, false
end

-- printable text for the Info column and labels: control and non-ASCII bytes as \xNN
local function printable(text)
    return (string.gsub(text, "[%c\128-\255]", function(c)
        return string.format("\\x%02X", string.byte(c))
    end))
end

local function add_string(tree, field, tvb, off, len, nul)
    -- a zero-length string is shown on its NUL byte (never a zero-length range)
    local rlen = len
    if nul then
        rlen = len + 1
    end
    if rlen <= 0 then
        return nil, ""
    end
    local text = ""
    if len > 0 then
        text = printable(tvb:range(off, len):string())
    end
    return tree:add(field, tvb:range(off, rlen), text), text
end

local function conversation_key(pinfo)
    local a = tostring(pinfo.src) .. ":" .. istr(pinfo.src_port)
    local b = tostring(pinfo.dst) .. ":" .. istr(pinfo.dst_port)
    if a < b then
        return a .. "-" .. b
    end
    return b .. "-" .. a
end

-- ---------------------------------------------------------------------------------------------
-- client commands

local function dissect_command(tvb, tree, off, plen, in_handshake)
    local num = u8(tvb, off)
    local name = COMMANDS[num]
    local ci = tree:add(pf.command, tvb:range(off, 1))
    if name == nil then
        name = "command " .. istr(num)
        ci:add_proto_expert_info(ex.unknown_command)
    end
    if SYNC_NAMES[num] and plen == 1 and in_handshake then
        name = SYNC_NAMES[num]
    end
    tree:add(pf.command_name, tvb:range(off, 1), name):set_generated()
    if plen == 1 then
        return name
    end
    local t = u8(tvb, off + 1)
    local ti = tree:add(pf.argtype, tvb:range(off + 1, 1))
    local summary
    local used
    if t == ARG_POSITIVE or t == ARG_NEGATIVE then
        if plen < 4 then
            -- (one summary a problem, issue 41: what is present is in the packet's byte count)
            ti:add_proto_expert_info(ex.arg_truncated, "Integer argument truncated")
            return name .. " (argument truncated)"
        end
        local mag = tvb:range(off + 2, 2):le_uint()
        local v = mag
        if t == ARG_NEGATIVE then
            v = -mag
        end
        tree:add(pf.arg_int, tvb:range(off + 2, 2), v)
        summary = name .. " " .. istr(v)
        used = 4
    elseif t == ARG_STRING then
        if plen < 3 then
            ti:add_proto_expert_info(ex.arg_truncated, "String argument without its length")
            return name .. " (argument truncated)"
        end
        local slen = u8(tvb, off + 2)
        local li = tree:add(pf.arg_length, tvb:range(off + 2, 1))
        local have = plen - 3
        if have < slen then
            -- (its length is p2os.arg.length, what is present p2os.arg.string)
            li:add_proto_expert_info(ex.arg_truncated, "String argument truncated")
            slen = have
        end
        if slen > 0 then
            local _, text = add_string(tree, pf.arg_string, tvb, off + 3, slen, false)
            summary = name .. ' "' .. text .. '"'
        else
            summary = name .. ' ""'
        end
        used = 3 + slen
        -- ARIA (ArRobotPacketSender::comStr: strToBuf) sends the NUL that ends the string after
        -- the counted characters: its terminator, not extra bytes
        if plen > used and u8(tvb, off + used) == 0 then
            tree:add(pf.arg_terminator, tvb:range(off + used, 1))
            used = used + 1
        end
    else
        ti:add_proto_expert_info(ex.arg_unknown)
        if plen > 2 then
            tree:add(pf.arg_data, tvb:range(off + 2, plen - 2))
        end
        return name .. " (unknown argument type)"
    end
    if plen > used then
        tree:add(pf.extra, tvb:range(off + used, plen - used)):add_proto_expert_info(ex.extra)
    end
    return summary
end

-- ---------------------------------------------------------------------------------------------
-- server packets

-- standard SIP layout after the type byte: field, size, signed
local SIP_HEAD = {
    { pf.sip_xpos, 2, "XPOS" }, { pf.sip_ypos, 2, "YPOS" }, { pf.sip_thpos, 2, "THPOS" },
    { pf.sip_lvel, 2, "LVEL" }, { pf.sip_rvel, 2, "RVEL" }, { pf.sip_battery, 1, "BATTERY" },
    { pf.sip_stall, 2, "STALL/BUMPERS" }, { pf.sip_control, 2, "CONTROL" }, { pf.sip_flags, 2, "FLAGS" },
    { pf.sip_compass, 1, "COMPASS" },
}
local SIP_TAIL = {
    { pf.sip_grip, "GRIP_STATE" }, { pf.sip_anport, "ANPORT" }, { pf.sip_analog, "ANALOG" },
    { pf.sip_digin, "DIGIN" }, { pf.sip_digout, "DIGOUT" },
}

local function dissect_sip(tvb, tree, off, plen)
    local t = u8(tvb, off)
    tree:add(pf.sip_moving, tvb:range(off, 1), t == TYPE_SIP_MOVING)
    local stop = off + plen
    local i = off + 1
    local v = {}
    for _, spec in ipairs(SIP_HEAD) do
        local f, size = spec[1], spec[2]
        if i + size > stop then
            tree:add_proto_expert_info(ex.sip_truncated, "Standard SIP truncated")   -- (issue 41: no field name)
            return "SIP (truncated)"
        end
        local r = tvb:range(i, size)
        local item = tree:add_le(f, r)
        v[f] = r:le_uint()
        if f == pf.sip_thpos then
            local deg = to_signed16(v[f]) * DEGREES_PER_UNIT
            item:append_text(string.format(" (%.1f degrees)", deg))
            tree:add(pf.sip_heading, r, deg):set_generated()
        elseif f == pf.sip_battery then
            item:append_text(string.format(" (%.1f V)", v[f] / 10))
            tree:add(pf.sip_volts, r, v[f] / 10):set_generated()
        elseif f == pf.sip_stall then
            item:add_le(pf.sip_stall_left, r)
            item:add_le(pf.sip_stall_right, r)
        elseif f == pf.sip_flags then
            item:add_le(pf.sip_motors, r)
        elseif f == pf.sip_compass then
            item:append_text(" (" .. istr(v[f] * 2) .. " degrees)")
        end
        i = i + size
    end
    local summary = string.format("SIP %s x=%s y=%s th=%.1f v=%s/%s %.1fV",
        (t == TYPE_SIP_MOVING) and "moving" or "stopped",
        istr(v[pf.sip_xpos]), istr(v[pf.sip_ypos]), to_signed16(v[pf.sip_thpos]) * DEGREES_PER_UNIT,
        istr(to_signed16(v[pf.sip_lvel])), istr(to_signed16(v[pf.sip_rvel])), v[pf.sip_battery] / 10)
    if i + 1 > stop then
        tree:add_proto_expert_info(ex.sip_truncated, "Standard SIP truncated before the sonar count")
        return summary .. " (truncated)"
    end
    local nson = u8(tvb, i)
    local st = tree:add(pf.sip_sonar_count, tvb:range(i, 1))
    i = i + 1
    for _ = 1, nson do
        if i + 3 > stop then
            st:add_proto_expert_info(ex.sip_truncated, "Standard SIP truncated in its sonar readings")
            return summary .. " (truncated)"
        end
        local num = u8(tvb, i)
        local rng = tvb:range(i + 1, 2):le_uint()
        local rt = st:add(pf.sip_sonar_range, tvb:range(i, 3), rng)
        rt:set_text("Sonar " .. istr(num) .. ": " .. istr(rng) .. " mm")
        rt:add(pf.sip_sonar_number, tvb:range(i, 1))
        i = i + 3
    end
    for _, spec in ipairs(SIP_TAIL) do
        if i + 1 > stop then
            tree:add_proto_expert_info(ex.sip_truncated, "Standard SIP truncated")
            return summary .. " (truncated)"
        end
        tree:add(spec[1], tvb:range(i, 1))
        i = i + 1
    end
    if stop > i then
        tree:add(pf.sip_extra, tvb:range(i, stop - i))
    end
    return summary
end

local function dissect_sync(tvb, tree, off, plen)
    local num = u8(tvb, off)
    tree:add(pf.sync, tvb:range(off, 1))
    local summary = "SYNC" .. istr(num) .. " echo"
    local i = off + 1
    local stop = off + plen
    local names = { pf.robot_name, pf.robot_class, pf.robot_subclass }
    local texts = {}
    for _, f in ipairs(names) do
        if i >= stop then
            break
        end
        local len, nul = cstring_len(tvb, i, stop)
        local _, text = add_string(tree, f, tvb, i, len, nul)
        texts[#texts + 1] = text
        i = i + len
        if nul then
            i = i + 1
        end
    end
    if stop > i then
        tree:add(pf.extra, tvb:range(i, stop - i)):add_proto_expert_info(ex.extra)
    end
    if #texts > 0 then
        summary = summary .. " " .. table.concat(texts, " ")
    end
    return summary
end

local function dissect_encoder(tvb, tree, off, plen)
    if plen < 9 then
        tree:add_proto_expert_info(ex.sip_truncated, "ENCODER packet truncated")
        return "ENCODER (truncated)"
    end
    local l = tvb:range(off + 1, 4):le_int()
    local r = tvb:range(off + 5, 4):le_int()
    tree:add_le(pf.enc_left, tvb:range(off + 1, 4))
    tree:add_le(pf.enc_right, tvb:range(off + 5, 4))
    if plen > 9 then
        tree:add(pf.extra, tvb:range(off + 9, plen - 9)):add_proto_expert_info(ex.extra)
    end
    return "ENCODER " .. istr(l) .. "/" .. istr(r)
end

local function dissect_config(tvb, tree, off, plen)
    local i = off + 1
    local stop = off + plen
    local summary = "CONFIG"
    for _, c in ipairs(CONFIG_FIELDS) do
        if i >= stop then
            break
        end
        local f = config_pf[c[1]]
        if c[2] == "s" then
            local len, nul = cstring_len(tvb, i, stop)
            if not nul then
                break
            end
            local _, text = add_string(tree, f, tvb, i, len, nul)
            if c[1] == "name" then
                summary = summary .. " " .. text
            end
            i = i + len + 1
        else
            if i + c[2] > stop then
                break
            end
            tree:add_le(f, tvb:range(i, c[2]))
            i = i + c[2]
        end
    end
    if stop > i then
        tree:add(pf.config_extra, tvb:range(i, stop - i))
    end
    return summary
end

local function dissect_server(tvb, tree, off, plen)
    local t = u8(tvb, off)
    local ti = tree:add(pf.type, tvb:range(off, 1))
    if t == TYPE_SIP_STOPPED or t == TYPE_SIP_MOVING then
        return dissect_sip(tvb, tree, off, plen)
    elseif t <= 2 then
        return dissect_sync(tvb, tree, off, plen)
    elseif t == TYPE_ENCODER then
        return dissect_encoder(tvb, tree, off, plen)
    elseif t == TYPE_CONFIG then
        return dissect_config(tvb, tree, off, plen)
    end
    ti:add_proto_expert_info(ex.unknown_type)
    if plen > 1 then
        tree:add(pf.data, tvb:range(off + 1, plen - 1))
    end
    return (SERVER_TYPES[t] or "type 0x" .. string.format("%02X", t)) .. " (not decoded)"
end

-- ---------------------------------------------------------------------------------------------
-- direction: by port, by the capture's direction flag, else from the content

local function direction(pinfo, tvb, off, plen)
    local port = p2os.prefs.tcp_port
    if port ~= 0 then
        if pinfo.dst_port == port then
            return true, "the server's TCP port"
        elseif pinfo.src_port == port then
            return false, "the server's TCP port"
        end
    end
    local d = pinfo.p2p_dir
    if d == 0 then
        return true, "the capture (sent by the client's side)"
    elseif d == 1 then
        return false, "the capture (received by the client's side)"
    end
    return plen < 1 or R.from_client(tvb:raw(off, plen), 1, plen), nil
end

-- ---------------------------------------------------------------------------------------------
-- one packet (header at h, count bytes after the count byte, all present in tvb)

-- a SYNC2 echo (with the robot's strings): the conversation's handshake ends here, unless
-- max_conversations conversations are remembered already
local function note_sync2(pinfo, tree, key)
    if not pinfo.visited then
        local s2 = sync2_frame[key]
        if s2 == nil and conversations >= p2os.prefs.max_conversations then
            not_kept[pinfo.number] = true
        elseif s2 == nil or pinfo.number < s2 then
            conversations = conversations + (s2 == nil and 1 or 0)
            sync2_frame[key] = pinfo.number
        end
    end
    if not_kept[pinfo.number] then
        tree:add_proto_expert_info(ex.limit, "Limit exceeded: " .. istr(p2os.prefs.max_conversations)
            .. " conversations remembered (p2os.max_conversations); this one's handshake is not")
    end
end

-- link health (issue 43 on P2OS links): the robot's packets, its SIPs the heartbeat, go to
-- SharedLink's health module when sharedlink.lua is loaded (the definition is written once there:
-- dissector/sharedlink/health.lua, H.robot); the first packet after an outage gets the expert
-- p2os.outage and the generated p2os.outage.duration.  Without sharedlink.lua: nothing.
local function link_health(pinfo, pt, where, status)
    local health = package.loaded["sharedlink.health"]
    if type(health) ~= "table" or not health.robot then return end
    local gone = health.robot(pinfo, where, "p2os", "robot", status)
    if gone then health.mark(pt, nil, gone, pf.outage_duration, ex.outage) end
end

local function dissect_one(tvb, pinfo, tree, h, count)
    local total = 3 + count
    local pt = tree:add(p2os, tvb:range(h, total))
    pt:add(pf.header, tvb:range(h, 2))
    local ci = pt:add(pf.count, tvb:range(h + 2, 1))
    local plen = count - 2
    local off = h + 3
    local calc = checksum_at(tvb, off, plen)
    local crange = tvb:range(off + plen, 2)
    local written = crange:uint()
    local client, how = direction(pinfo, tvb, off, plen)
    -- the robot ignores a client command over 200 bytes (the P2OS manual); a server packet may
    -- count up to 255 (ARIA reads them; shared/PROTOCOL-NOTES.md, issue 40): no expert for it
    local too_big = client and count > MAX_COUNT
    if too_big then
        ci:add_proto_expert_info(ex.count_big)
    end
    local di = pt:add(pf.direction, tvb:range(h, total), client and 0 or 1)
    di:set_generated()
    if how then
        di:append_text(", from " .. how)
    else
        di:append_text(", guessed from the content")
        di:add_proto_expert_info(ex.direction_guess)
    end
    local summary
    if plen == 0 then
        pt:add_proto_expert_info(ex.empty)
        summary = "empty packet"
    else
        local body = pt:add(pf.payload, tvb:range(off, plen))
        local key = conversation_key(pinfo)
        if client then
            local s2 = sync2_frame[key]
            summary = dissect_command(tvb, body, off, plen, s2 == nil or pinfo.number <= s2)
        else
            if plen > 1 and u8(tvb, off) == 2 then
                note_sync2(pinfo, body, key)
            end
            summary = dissect_server(tvb, body, off, plen)
        end
    end
    local ck = pt:add(pf.checksum, crange)
    pt:add(pf.checksum_calc, crange, calc):set_generated()
    local status
    if written == calc then
        ck:append_text(" [correct]")
        status = 1
    else
        ck:append_text(" [incorrect, should be 0x" .. string.format("%04X", calc) .. "]")
        -- one summary a problem (issue 41): the values are p2os.checksum and p2os.checksum.calculated
        ck:add_proto_expert_info(ex.checksum_bad)
        status = 0
        summary = summary .. " [bad checksum]"
    end
    pt:add(pf.checksum_status, crange, status):set_generated()
    if not client then
        link_health(pinfo, pt, h .. "/" .. tvb:len(), status)
    end
    if too_big then
        summary = summary .. " [count > 200]"
    end
    pt:append_text(", " .. (client and "client to robot: " or "robot to client: ") .. summary)
    return summary, client and 0 or 1
end

-- "Client→Robot SYNC0; SYNC1; Robot→Client SYNC0 echo": the direction said when it changes;
-- past 6 entries the first 3 and the count
local function info_text(infos, dirs)
    local parts, last = {}, nil
    local shown = #infos > 6 and 3 or #infos
    for i = 1, shown do
        local d = dirs[i]
        parts[i] = ((d ~= nil and d ~= last) and DIRECTION_INFO[d] or "") .. infos[i]
        if d ~= nil then last = d end
    end
    if shown < #infos then parts[#parts + 1] = "... (" .. istr(#infos) .. " packets)" end
    return table.concat(parts, "; ")
end

-- a header cut off before a packet at h (R.resync_at over s, the buffer's bytes): junk up to
-- the packet, and where to go on; "more" after asking TCP for more bytes; nil when h is no such
-- header
local function skip_cut_header(tvb, s, pinfo, tree, h, can_more, infos)
    if h + 3 > #s or u8(tvb, h + 2) < 2 then return nil end
    local k = R.resync_at(s, h + 1, not can_more)
    if k and k ~= "wait" then k = k - 1 end
    if k == "wait" then
        pinfo.desegment_offset = h
        pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
        return "more"
    elseif k then
        tree:add(pf.junk, tvb:range(h, k - h)):add_proto_expert_info(ex.junk)
        infos[#infos + 1] = "junk"
    end
    return k
end

-- whole buffer: packets and the bytes between them. Returns bytes consumed, or the buffer
-- length after asking TCP for more.
local function dissect_buffer(tvb, pinfo, tree)
    local n = tvb:len()
    if n == 0 then
        return 0
    end
    pinfo.cols.protocol = "P2OS"
    local can_more = pinfo.can_desegment > 0
    local s = tvb:raw(0, n)
    local infos = {}
    local dirs = {} -- infos[i]'s direction (0 client to robot, 1 robot to client), if a packet
    local off = 0
    while off < n do
        local h = find_header(tvb, off, n)
        if h == nil then
            local stop = n
            if can_more and u8(tvb, n - 1) == 0xFA then
                stop = n - 1 -- maybe the start of a header
            end
            if stop > off then
                tree:add(pf.junk, tvb:range(off, stop - off)):add_proto_expert_info(ex.junk)
                infos[#infos + 1] = "junk"
            end
            if stop < n then
                pinfo.desegment_offset = stop
                pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
            end
            break
        end
        if h > off then
            tree:add(pf.junk, tvb:range(off, h - off)):add_proto_expert_info(ex.junk)
            infos[#infos + 1] = "junk"
        end
        local k = skip_cut_header(tvb, s, pinfo, tree, h, can_more, infos)
        if k == "more" then
            break
        elseif k then
            off = k
        elseif h + 3 > n or h + 3 + u8(tvb, h + 2) > n then
            if can_more then
                -- one more segment, not the bytes the count claims: the count may be a cut-off
                -- header's, and the next segment may bring the FA FB it resynchronises on
                -- (R.resync_at; asking for the claimed bytes would wait for bytes that never come)
                pinfo.desegment_offset = h
                pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
                break
            end
            local t = tree:add(p2os, tvb:range(h, n - h))
            t:append_text(", truncated")
            t:add(pf.header, tvb:range(h, 2))
            if h + 3 <= n then
                t:add(pf.count, tvb:range(h + 2, 1))
            end
            t:add_proto_expert_info(ex.truncated)   -- (its byte count: p2os.count)
            infos[#infos + 1] = "truncated packet"
            break
        elseif u8(tvb, h + 2) < 2 then
            local t = tree:add(p2os, tvb:range(h, 3))
            t:add(pf.header, tvb:range(h, 2))
            t:add(pf.count, tvb:range(h + 2, 1)):add_proto_expert_info(ex.count_small)
            infos[#infos + 1] = "bad count"
            off = h + 3
        else
            local count = u8(tvb, h + 2)
            infos[#infos + 1], dirs[#infos + 1] = dissect_one(tvb, pinfo, tree, h, count)
            off = h + 3 + count
        end
    end
    if #infos > 0 then
        pinfo.cols.info = info_text(infos, dirs)
    end
    return n
end


-- heuristic: FA FB, a count of 2..255 (server packets run to 255), the whole first packet
-- present with a good checksum
local function heuristic(tvb, pinfo, tree)
    local n = tvb:len()
    if n < 5 or u8(tvb, 0) ~= 0xFA or u8(tvb, 1) ~= 0xFB then
        return false
    end
    local count = u8(tvb, 2)
    if count < 2 or 3 + count > n then
        return false
    end
    local plen = count - 2
    if checksum_at(tvb, 3, plen) ~= tvb:range(3 + plen, 2):uint() then
        return false
    end
    dissect_buffer(tvb, pinfo, tree)
    -- the rest of this conversation comes straight here (where the version allows)
    pcall(function()
        pinfo.conversation = p2os
    end)
    return true
end

D.dissector = dissect_buffer
D.heuristic = heuristic
return D
