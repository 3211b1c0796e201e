-- Robot link module: blackboard.lua's dissection (its per-capture state, its helpers, the dissect
-- functions, the buffer dissector and the heuristic), split from blackboard.lua so that its code is
-- compiled only on the first packet that needs it: a capture without blackboard never holds it in the
-- live Lua heap, whose size sets the collector's work for every plugin (docs/perf-log.md,
-- 7 December 2026). blackboard.lua keeps the Proto, the fields, the experts, the preferences, the
-- twins (istr, u8) and the registration, all made at load time, and hands them over in C.
--
-- Run by blackboard.lua alone (dissection(): robots/ beside it); Wireshark also runs every .lua file of
-- a plugin folder's subfolders as a plugin of its own: this file then does nothing.

local token, C = ...
if type(token) ~= "table" or token.robot_module ~= true then return end

local D = {}   -- what blackboard.lua calls: D.dissector, D.heuristic, D.init
local bb, pf, ex, BB, istr, u8 = C.proto, C.pf, C.ex, C.BB, C.istr, C.u8
local SET, REQUEST, LF = C.SET, C.REQUEST, C.LF
-- conversation state: the request each side waits an answer to
--
-- pending[key] = { kind = "set" | "request", frame = n, checksum = c, count = n, sum = s,
--                  text = "..." } where key names the direction the answer travels. On the
-- first pass the live table is used, and each frame keeps a note of the two entries it can
-- read (its own direction's and the opposite one's), so later passes (and the GUI
-- re-dissecting one frame) see the same state: one small table a frame, never a copy of all.

local pending = {}
local pending_count = 0 -- entries in pending (bounded by the max_pending preference)
local frame_state = {}
local messages = {} -- "frame:offset" -> the record of a message, to show where it was answered
local not_held = {} -- "frame:offset" -> true: a message left out of pending (max_pending)
-- [direction key] = the frame whose text waits for its CR (TCP asked for more segments), first
-- pass; a later call in that direction clears it. What the first pass leaves is text the capture
-- ends before its CR: a later pass shows it in that frame, not ended by CR
local waiting_cr = {}

function D.init()
    pending = {}
    pending_count = 0
    frame_state = {}
    messages = {}
    not_held = {}
    waiting_cr = {}
end

local function hexval(c)
    if c >= 0x30 and c <= 0x39 then
        return c - 0x30
    elseif c >= 0x41 and c <= 0x46 then
        return c - 0x37
    elseif c >= 0x61 and c <= 0x66 then
        return c - 0x57
    end
    return nil
end

local function hex2(n)
    return string.format("%02X", n)
end

-- ---------------------------------------------------------------------------------------------
-- conversation state: helpers

local function endpoint(addr, port)
    return tostring(addr) .. ":" .. istr(port)
end

-- key of the direction this frame travels in; and of the opposite one (where answers go)
local function keys(pinfo)
    local src = endpoint(pinfo.src, pinfo.src_port)
    local dst = endpoint(pinfo.dst, pinfo.dst_port)
    local d = pinfo.p2p_dir
    local here, back = "?", "?"
    if d == 0 then
        here, back = "sent", "received"
    elseif d == 1 then
        here, back = "received", "sent"
    end
    return src .. ">" .. dst .. "/" .. here, dst .. ">" .. src .. "/" .. back
end

-- the pending table this frame reads and writes: the live one on the first pass (noting the
-- frame's two entries as they are at its start), a table of the noted entries later
local function state_for(pinfo)
    local here, back = keys(pinfo)
    if not pinfo.visited then
        if frame_state[pinfo.number] == nil then
            frame_state[pinfo.number] = { [here] = pending[here], [back] = pending[back] }
        end
        return pending
    end
    local noted = frame_state[pinfo.number] or {}
    return { [here] = noted[here], [back] = noted[back] }
end

-- an answered message leaves the table (the live one keeps its count)
local function clear_pending(state, key)
    if state[key] ~= nil and state == pending then
        pending_count = pending_count - 1
    end
    state[key] = nil
end

-- a message waits for its answer; false when max_pending messages already wait
local function set_pending(key, rec)
    if pending[key] == nil then
        if pending_count >= bb.prefs.max_pending then
            return false
        end
        pending_count = pending_count + 1
    end
    pending[key] = rec
    return true
end

-- ---------------------------------------------------------------------------------------------
-- text messages

-- the offset of the first match of a Lua pattern (one character long) in [off, stop), or nil;
-- read in windows that double, so the bytes copied are linear in the distance to the match
local function find_byte(tvb, off, stop, pattern)
    local i, w = off, 64
    while i < stop do
        local len = math.min(w, stop - i)
        local k = string.find(tvb:raw(i, len), pattern)
        if k then
            return i + k - 1
        end
        i, w = i + len, w * 2
    end
    return nil
end

-- the first CR in [off, stop), or nil
local function find_cr(tvb, off, stop)
    return find_byte(tvb, off, stop, "\r")
end

-- the hex digits between off + 1 and text_end decoded; every bad character flagged (the first
-- few, then the count). Returns the bytes and the number of bad characters
local function decode_hex(tvb, t, off, text_end, ndig)
    local bytes = {}
    local bad = 0
    local function flag(pos)
        bad = bad + 1
        if bad <= 8 then -- the first few (each its byte, at its place); the count after
            t:add(pf.non_hex, tvb:range(pos, 1)):add_proto_expert_info(ex.non_hex)
        end
    end
    local i = off + 1
    while i + 1 < text_end do
        local a, b = hexval(u8(tvb, i)), hexval(u8(tvb, i + 1))
        if a == nil then
            flag(i)
        end
        if b == nil then
            flag(i + 1)
        end
        bytes[#bytes + 1] = (a or 0) * 16 + (b or 0)
        i = i + 2
    end
    if ndig > 0 and ndig % 2 == 1 then
        if hexval(u8(tvb, text_end - 1)) == nil then
            flag(text_end - 1)
        end
        t:add_proto_expert_info(ex.odd)
    end
    if bad > 8 then
        local ci = t:add(pf.non_hex_count, bad)
        ci:set_generated()
        ci:add_proto_expert_info(ex.non_hex, "Non-hex characters past the first 8")
    end
    return bytes, bad
end

-- the terminator (CR and an LF with it), added last, after the fields it ends
local function add_terminator(tvb, t, m, over_limit)
    if m.cr == nil then
        if m.capture_end then
            t:add_proto_expert_info(ex.no_cr, "Message not ended by CR: the capture ends before it")
        else
            t:add_proto_expert_info(ex.no_cr)
        end
        if over_limit then
            t:add_proto_expert_info(ex.limit, "Limit exceeded: over " .. istr(bb.prefs.max_held_bytes)
                .. " bytes without a CR (blackboard.max_held_bytes): not held for more segments")
        end
    else
        t:add(pf.terminator, tvb:range(m.cr, m.used - (m.cr - m.off)))
    end
end

-- the checksum (last byte) of a message at r; returns the status (1 good, 0 bad) and the byte
local function add_checksum(t, r, bytes)
    local sum = 0
    for k = 1, #bytes - 1 do
        sum = sum + bytes[k]
    end
    local calc = BB.checksum_of(sum)
    local written = bytes[#bytes]
    local cki = t:add(pf.checksum, r, written)
    t:add(pf.checksum_calc, r, calc):set_generated()
    local status = 1
    if written ~= calc then
        status = 0
        cki:append_text(" [incorrect, should be 0x" .. hex2(calc) .. "]")
        cki:add_proto_expert_info(ex.checksum_bad)   -- (blackboard.checksum and .calculated)
    else
        cki:append_text(" [correct]")
    end
    t:add(pf.checksum_status, r, status):set_generated()
    return status, written
end

-- count, address, node, data and checksum of a message whose hex decoded well; returns its
-- summary and whether it is good (checksum right, count matching its length)
local function add_fields(tvb, t, m)
    local bytes, off = m.bytes, m.off
    -- byte k of the message is at hex offset off + 1 + 2 (k - 1)
    local function brange(k, n)
        return tvb:range(off + 1 + 2 * (k - 1), 2 * n)
    end
    local count = bytes[1]
    local address = bytes[2] * 256 + bytes[3]
    local node = bytes[4]
    local ci = t:add(pf.count, brange(1, 1), count)
    t:add(pf.address, brange(2, 2), address)
    t:add(pf.node, brange(4, 1), node)
    local need = (m.kind == SET) and 5 + count or 5
    if #bytes ~= need then
        ci:add_proto_expert_info(ex.count_bad)   -- (the count in blackboard.count, the bytes in the hex text)
    end
    local ndata = #bytes - 5
    if m.kind == SET and ndata > 0 then
        -- the decoded data as a tvb of its own (a "Decoded data" tab), so the field holds bytes
        local parts = {}
        for k = 5, 4 + ndata do
            parts[#parts + 1] = hex2(bytes[k])
        end
        local dtvb = ByteArray.new(table.concat(parts, "")):tvb("Decoded data")
        t:add(pf.data, dtvb:range(0, ndata))
    end
    local status, written = add_checksum(t, brange(#bytes, 1), bytes)
    m.written, m.count, m.status = written, count, status
    local what = (m.kind == SET) and ("set " .. istr(ndata)) or ("request " .. istr(count))
    local summary = what .. " bytes at 0x" .. string.format("%04X", address) .. " node " .. istr(node)
    if status == 0 then
        summary = summary .. " [bad checksum]"
    end
    return summary, status == 1 and #bytes == need
end

-- the previous message the same way still waiting: repeated (the same text) or left unanswered
local function note_previous(tvb, t, m, prev, summary)
    if prev == nil then
        return summary
    end
    if prev.text == m.hextext then
        t:add(pf.repeat_of, tvb:range(m.off, 1), prev.frame):set_generated()
        t:add_proto_expert_info(ex.repeat_msg)   -- (the frame: blackboard.repeat_of)
        return summary .. " [repeat]"
    end
    t:add(pf.unanswered_in, tvb:range(m.off, 1), prev.frame):set_generated()
    t:add_proto_expert_info(ex.unanswered)
    return summary
end

-- a good message waits for its answer from the other side (back); on a later pass, where it
-- was answered
local function remember(tvb, pinfo, t, m, back)
    local mkey = istr(pinfo.number) .. ":" .. istr(m.off)
    if not pinfo.visited then
        -- what the answer must be (BB.expectation: a read response's checksum covers the
        -- request's count, address and node bytes)
        local e = BB.expectation(tvb:raw(m.off, m.cr - m.off + 1), 1, m.cr - m.off + 1)
        local rec = { kind = m.name, frame = pinfo.number, checksum = e.checksum, count = m.count, sum = e.sum,
            text = m.hextext }
        if set_pending(back, rec) then
            messages[mkey] = rec
        else
            not_held[mkey] = true
        end
    end
    if not_held[mkey] then
        t:add_proto_expert_info(ex.limit, "Limit exceeded: " .. istr(bb.prefs.max_pending)
            .. " messages already wait for an answer (blackboard.max_pending); this one's answer is not looked for")
    end
    if pinfo.visited then
        local rec = messages[mkey]
        if rec ~= nil and rec.answered then
            t:add(pf.response_in, tvb:range(m.off, 1), rec.answered):set_generated()
        end
    end
end

-- link health (issue 43 on blackboard links): each message (master) and answer (slave) goes to
-- SharedLink's health module when sharedlink.lua is loaded (the definition is written once there:
-- dissector/sharedlink/health.lua, H.robot); the first one after an outage gets the expert
-- blackboard.outage and the generated blackboard.outage.duration.  Without sharedlink.lua: nothing.
local function link_health(tvb, pinfo, t, off, side, status)
    local health = package.loaded["sharedlink.health"]
    if type(health) ~= "table" or not health.robot then return end
    local gone = health.robot(pinfo, istr(off) .. "/" .. istr(tvb:len()), "blackboard", side, status)
    if gone then health.mark(t, nil, gone, pf.outage_duration, ex.outage) end
end

-- a text message at off (type character there); stop is the end of the buffer.
-- Returns: bytes used and the summary, or nil when the CR is not there yet and more may come
local function dissect_text(tvb, pinfo, tree, off, stop, state, can_more, over_limit, capture_end)
    local cr = find_cr(tvb, off + 1, stop)
    if cr == nil and can_more then
        return nil
    end
    local text_end = cr or stop
    local m = { off = off, cr = cr, kind = u8(tvb, off), used = text_end - off, ndig = text_end - off - 1,
        capture_end = capture_end }
    if cr then
        m.used = m.used + 1
        if cr + 1 < stop and u8(tvb, cr + 1) == LF then
            m.used = m.used + 1
        end
    end
    local t = tree:add(bb, tvb:range(off, m.used))
    m.name = (m.kind == SET) and "set" or "request"
    t:add(pf.type, tvb:range(off, 1), m.name)
    t:add(pf.type_char, tvb:range(off, 1))
    if m.ndig > 0 then
        t:add(pf.hex, tvb:range(off + 1, m.ndig))
    end
    local bad
    m.bytes, bad = decode_hex(tvb, t, off, text_end, m.ndig)
    if bad > 0 or m.ndig % 2 == 1 or #m.bytes < 5 then
        if #m.bytes < 5 and bad == 0 and m.ndig % 2 == 0 then
            t:add_proto_expert_info(ex.short)   -- (its bytes: blackboard.hex)
        end
        add_terminator(tvb, t, m, over_limit)
        -- a malformed message is a message: it keeps its side's link alive, no checksum verdict
        -- (docs/fields-p2os-blackboard.md, "Malformed messages")
        link_health(tvb, pinfo, t, off, "master", nil)
        t:append_text(", " .. m.name .. " (malformed)")
        return m.used, m.name .. " (malformed)"
    end
    local summary, good = add_fields(tvb, t, m)
    link_health(tvb, pinfo, t, off, "master", m.status)
    -- conversation: a good message waits for its answer from the other side
    local _, back = keys(pinfo)
    m.hextext = m.ndig > 0 and tvb:range(off, 1 + m.ndig):string() or ""
    summary = note_previous(tvb, t, m, state[back], summary)
    if good and cr then   -- a message with no CR is malformed: it waits for no answer
        remember(tvb, pinfo, t, m, back)
    end
    add_terminator(tvb, t, m, over_limit)
    t:append_text(", " .. summary)
    return m.used, summary
end

-- a binary answer to rec at off; returns bytes used, summary (nil, need when more is needed)
local function dissect_binary(tvb, pinfo, tree, off, stop, rec, can_more)
    local want = 1
    if rec.kind == "request" then
        want = rec.count + 1
    end
    local have = stop - off
    if have < want and can_more then
        return nil, want - have
    end
    local n = want
    if have < n then
        n = have
    end
    local t = tree:add(bb, tvb:range(off, n))
    -- the link to the request goes last, after the answer's own fields
    local function add_request_link()
        t:add(pf.request_in, tvb:range(off, n), rec.frame):set_generated()
    end
    if not pinfo.visited then
        rec.answered = pinfo.number
    end
    local summary
    if rec.kind == "set" then
        t:add(pf.type, tvb:range(off, 1), "ack")
        local a = u8(tvb, off)
        local ai = t:add(pf.ack, tvb:range(off, 1))
        local status = 1
        if a ~= rec.checksum then
            status = 0
            t:add(pf.ack_expected, tvb:range(off, 1), rec.checksum):set_generated()
            ai:add_proto_expert_info(ex.ack_bad)   -- (the set message: blackboard.request_in)
        end
        t:add(pf.checksum_status, tvb:range(off, 1), status):set_generated()
        link_health(tvb, pinfo, t, off, "slave", status)
        summary = "ack 0x" .. hex2(a) .. ((status == 1) and "" or " [wrong]")
    else
        t:add(pf.type, tvb:range(off, n), "response")
        if have < want then
            t:add_proto_expert_info(ex.response_short)   -- (what it asked: the request's blackboard.count)
            if n > 0 then
                t:add(pf.data, tvb:range(off, n))
            end
            add_request_link()
            return n, "response (truncated)"
        end
        local calc = BB.response_checksum(rec.sum, rec.count > 0 and tvb:raw(off, rec.count) or "", 1, rec.count)
        if rec.count > 0 then
            t:add(pf.data, tvb:range(off, rec.count))
        end
        local cr = tvb:range(off + rec.count, 1)
        local written = cr:uint()
        local ci = t:add(pf.checksum, cr)
        t:add(pf.checksum_calc, cr, calc):set_generated()
        local status = 1
        if written ~= calc then
            status = 0
            ci:add_proto_expert_info(ex.response_bad)   -- (blackboard.checksum and .calculated)
        end
        t:add(pf.checksum_status, cr, status):set_generated()
        link_health(tvb, pinfo, t, off, "slave", status)
        summary = "response " .. istr(rec.count) .. " bytes" .. ((status == 1) and "" or " [bad checksum]")
    end
    add_request_link()
    t:append_text(", " .. summary)
    return n, summary
end

-- whether a complete, valid text message with a good checksum starts at off (used to tell a
-- message, a side talking or a master repeating itself, from the binary answer awaited there)
local function valid_text_at(tvb, off, stop)
    local kind = u8(tvb, off)
    if kind ~= SET and kind ~= REQUEST then
        return false
    end
    local limit = stop
    if limit > off + BB.MAX_TEXT then
        limit = off + BB.MAX_TEXT -- bounded: callers may ask at every byte
    end
    local cr = find_cr(tvb, off + 1, limit)
    if cr == nil then
        return false
    end
    local valid, good = BB.check(tvb:raw(off, cr - off + 1), 1, cr - off + 1)
    return valid and good
end

-- bytes outside any message, from off up to j
local function add_junk(tvb, tree, off, j, infos)
    local item = tree:add(pf.junk, tvb:range(off, j - off))
    if not string.find(tvb:raw(off, j - off), "[^\r\n]") then
        item:append_text(" (line ends)")
    else
        item:add_proto_expert_info(ex.unexpected)
        infos[#infos + 1] = "bytes outside any message"
    end
    return j
end

-- bytes outside any message, up to the next type character (or the end); returns where it is
local function dissect_junk(tvb, tree, off, n, infos)
    return add_junk(tvb, tree, off, find_byte(tvb, off + 1, n, "[:;]") or n, infos)
end

-- where the message a type character at off begins starts: the last ':' or ';' before the CR
-- after it (the rule of serial.lua and the Python readers, docs/fields-p2os-blackboard.md: the
-- text before it is outside any message); off when there is no CR yet or no other one before it
local function message_start(tvb, off, n)
    local cr = find_cr(tvb, off + 1, n)
    if not cr then return off end
    return off - 1 + BB.message_start(tvb:raw(off, cr - off), 1, cr - off + 1)
end

-- text the capture ends before its CR (TCP; docs/fields-p2os-blackboard.md): on the first pass
-- a call in a direction clears its note (more segments came) and a message still waiting for
-- its CR notes the frame; a later pass shows the text of the frame noted last, not ended by CR
local function ends_capture(pinfo, here)
    if not pinfo.visited then
        waiting_cr[here] = nil
        return false
    end
    return pinfo.can_desegment > 0 and waiting_cr[here] == pinfo.number
end

local function note_waiting(pinfo, here)
    if not pinfo.visited then
        waiting_cr[here] = pinfo.number
    end
end

-- the answers serial.lua framed in the bytes it hands over (pinfo.private "slserial.answers",
-- "offset:length" pairs from 0): offset -> length; nil for bytes not from serial.lua. On a serial
-- line serial.lua's framing decides where an answer is (it holds one until whole, and knows
-- which bytes came before the message it answers: docs/serial-capture-format.md)
local function serial_answers(pinfo)
    local text = pinfo.private["slserial.answers"]
    if text == nil then return nil end
    local t = {}
    for a, l in string.gmatch(text, "(%d+):(%d+)") do
        t[tonumber(a)] = tonumber(l)
    end
    return t
end

-- where text or junk at off may run to: the next answer serial.lua framed, else n
local function answer_stop(answers, off, n)
    local stop = n
    for a in pairs(answers) do
        if a > off and a < stop then stop = a end
    end
    return stop
end

-- whether the bytes at off are the awaited answer (rec): where serial.lua framed one, else
-- anything but a complete, valid message (the side talks instead of answering:
-- docs/fields-p2os-blackboard.md, "Both directions"; the Python reader too)
local function is_answer(tvb, off, n, rec, answers)
    if rec == nil then return false end
    if answers then return answers[off] ~= nil end
    return not valid_text_at(tvb, off, n)
end

local NO_ANSWERS = {}

local function dissect_buffer(tvb, pinfo, tree)
    local n = tvb:len()
    if n == 0 then
        return 0
    end
    pinfo.cols.protocol = "Blackboard"
    local state = state_for(pinfo)
    local here = keys(pinfo)
    local capture_end = ends_capture(pinfo, here)
    local can_more = pinfo.can_desegment > 0 and not capture_end
    local infos = {}
    local answers = serial_answers(pinfo)
    local off = 0
    while off < n do
        local c = u8(tvb, off)
        local rec = state[here]
        local stop = answer_stop(answers or NO_ANSWERS, off, n)
        if is_answer(tvb, off, n, rec, answers) then
            local used, summary = dissect_binary(tvb, pinfo, tree, off, n, rec, can_more)
            if used == nil then
                pinfo.desegment_offset = off
                pinfo.desegment_len = summary
                break
            end
            clear_pending(state, here)
            infos[#infos + 1] = summary
            off = off + used
        elseif (c == SET or c == REQUEST) and message_start(tvb, off, stop) > off then
            off = add_junk(tvb, tree, off, message_start(tvb, off, stop), infos)
        elseif c == SET or c == REQUEST then
            -- a message without its CR is held for more segments up to max_held_bytes
            local more = can_more and n - off <= bb.prefs.max_held_bytes
            local used, summary = dissect_text(tvb, pinfo, tree, off, stop, state, more, can_more and not more,
                capture_end)
            if used == nil then
                pinfo.desegment_offset = off
                pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
                note_waiting(pinfo, here)
                break
            end
            infos[#infos + 1] = summary
            off = off + used
        else
            off = dissect_junk(tvb, tree, off, stop, infos)
        end
    end
    if #infos > 0 then
        pinfo.cols.info = table.concat(infos, "; ")
    end
    return n
end


-- heuristic: a valid message with a good checksum, or the answer a pending request expects
local function heuristic(tvb, pinfo, tree)
    local n = tvb:len()
    if n < 1 then
        return false
    end
    local ok = valid_text_at(tvb, 0, n)
    if not ok then
        local here = keys(pinfo)
        local rec
        if pinfo.visited then
            rec = (frame_state[pinfo.number] or {})[here]
        else
            rec = pending[here]
        end
        if rec == nil then
            return false
        end
        local want = 1
        if rec.kind == "request" then
            want = rec.count + 1
        end
        if n ~= want and pinfo.can_desegment == 0 then
            return false
        end
    end
    dissect_buffer(tvb, pinfo, tree)
    -- the rest of this conversation comes straight here (where the version allows)
    pcall(function()
        pinfo.conversation = bb
    end)
    return true
end

D.dissector = dissect_buffer
D.heuristic = heuristic
return D
