-- Serial link dispatcher for Wireshark (Lua): SharedLink, P2OS and blackboard traffic captured
-- from a serial line.
--
-- Capture format (docs/serial-capture-format.md): pcapng, a USER link type (default
-- LINKTYPE_USER0 = 147; preference "USER link type"), one record per chunk of bytes as read
-- from the line, the direction in the EPB flags (inbound / outbound; Wireshark turns them
-- into pinfo.p2p_dir).
--
-- Each direction (of each interface with SHAREDLINK_SERIAL_INTERFACES=1: see dirs) is a byte
-- stream. On the first pass the stream is cut into frames (and the noise between them) by
-- the protocol's framing rules; a frame split across records is held back until its last
-- byte arrives and shown in that record as a reassembled data source with links to the
-- records it came from. The bytes completed in a record are handed, in one
-- call, to the protocol's own dissector by name (Dissector.get("sharedlink" / "p2os" /
-- "blackboard"), looked up at dissection time); when that dissector is not loaded the bytes
-- are shown as data.
--
-- Protocol per direction: the "Protocol" preference, or "auto": the first protocol with a
-- frame with a correct checksum in the bytes seen (a direction with none of its own, e.g. a
-- blackboard slave's binary answers, takes another direction's protocol once it holds 64
-- bytes). The framing rules are those of the Python reader
-- (sharedlink.serialcap), so both find the same frames whatever the chunking:
--  * SharedLink: a frame runs from the last "[" before a "]" to that "]", and takes a CR LF
--    after it; a "[...]" that is not a frame (no ":DS" header) is noise. A frame whose "]"
--    is the last byte seen (or "]" CR) waits for the next bytes (its CR LF).
--  * P2OS: FA FB, count, count bytes; a count below 2 is noise; a truncated packet waits; a
--    header cut off before a packet is noise up to the next FA FB starting inside its claimed
--    span (its FA may be the span's last byte) that starts a whole packet with a good checksum
--    (robots/p2os_rules.lua, R.resync_at).
--  * Blackboard: ":" or ";" (the last one before the CR), hex digits, CR, and an LF if it
--    came with the CR (a message does not wait for one); text that does not parse is noise.
--    Binary answers (as the Python session reader reads them): a good message in one direction
--    makes the other expect its answer (1 byte for a set, count + 1 for a request), held until
--    whole and handed over as one answer (slserial.answer), whether or not that direction
--    talks too; a whole message where the answer would be is that message, the answer still
--    expected after it; blackboard.lua reads answers only where this framing put them
--    (pinfo.private "slserial.answers"). A direction not yet recognised whose first bytes are
--    a right answer is blackboard's. An answer is matched only when its message's record comes first.
-- An unfinished frame longer than the max_held_bytes preference (65536) is given up as noise,
-- with a "Limit exceeded" warning. A record that only lengthens an unfinished frame is appended
-- to the held bytes without scanning them again (linear time for a frame sent byte by byte).
--
-- What the GUI shows: the Source and Destination columns name the direction ("device" ->
-- "host" for inbound bytes, "host" -> "device" for outbound ones); a record that only holds
-- bytes of an unfinished frame says so in one Info line ("[26 bytes held, part of a SharedLink
-- frame completed in record 14]") and one tree row; the record that completes a frame names the
-- protocol in its tree and shows Wireshark's fragment subtree, as TCP and IP do ("[3 Reassembled
-- fragments (52 bytes): #12(26), #13(18), #14(8)]", one "[Frame: N, payload: a-b (n bytes)]" row
-- per record, the count and the length).
--
-- Works with Wireshark 4.0 (Lua 5.2) and later. Needs robots/p2os_rules.lua and
-- robots/blackboard_rules.lua beside it: the P2OS framing rules, written once for this file and
-- p2os.lua, and the blackboard message rules, once for this file and blackboard.lua
-- (tests/dissector/test_lua_twins.py runs them beside the Python readers'), and
-- robots/serial_dissect.lua, its dissection, run on the first serial record.
-- File order (../shared/STYLE.md): header, plugin info, Proto and tables, fields and experts,
-- preferences, the interface field, the dissection (robots/serial_dissect.lua: state, helpers
-- (framing), first pass, display), registration.

-- luacheck: read globals set_plugin_info

if set_plugin_info then
    set_plugin_info({
        version = "1.3.0",
        description = "Serial link captures (pcapng, USER link type): SharedLink, P2OS and blackboard",
        author = "SharedLink analyzer project",
        repository = "dissector/serial.lua",
    })
end

local slserial = Proto("slserial", "Serial link")

-- The P2OS and blackboard rules (robots/p2os_rules.lua, robots/blackboard_rules.lua beside this
-- file, run by dissection() below with the dissection; copies of our own: no state shared with
-- p2os.lua or blackboard.lua)
local HERE = (debug.getinfo(1, "S").source or ""):match("^@(.*[/\\])") or ""
-- robots/NAME.lua beside this file, compiled (Wireshark's loadfile raises where Lua's returns nil
-- and the reason)
local function robot_chunk(name)
    local ok, chunk, err = pcall(loadfile, HERE .. "robots/" .. name .. ".lua")
    if not ok or not chunk then
        err = tostring(ok and err or chunk)
        error("serial.lua needs robots/" .. name .. ".lua beside it (plugins install copies it): " .. err)
    end
    return chunk
end
local function rules(name)
    return robot_chunk(name)({ robot_module = true })
end
robot_chunk("p2os_rules")   -- (compiled and dropped: they are there and parse)
robot_chunk("blackboard_rules")
local tonumber, pcall = tonumber, pcall

local MAX_HELD_DEFAULT = 65536
local USER0 = (wtap_encaps and wtap_encaps.USER0) or 45 -- luacheck: read globals wtap_encaps

------------------------------------------------------------------------------
-- Fields, expert infos, preferences
------------------------------------------------------------------------------
local hf = {
    direction = ProtoField.int8("slserial.direction", "Direction", base.DEC,
        { [-1] = "unknown", [0] = "outbound", [1] = "inbound" }),
    protocol = ProtoField.string("slserial.protocol", "Protocol"),
    frame = ProtoField.bytes("slserial.frame", "Frame"),
    answer = ProtoField.bytes("slserial.answer", "Answer (blackboard, binary)"),
    noise = ProtoField.bytes("slserial.noise", "Noise"),
    held = ProtoField.bytes("slserial.held", "Held back (unfinished frame)"),
    completed_in = ProtoField.framenum("slserial.completed_in", "Completed in record", base.NONE),
    fragments = ProtoField.none("slserial.fragments", "Reassembled fragments"),
    fragment = ProtoField.framenum("slserial.fragment", "Frame", base.NONE),
    fragment_count = ProtoField.uint32("slserial.fragment.count", "Fragment count", base.DEC),
    reassembled_length = ProtoField.uint32("slserial.reassembled.length", "Reassembled length", base.DEC),
    frames = ProtoField.uint32("slserial.frames", "Frames completed", base.DEC),
}
local field_list = {}
for _, f in pairs(hf) do
    field_list[#field_list + 1] = f
end
slserial.fields = field_list

local ei = {
    noise = ProtoExpert.new("slserial.noise.skipped", "Bytes outside any frame",
        expert.group.PROTOCOL, expert.severity.NOTE),
    undetected = ProtoExpert.new("slserial.undetected", "Protocol not recognised",
        expert.group.UNDECODED, expert.severity.NOTE),
    missing = ProtoExpert.new("slserial.dissector.missing", "Protocol dissector not loaded",
        expert.group.UNDECODED, expert.severity.WARN),
    limit = ProtoExpert.new("slserial.limit", "Limit exceeded", expert.group.PROTOCOL, expert.severity.WARN),
}
local expert_list = {}
for _, e in pairs(ei) do
    expert_list[#expert_list + 1] = e
end
slserial.experts = expert_list

local linktype_enum = {}
for i = 0, 15 do
    linktype_enum[#linktype_enum + 1] = { i + 1, "user" .. i, i }
end
local protocol_enum = { { 1, "auto", 0 }, { 2, "sharedlink", 1 }, { 3, "p2os", 2 }, { 4, "blackboard", 3 } }

slserial.prefs.user_linktype = Pref.enum("USER link type", 0,
    "LINKTYPE_USERn of serial captures (user0 = 147 ... user15 = 162)", linktype_enum, false)
slserial.prefs.protocol = Pref.enum("Protocol", 0,
    "Protocol on the line; auto: recognised from the first frame with a good checksum", protocol_enum, false)
slserial.prefs.max_held_bytes = Pref.uint("Max held bytes", MAX_HELD_DEFAULT,
    "Bytes of one unfinished frame held back for the next records; past it they are given up as noise")

------------------------------------------------------------------------------
-- State (first pass): per direction stream buffer; per record the result (robots/serial_dissect.lua)
------------------------------------------------------------------------------
-- [stream_key(interface, p2p_dir)] = { held = { strings }, hlen = their length, recs = { {num, s,
-- e}... } (positions in the held bytes: released when their frame completes), proto = name|nil,
-- expect = the answer awaited (BB.expectation, scan_bb_stream), append = whether the next bytes
-- can be appended to the held ones without a scan (see can_append), run = the result the records
-- appended since the last scan share (append_held), iface = the capture interface }
-- A stream is a direction of one interface (stream_key). The documented wslua API gives a
-- dissector a record's interface only through a field extractor (Pinfo has no interface on
-- 4.0-4.6; Field.new is refused once dissection has begun, so it cannot be made on the first
-- serial record), and any field extractor makes Wireshark build a tree for every packet of
-- every capture (tests/dissector/test_stats_tap.py's test_the_tap_costs_nothing_until_asked;
-- +45 % CPU on a summary pass). So it is made on request only: SHAREDLINK_SERIAL_INTERFACES=1 in
-- the environment Wireshark starts from (read at load, the only time Field.new is allowed).
-- Without it the interface is 0 for every record: two serial interfaces whose records interleave
-- in one pcapng share their streams (a known limit, docs/serial-capture-format.md).
local interface_field = os.getenv("SHAREDLINK_SERIAL_INTERFACES") == "1" and Field.new("frame.interface_id") or nil

local function record_interface()
    if not interface_field then return 0 end
    local fi = interface_field()
    return fi and tonumber(fi.value) or 0
end

------------------------------------------------------------------------------
-- The dissection: robots/serial_dissect.lua (the per-direction state, the framing, the first
-- pass, the display), run on the first serial record, so that a capture without one never holds
-- its code (compiled functions are live Lua heap, which the collector walks for every plugin:
-- docs/perf-log.md, 7 December 2026). Compiled once at load as well, so that a missing or
-- broken file says so when Wireshark starts.
------------------------------------------------------------------------------
robot_chunk("serial_dissect")
local D -- the module once run: D.dissector, D.init
local function dissection()
    if not D then
        D = robot_chunk("serial_dissect")({ robot_module = true }, {
            proto = slserial, hf = hf, ei = ei, R = rules("p2os_rules"), BB = rules("blackboard_rules"),
            record_interface = record_interface,
            MAX_HELD_DEFAULT = MAX_HELD_DEFAULT,
        })
    end
    return D
end

-- per-capture state: the module's (none before it runs; it reads the preferences when it does)
function slserial.init()
    if D then D.init() end
end

function slserial.dissector(tvb, pinfo, tree)
    return dissection().dissector(tvb, pinfo, tree)
end


------------------------------------------------------------------------------
-- Registration: wtap_encap table, USER link type from the preference
------------------------------------------------------------------------------
local wtap_table = DissectorTable.get("wtap_encap")
local current_encap, saved_handle

local function apply_linktype()
    local enc = USER0 + (tonumber(slserial.prefs.user_linktype) or 0)
    if enc == current_encap then return end
    if current_encap then
        wtap_table:remove(current_encap, slserial)
        if saved_handle then wtap_table:add(current_encap, saved_handle) end
    end
    local ok, old = pcall(wtap_table.get_dissector, wtap_table, enc)
    saved_handle = ok and old or nil
    wtap_table:add(enc, slserial)
    current_encap = enc
end

function slserial.prefs_changed()
    apply_linktype()
end

apply_linktype()
