-- Blackboard message dissector (Holland, Designing Autonomous Mobile Robots, figures 6.3 and
-- 6.4) for Wireshark 4.0+ (Lua 5.2 .. 5.4).
--
-- Messages are ASCII hex, two characters per byte, ended by CR:
--   :031F0001010203D7<CR>   set data: count, base address (2, big-endian), node, data, checksum
--   ;05E000011A<CR>         request data: count requested, base address, node, checksum
-- Checksum: zero minus the 8-bit sum of the decoded bytes. The slave answers a set message with
-- its checksum as one binary byte, and a request with the data block plus one checksum byte
-- over the data and the request's count, address and node bytes. Binary answers have no
-- framing of their own: they are recognised from the request they answer (the last one sent
-- the other way in the same conversation).
--
-- Transports: any bare byte buffer through Dissector.get("blackboard") (serial captures); UDP
-- and TCP port preferences (off by default: 0); heuristics on UDP and TCP (a well-formed
-- message with a good checksum, or the answer a pending request expects).
--
-- Limits (preferences): max_pending messages waiting for an answer at once, max_held_bytes of a
-- message without its CR held for more TCP segments; past either a "Limit exceeded" warning.
--
-- A message's tree reads in wire order: type, hex text, count, address, node, data, checksum,
-- then its terminator (CR, LF) last.
--
-- Field reference: docs/fields-p2os-blackboard.md. Needs robots/blackboard_rules.lua beside it
-- (the message rules it shares with serial.lua) and robots/blackboard_dissect.lua (its
-- dissection, run on the first packet that needs it); sharedlink plugins install copies them.
-- Twins (code that must exist in two self-contained files; tests/dissector/test_lua_twins.py
-- shows they agree): istr, u8 <-> p2os.lua.
-- File order (../shared/STYLE.md): header, plugin info, Proto and tables, fields and experts,
-- preferences, the twins, the dissection (robots/blackboard_dissect.lua: state, helpers,
-- dissect_*, the buffer dissector, heuristic), registration.

-- luacheck: read globals Proto ProtoField ProtoExpert Pref DissectorTable ByteArray base expert frametype
-- luacheck: read globals DESEGMENT_ONE_MORE_SEGMENT set_plugin_info

if set_plugin_info then
    set_plugin_info({
        version = "1.3.0",
        description = "Blackboard messages (Holland) over serial captures, UDP and TCP",
        author = "SharedLink analyzer project",
        repository = "dissector/blackboard.lua",
    })
end

local bb = Proto("blackboard", "Blackboard message (Holland)")

-- The blackboard message rules (which text is a message, its checksum, where it starts, the
-- answer it expects), written once for this file and serial.lua: robots/blackboard_rules.lua
-- beside this file, run by dissection() below with the dissection (a copy of our own: no state
-- shared with serial.lua).
local HERE = (debug.getinfo(1, "S").source or ""):match("^@(.*[/\\])") or ""
-- robots/NAME.lua beside this file, compiled (Wireshark's loadfile raises where Lua's returns nil
-- and the reason)
local function robot_chunk(name)
    local ok, chunk, err = pcall(loadfile, HERE .. "robots/" .. name .. ".lua")
    if not ok or not chunk then
        err = tostring(ok and err or chunk)
        error("blackboard.lua needs robots/" .. name .. ".lua beside it (plugins install copies it): " .. err)
    end
    return chunk
end
robot_chunk("blackboard_rules")   -- (compiled and dropped: it is there and parses)

local SET, REQUEST, LF = 0x3A, 0x3B, 0x0A

local pf = {
    type = ProtoField.string("blackboard.type", "Message type"),
    type_char = ProtoField.uint8("blackboard.type_char", "Type character", base.HEX,
        { [SET] = "':' set data", [REQUEST] = "';' request data" }),
    hex = ProtoField.string("blackboard.hex", "Hex text"),
    count = ProtoField.uint8("blackboard.count", "Count", base.DEC),
    address = ProtoField.uint16("blackboard.address", "Base address", base.HEX),
    node = ProtoField.uint8("blackboard.node", "Node", base.DEC),
    data = ProtoField.bytes("blackboard.data", "Data"),
    checksum = ProtoField.uint8("blackboard.checksum", "Checksum", base.HEX),
    checksum_calc = ProtoField.uint8("blackboard.checksum.calculated", "Calculated checksum", base.HEX),
    checksum_status = ProtoField.uint8("blackboard.checksum.status", "Checksum status", base.DEC,
        { [0] = "Bad", [1] = "Good", [2] = "Unverified" }),
    terminator = ProtoField.bytes("blackboard.terminator", "Terminator"),
    ack = ProtoField.uint8("blackboard.ack", "Acknowledgement", base.HEX),
    request_in = ProtoField.framenum("blackboard.request_in", "Request in frame", base.NONE, frametype.REQUEST),
    response_in = ProtoField.framenum("blackboard.response_in", "Answered in frame", base.NONE, frametype.RESPONSE),
    repeat_of = ProtoField.framenum("blackboard.repeat_of", "Repeat of frame", base.NONE, frametype.DUP_ACK),
    junk = ProtoField.bytes("blackboard.junk", "Bytes outside any message"),
    outage_duration = ProtoField.double("blackboard.outage.duration", "Outage duration (s)"),
    -- the values of the expert infos, in fields of their own (issue 41: one summary a problem)
    non_hex = ProtoField.uint8("blackboard.non_hex.char", "Non-hex character", base.HEX),
    non_hex_count = ProtoField.uint32("blackboard.non_hex.count", "Non-hex characters in all", base.DEC),
    ack_expected = ProtoField.uint8("blackboard.ack.expected", "Expected acknowledgement (the set message's checksum)",
        base.HEX),
    unanswered_in = ProtoField.framenum("blackboard.unanswered_in", "Unanswered message in frame", base.NONE),
}
local field_list = {}
for _, f in pairs(pf) do
    field_list[#field_list + 1] = f
end
bb.fields = field_list

local ex = {
    checksum_bad = ProtoExpert.new("blackboard.checksum.bad", "Bad checksum", expert.group.CHECKSUM,
        expert.severity.ERROR),
    non_hex = ProtoExpert.new("blackboard.non_hex", "Non-hex character", expert.group.MALFORMED,
        expert.severity.ERROR),
    odd = ProtoExpert.new("blackboard.odd_digits", "Odd number of hex digits", expert.group.MALFORMED,
        expert.severity.ERROR),
    short = ProtoExpert.new("blackboard.too_short", "Message too short", expert.group.MALFORMED,
        expert.severity.ERROR),
    count_bad = ProtoExpert.new("blackboard.count.wrong", "Count does not match the message length",
        expert.group.MALFORMED, expert.severity.ERROR),
    no_cr = ProtoExpert.new("blackboard.no_cr", "Message not ended by CR", expert.group.MALFORMED,
        expert.severity.ERROR),
    ack_bad = ProtoExpert.new("blackboard.ack.wrong", "Acknowledgement does not match the set message's checksum",
        expert.group.SEQUENCE, expert.severity.ERROR),
    response_bad = ProtoExpert.new("blackboard.response.checksum.bad", "Bad read response checksum",
        expert.group.CHECKSUM, expert.severity.ERROR),
    response_short = ProtoExpert.new("blackboard.response.truncated", "Read response truncated",
        expert.group.MALFORMED, expert.severity.ERROR),
    unexpected = ProtoExpert.new("blackboard.unexpected",
        "Bytes outside any message (and no request waiting for an answer)",
        expert.group.SEQUENCE, expert.severity.WARN),
    repeat_msg = ProtoExpert.new("blackboard.repeat", "Repeated message: no acknowledgement seen",
        expert.group.SEQUENCE, expert.severity.NOTE),
    unanswered = ProtoExpert.new("blackboard.unanswered", "Request superseded before an answer",
        expert.group.SEQUENCE, expert.severity.NOTE),
    limit = ProtoExpert.new("blackboard.limit", "Limit exceeded", expert.group.PROTOCOL, expert.severity.WARN),
    outage = ProtoExpert.new("blackboard.outage", "Link silent", expert.group.SEQUENCE, expert.severity.WARN),
}
local expert_list = {}
for _, e in pairs(ex) do
    expert_list[#expert_list + 1] = e
end
bb.experts = expert_list

-- ---------------------------------------------------------------------------------------------
-- preferences and per-capture state

bb.prefs.udp_port = Pref.uint("UDP port", 0, "UDP port carrying blackboard messages (0: none, heuristic only)")
bb.prefs.tcp_port = Pref.uint("TCP port", 0, "TCP port carrying blackboard messages (0: none, heuristic only)")
bb.prefs.max_pending = Pref.uint("Max pending messages", 1024,
    "Messages waiting for an answer at once, all conversations together (each direction holds one); "
    .. "past it a message's answer is not looked for")
bb.prefs.max_held_bytes = Pref.uint("Max held bytes", 65536,
    "Bytes of one message without its CR held for more TCP segments; past it the message is shown unended")

-- ---------------------------------------------------------------------------------------------
-- helpers (every tvb access checked against the length first)

-- <twin: p2os.lua istr>
local function istr(n)
    return tostring(math.floor(n))
end

-- <twin: p2os.lua u8>
local function u8(tvb, off)
    return tvb:range(off, 1):uint()
end

-- ---------------------------------------------------------------------------------------------
-- the dissection: robots/blackboard_dissect.lua (the conversation state, the other helpers, the
-- message dissectors, the buffer dissector, the heuristic), run on the first packet that needs
-- it, so that a capture without blackboard messages never holds its code (compiled functions
-- are live Lua heap, which the collector walks for every plugin: docs/perf-log.md, 7 December
-- 2026). Compiled once at load as well, so that a missing or broken file says so when Wireshark
-- starts.

robot_chunk("blackboard_dissect")
local D -- the module once run: D.dissector, D.heuristic, D.init
local function dissection()
    if not D then
        D = robot_chunk("blackboard_dissect")({ robot_module = true }, {
            BB = robot_chunk("blackboard_rules")({ robot_module = true }),
            proto = bb, pf = pf, ex = ex, istr = istr, u8 = u8, SET = SET, REQUEST = REQUEST, LF = LF,
        })
    end
    return D
end

-- per-capture state: the module's (none before it runs)
function bb.init()
    if D then D.init() end
end

function bb.dissector(tvb, pinfo, tree)
    return dissection().dissector(tvb, pinfo, tree)
end

-- heuristic (robots/blackboard_dissect.lua): before the module runs no request waits for an
-- answer, so only a message (":" or ";" first) can be blackboard
local function heuristic(tvb, pinfo, tree)
    if not D and (tvb:len() < 1 or (u8(tvb, 0) ~= SET and u8(tvb, 0) ~= REQUEST)) then
        return false
    end
    return dissection().heuristic(tvb, pinfo, tree)
end

bb:register_heuristic("udp", heuristic)
bb:register_heuristic("tcp", heuristic)

local registered = { udp = 0, tcp = 0 }
local function register_ports()
    for _, proto in ipairs({ "udp", "tcp" }) do
        local want = bb.prefs[proto .. "_port"]
        if registered[proto] ~= want then
            local t = DissectorTable.get(proto .. ".port")
            if registered[proto] ~= 0 then
                t:remove(registered[proto], bb)
            end
            if want ~= 0 then
                t:add(want, bb)
            end
            registered[proto] = want
        end
    end
end

function bb.prefs_changed()
    register_ports()
end

register_ports()
