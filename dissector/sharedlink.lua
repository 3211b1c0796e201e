-- SharedLink protocol dissector for Wireshark (Lua).
--
-- SharedLink (Kairos Autonomi BUL-009 / BUL-049) is a line protocol:
--   [:<dst><src>|<field>|<field>|...|C<xx>]<CR><LF>
-- dst/src are letters A..P (nodes 1..16).  Every field starts with a type letter
-- (N ordinal, T type, Q name/query, R reply, D data, C checksum, L inbound
-- declaration, E command, M mode, P ping, G pong).  The checksum is the sum of the
-- bytes from ':' through the 'C' of the checksum field, modulo 256, in hex.
--
-- Install: copy this single file into your personal Lua plugins folder
-- (Help > About Wireshark > Folders > Personal Lua Plugins), or run
--   tshark -X lua_script:/path/to/sharedlink.lua ...
--
-- Works with Wireshark 4.0 (Lua 5.2) and later (Lua 5.4).
--
-- Preferences (tshark -o name:value):
--   sharedlink.ports              UDP/TCP port range always decoded (default 7013)
--   sharedlink.heuristic          try the heuristic on other ports (default TRUE)
--   sharedlink.validate_checksum  compute and check the checksum (default TRUE)
--   sharedlink.variables          a-priori list naming positional values, NAME or NAME:TYPE
--                                 (0 long, 2 double, 4 string; default
--                                 AutoGpsLat,AutoGpsLon,AutoGpsHead,AutoGpsVel, untyped)
--   sharedlink.sync_interval      expected full-frame interval in ms (default 1000)
--   sharedlink.max_slots, max_names, max_conversations, max_pending, max_held_bytes
--                                 limits (1024, 4096, 65536, 1024, 65536): input past one is
--                                 dropped with sharedlink.limit.exceeded ("Limits" in
--                                 docs/fields-sharedlink.md)
-- Heuristic dissectors (Enabled Protocols / --disable-heuristic): sharedlink_udp,
-- sharedlink_tcp.
--
-- Fields beyond the core set: sharedlink.var (one subtree per variable),
-- sharedlink.inbound_ordinal (L), sharedlink.command / .command.arg (E and its D
-- arguments), sharedlink.mode (M), sharedlink.ping (P), sharedlink.pong (G),
-- sharedlink.field.letter / .field.text (unknown fields), sharedlink.noise (bytes
-- between frames), sharedlink.checksum.text (a checksum that is not a hex byte),
-- sharedlink.sync.is_late (generated boolean: the sync.late condition, for taps/filters).
-- Expert infos beyond the core set: sharedlink.checksum.missing (warning),
-- sharedlink.var.badvalue (warning: value/type/ordinal not matching its type),
-- sharedlink.crlf.missing (note), sharedlink.noise.skipped (note),
-- sharedlink.reply.unmatched (note: a reply with no query seen before it).
--
-- Query/reply links: a reply links back to its query in any pass; the query's
-- "Response in" needs the reply to have been seen, i.e. a second pass (GUI, tshark -2).
--
-- Performance: with no tree (tshark summary pass) no tree items are built; with a tree
-- nobody sees (-Y, coloring rules, taps) a fast-path frame gets its fields without byte
-- ranges, labels or flags, and a per-variable field no filter references is added once a
-- frame, not once a variable (tree_compact); the fast paths check the checksum as a fixed
-- sum plus the values' sums; a frame with the layout of one of the node pair's recent
-- plain named frames (up to 8: a compressed stream's deltas) is parsed by one anchored
-- pattern, in a shown tree too (the fields' places follow from the layout and the values'
-- lengths), and the express lane (see express) takes such frames in every pass; the shown
-- tree's labels are made once (addresses, protocol line, a correct checksum); every use of
-- Wireshark's internals is in wsapi, checked against the documented API.  Per-frame state
-- is stored only for frames that need it (carried values, late sync, queries/replies);
-- carried-only records are packed as text lines, 256 per Lua string, and the list in use is
-- kept as a per-direction history of changes, so that long compressed captures add few Lua
-- objects (Wireshark runs full Lua garbage collections during a capture).
--
-- Decoding choices (where the bulletins are silent); the full set of rules, shared with
-- the Python tools, is "Decoding rules" in docs/fields-sharedlink.md:
--  * UDP/TCP ports from the "ports" preference (default 7013) are dissected
--    unconditionally; elsewhere the heuristic dissectors "sharedlink_udp" and
--    "sharedlink_tcp" claim a payload only if it starts with "[:" + two letters A-P +
--    "|" or "]", is printable ASCII (or CR, LF, TAB) up to the first "]" and that "]" is followed by
--    CR LF, LF, "[" or the end of the payload (TCP also accepts a frame that is not
--    finished yet).  A claimed conversation skips the heuristic afterwards.
--  * A frame ends at the first "]" after "[:" (BUL-049: a field ends with "|" or "]");
--    CR/LF/TAB before it belong to the value.  A "[:" before that "]" means the first
--    frame is unterminated (malformed).  Bytes between frames are noise.
--  * A frame with no checksum field: status Unverified, expert
--    sharedlink.checksum.missing (warning), not malformed.
--  * A checksum that is not exactly two upper-case hex digits (lower case, one digit)
--    but has the right value is Good with a sharedlink.checksum.format note.
--  * A frame with a bad checksum changes no state (values, lists, names, sync clock);
--    its kind and carried values are judged against the state before it.  A frame
--    with no checksum field counts as good.
--  * sync.late: for full/delta data frames, a warning when the last good full frame in
--    the same conversation (or the first frame seen, at the start of a capture) is
--    older than the sync interval preference plus a fixed slack of 0.5 s.
--  * Direction state (carried values, learnt lists, sync) is keyed on the network
--    addresses + ports + the capture direction (serial) + the SharedLink src/dst
--    letters.  A list learnt from a declaration is also remembered for the letter pair
--    alone, used when the exact endpoints have none (broadcast replies).  Queries,
--    declarations and replies are matched on the letters, the variable name and the
--    (unordered) port pair; a frame of R/D pairs answers a declaration too.
--  * A positional frame is "full" when N is 0 and every slot that held a value before
--    in the conversation has a non-empty D (never-filled slots may stay empty); a
--    named frame is "full" when N is 0 (or absent) and every name sent before in a good
--    frame is present; otherwise "delta".  A named triplet's empty D is an empty value.
--  * Positional values are typed by the declaration (T before Q) or by NAME:TYPE in
--    the variables preference; a value not matching its type gets var.badvalue.
--  * Frame kinds: full, delta, query (also L? / N?), reply, declaration (T/Q pairs
--    after a numeric N/L, no D), command, ping, pong, other (well formed, none of
--    these), malformed (unterminated or bad header: no state update).

-- luacheck: read globals gui_enabled

-- Load guard: the file may be loaded twice (installed, and named with -X lua_script:); the second
-- load would register the protocol again (an error), so it does nothing.
if package.loaded["sharedlink.dissector"] then return end
package.loaded["sharedlink.dissector"] = true

if set_plugin_info then
    set_plugin_info({
        version = "1.3.0",
        description = "SharedLink (Kairos Autonomi BUL-009/BUL-049) dissector",
        repository = "dissector/sharedlink.lua",
    })
end

local sl = Proto("sharedlink", "SharedLink Protocol")

local s_byte, s_sub, s_find, s_format, s_gsub = string.byte, string.sub, string.find, string.format, string.gsub
local s_rep, s_match = string.rep, string.match
local tonumber, tostring, type = tonumber, tostring, type
local floor = math.floor
local t_concat = table.concat

------------------------------------------------------------------------------
-- Fields
------------------------------------------------------------------------------
-- 1 and 3 are not defined by the bulletins: Wireshark shows them as "Unknown (n)"
local type_names = { [0] = "long", [2] = "double", [4] = "string" }
local checksum_status_vals = { [0] = "Bad", [1] = "Good", [2] = "Unverified" }

local hf = {
    dst = ProtoField.string("sharedlink.dst", "Destination"),
    src = ProtoField.string("sharedlink.src", "Source"),
    dst_node = ProtoField.uint8("sharedlink.dst.node", "Destination node", base.DEC),
    src_node = ProtoField.uint8("sharedlink.src.node", "Source node", base.DEC),
    kind = ProtoField.string("sharedlink.kind", "Frame kind"),
    ordinal = ProtoField.uint32("sharedlink.ordinal", "Start ordinal (N)", base.DEC),
    inbound_ordinal = ProtoField.uint32("sharedlink.inbound_ordinal", "Inbound list ordinal (L)", base.DEC),
    ftype = ProtoField.uint8("sharedlink.type", "Type (T)", base.DEC, type_names),
    query = ProtoField.string("sharedlink.query", "Query (Q)"),
    response = ProtoField.string("sharedlink.response", "Reply (R)"),
    var = ProtoField.none("sharedlink.var", "Variable"),
    var_name = ProtoField.string("sharedlink.var.name", "Name"),
    var_index = ProtoField.uint32("sharedlink.var.index", "Index", base.DEC),
    var_value = ProtoField.string("sharedlink.var.value", "Value"),
    var_double = ProtoField.double("sharedlink.var.double", "Double value"),
    var_long = ProtoField.int64("sharedlink.var.long", "Long value", base.DEC),
    var_string = ProtoField.string("sharedlink.var.string", "String value"),
    var_carried = ProtoField.bool("sharedlink.var.carried", "Carried forward"),
    var_carried_from = ProtoField.framenum("sharedlink.var.carried_from", "Value from frame", base.NONE),
    checksum = ProtoField.uint8("sharedlink.checksum", "Checksum", base.HEX),
    checksum_text = ProtoField.string("sharedlink.checksum.text", "Checksum text"),
    checksum_calc = ProtoField.uint8("sharedlink.checksum.calculated", "Calculated checksum", base.HEX),
    checksum_status = ProtoField.uint8("sharedlink.checksum.status", "Checksum status", base.DEC,
        checksum_status_vals),
    response_in = ProtoField.framenum("sharedlink.response_in", "Response in", base.NONE, frametype.RESPONSE),
    response_to = ProtoField.framenum("sharedlink.response_to", "Response to", base.NONE, frametype.REQUEST),
    response_time = ProtoField.relative_time("sharedlink.response_time", "Response time"),
    command = ProtoField.string("sharedlink.command", "Command (E)"),
    command_arg = ProtoField.string("sharedlink.command.arg", "Command argument"),
    mode = ProtoField.string("sharedlink.mode", "Mode (M)"),
    ping = ProtoField.string("sharedlink.ping", "Ping (P)"),
    pong = ProtoField.string("sharedlink.pong", "Pong (G)"),
    field_letter = ProtoField.string("sharedlink.field.letter", "Unknown field letter"),
    field_text = ProtoField.string("sharedlink.field.text", "Unknown field text"),
    noise = ProtoField.bytes("sharedlink.noise", "Noise"),
    -- the sync.late condition as a field (the expert of the same name cannot be read by a tap)
    sync_is_late = ProtoField.bool("sharedlink.sync.is_late", "Sync late"),
}
-- fields and experts are registered by a loop over their keyed tables, in key order
-- (a stable order for tshark -G fields)
local function register(tbl)
    local keys = {}
    for k in pairs(tbl) do keys[#keys + 1] = k end
    table.sort(keys)
    local list = {}
    for i, k in ipairs(keys) do list[i] = tbl[k] end
    return list
end
sl.fields = register(hf)

------------------------------------------------------------------------------
-- Expert infos
------------------------------------------------------------------------------
local ei = {
    checksum_bad = ProtoExpert.new("sharedlink.checksum.bad", "Bad checksum",
        expert.group.CHECKSUM, expert.severity.ERROR),
    checksum_format = ProtoExpert.new("sharedlink.checksum.format",
        "Checksum is not two upper-case hex digits", expert.group.PROTOCOL, expert.severity.NOTE),
    checksum_missing = ProtoExpert.new("sharedlink.checksum.missing", "No checksum field",
        expert.group.PROTOCOL, expert.severity.WARN),
    address_invalid = ProtoExpert.new("sharedlink.address.invalid", "Address is not a letter A-P",
        expert.group.PROTOCOL, expert.severity.WARN),
    field_unknown = ProtoExpert.new("sharedlink.field.unknown", "Unknown field letter",
        expert.group.UNDECODED, expert.severity.NOTE),
    field_empty = ProtoExpert.new("sharedlink.field.empty", "Empty field",
        expert.group.PROTOCOL, expert.severity.NOTE),
    malformed = ProtoExpert.new("sharedlink.malformed", "Malformed frame",
        expert.group.MALFORMED, expert.severity.ERROR),
    sync_late = ProtoExpert.new("sharedlink.sync.late", "No full frame within the sync interval",
        expert.group.SEQUENCE, expert.severity.WARN),
    var_unknown = ProtoExpert.new("sharedlink.var.unknown", "Positional value past the known variable list",
        expert.group.PROTOCOL, expert.severity.WARN),
    var_badvalue = ProtoExpert.new("sharedlink.var.badvalue", "Value does not match its declared type",
        expert.group.PROTOCOL, expert.severity.WARN),
    crlf_missing = ProtoExpert.new("sharedlink.crlf.missing", "Frame not terminated by CR LF",
        expert.group.PROTOCOL, expert.severity.NOTE),
    noise = ProtoExpert.new("sharedlink.noise.skipped", "Bytes outside any frame",
        expert.group.PROTOCOL, expert.severity.NOTE),
    unanswered = ProtoExpert.new("sharedlink.reply.unmatched", "Reply without a matching query",
        expert.group.SEQUENCE, expert.severity.NOTE),
    -- input past one of the limits (docs/fields-sharedlink.md "Limits"): dropped, never allocated
    limit = ProtoExpert.new("sharedlink.limit.exceeded", "Limit exceeded",
        expert.group.PROTOCOL, expert.severity.WARN),
}
sl.experts = register(ei)

------------------------------------------------------------------------------
-- Preferences
------------------------------------------------------------------------------
local DEFAULT_PORTS = "7013"
local DEFAULT_VARS = "AutoGpsLat,AutoGpsLon,AutoGpsHead,AutoGpsVel"
local SYNC_SLACK = 0.5 -- seconds added to the sync interval before sync.late fires

sl.prefs.ports = Pref.range("UDP/TCP ports", DEFAULT_PORTS,
    "Ports always decoded as SharedLink (UDP and TCP)", 65535)
sl.prefs.heuristic = Pref.bool("Try heuristic on other ports", true,
    "Look for SharedLink frames on any UDP/TCP port")
sl.prefs.validate_checksum = Pref.bool("Validate the checksum", true,
    "Compute and compare the frame checksum")
sl.prefs.variables = Pref.string("Positional variable list", DEFAULT_VARS,
    "Comma-separated a-priori variable list naming positional D values (index 0 first)")
sl.prefs.sync_interval = Pref.uint("Sync interval (ms)", 1000,
    "A full frame is expected at least this often per direction (plus 500 ms slack)")
-- Limits (issue 31; the same names and defaults as the Python tools' sharedlink.protocols.limits)
local LIMIT_DEFAULTS = { max_slots = 1024, max_names = 4096, max_conversations = 65536, max_pending = 1024,
    max_held_bytes = 65536 }
sl.prefs.max_slots = Pref.uint("Maximum slot number", LIMIT_DEFAULTS.max_slots,
    "Positional slots, ordinals and declared list entries at or past this number are dropped")
sl.prefs.max_names = Pref.uint("Maximum names a direction holds", LIMIT_DEFAULTS.max_names,
    "New variable names past this many in one direction are dropped")
sl.prefs.max_conversations = Pref.uint("Maximum directions with state", LIMIT_DEFAULTS.max_conversations,
    "Directions past this many keep no state")
sl.prefs.max_pending = Pref.uint("Maximum unanswered queries", LIMIT_DEFAULTS.max_pending,
    "Queries past this many unanswered ones in a conversation are not matched with a reply")
sl.prefs.max_held_bytes = Pref.uint("Maximum bytes held for an unterminated frame", LIMIT_DEFAULTS.max_held_bytes,
    "A TCP frame not terminated within this many bytes is decoded as unterminated")

local pref_list = {}         -- parsed variable list
local pref_validate = true
local pref_heuristic = true
local pref_sync = 1.0 + SYNC_SLACK
-- the limits in use (from the preferences) and the per-capture facts they need: journal (a
-- direction keeps a journal, see journal_start), ndirs (directions with state), npend
-- (unanswered queries a conversation)
local LIM = { journal = false, ndirs = 0, npend = {} }
local function read_limits()
    for k, v in pairs(LIMIT_DEFAULTS) do
        local x = tonumber(sl.prefs[k])
        LIM[k] = (x and x >= 0) and math.floor(x) or v
    end
end

-- "Name:T,Name,..." -> list of names with list.t[i] = type number (0 long, 2 double,
-- 4 string) for the typed ones (twin: pytools sharedlink --variables parser)
local function parse_list(str)
    local list, types = {}, {}
    list.t = types
    if type(str) ~= "string" then return list end
    for item in str:gmatch("[^,]+") do
        local name = item:match("^%s*(.-)%s*$")
        local n, t = name:match("^(.-)%s*:%s*(%d+)$")
        if n and n ~= "" then name = n end
        if name ~= "" then
            list[#list + 1] = name
            if n and n ~= "" then types[#list] = tonumber(t) end
        end
    end
    return list
end

------------------------------------------------------------------------------
-- Per-capture state (reset by init)
------------------------------------------------------------------------------
local dirs          -- direction key -> direction state
local pair_lists    -- "SD" letters -> learnt list
local recs          -- frame number -> { [subkey] = record }
local pending_q     -- query key -> record of the query frame
local dir_cache_key, dir_cache_num, dir_cache_ports -- cache for the current packet
local last_asrc, last_adst, last_pdir, last_akey     -- addresses of the last packet and their key
local shapes        -- node pair -> layouts of its recent plain named frames (fast path), newest first
local MAX_SHAPES = 8
local pshapes       -- node pair -> layout of the last plain positional frame (fast path)
local bshapes       -- node pair -> layout of its last bare frame ([:AB|N0|Cxx], express lane)
-- node pair * 65536 + payload length -> the layout that matched last (express lane), xlen_n entries
local xlen, xlen_n
local stamp_ctr = 0
local cr_pend, cr_npend, cr_npieces, cr_pend_first, cr_store, cr_first  -- packed carried records
local sk_str, sk_str_n       -- frame key -> its text, for them

local function reset_state()
    dirs, pair_lists, recs, pending_q, shapes, pshapes, bshapes = {}, {}, {}, {}, {}, {}, {}
    xlen, xlen_n = {}, 0
    cr_pend, cr_npend, cr_npieces, cr_pend_first, cr_first = {}, 0, 0, 0, {}
    cr_store = { bytes = nil, size = 0, off = {}, len = {}, last = 0, last_text = nil }
    sk_str, sk_str_n = {}, 0
    dir_cache_key, dir_cache_num, dir_cache_ports = nil, nil, 0
    last_asrc, last_adst, last_pdir, last_akey = nil, nil, nil, nil
    LIM.journal, LIM.ndirs, LIM.npend = false, 0, {}
end
reset_state()

function sl.init()
    reset_state()
    pref_list = parse_list(sl.prefs.variables)
    pref_validate = sl.prefs.validate_checksum
    pref_heuristic = sl.prefs.heuristic
    pref_sync = (tonumber(sl.prefs.sync_interval) or 1000) / 1000 + SYNC_SLACK
    read_limits()
end

------------------------------------------------------------------------------
-- Helpers
------------------------------------------------------------------------------
local ARROW = "\226\134\146"     -- U+2192
local ELLIPSIS = "\226\128\166"  -- U+2026
local INFO_MAX = 120
local CTRL = "[\0-\31\127]"   -- control characters (not to be shown in the Info column)

local B_LBRACK, B_RBRACK, B_PIPE, B_COLON = 91, 93, 124, 58
local B_CR, B_LF = 13, 10
local B_A, B_P = 65, 80
local L_N, L_T, L_Q, L_R, L_D, L_C, L_L, L_E, L_M, L_P, L_G = 78, 84, 81, 82, 68, 67, 76, 69, 77, 80, 71

-- SUM_OF[n](b1, ..., bn): the sum of its n arguments (made for n = 0 to 40: n - 1 adds).
-- Speed trick (measured): bytes are summed as s_byte returns them, up to 40 a call.
local SUM_OF = {}
for n = 0, 40 do
    local args = {}
    for i = 1, n do args[i] = "b" .. i end
    SUM_OF[n] = assert(load("return function(" .. t_concat(args, ", ") .. ") return " ..
        (n > 0 and t_concat(args, " + ") or "0") .. " end", "=SUM_OF", "t", {}))()
end
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

-- Sum of the bytes of a value.  Speed trick (measured): the fast paths check a checksum
-- as the shape's fixed sum plus the sums of the values, one s_byte call per value.
local function str_sum(v)
    local n = #v
    if n > 40 then return byte_sum(v, 1, n) end
    return SUM_OF[n](s_byte(v, 1, n))
end

-- Checksum texts of two hex digits -> value (the common case without a pattern match)
local HEXV = {}
do
    local digits = "0123456789ABCDEFabcdef"
    for i = 1, #digits do
        for j = 1, #digits do
            local t = s_sub(digits, i, i) .. s_sub(digits, j, j)
            HEXV[t] = tonumber(t, 16)
        end
    end
end

-- The value of a checksum text: two hex digits (either case) or up to 8; nil otherwise.
local function checksum_value(ctext)
    local v = HEXV[ctext]
    if v then return v end
    if #ctext >= 1 and #ctext <= 8 and not s_find(ctext, "[^0-9A-Fa-f]") then return tonumber(ctext, 16) end
    return nil
end

-- For the express lane (see express), one per value count n, made the same way:
-- EXPRESS_SUMS[n](v1, ..., vn, ctext) -> the values' total length, the sum of their bytes and
-- ctext.  Speed trick (measured): the values are summed as one string, one str_sum instead of
-- one a value (-2.3 thousand instructions a frame, summary pass; the joined string is short,
-- interned and soon garbage).
local EXPRESS_SUMS = {}
for n = 1, 8 do
    local args = {}
    for k = 1, n do args[k] = "v" .. k end
    EXPRESS_SUMS[n] = assert(load("local str_sum = ... return function(" .. t_concat(args, ", ") ..
        ", ctext) local all = " .. t_concat(args, " .. ") .. " return #all, str_sum(all), ctext end",
        "=EXPRESS_SUMS", "t", {}))(str_sum)
end

local INT64_MAX = "9223372036854775807"

-- Parse a decimal long; returns an Int64, or nil if not an integer / out of range.
local function parse_long(text)
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
local function to_ordinal(text)
    local o = tonumber(text)
    if not o or o ~= o or o < 0 or o >= 2147483647 then return 0 end
    return floor(o)
end

local function nstime_of(d)
    if d < 0 then d = 0 end
    local secs = floor(d)
    local ns = floor((d - secs) * 1e9 + 0.5)
    if ns >= 1000000000 then ns = 999999999 end
    return NSTime.new(secs, ns)
end

------------------------------------------------------------------------------
-- Modules: dissector/sharedlink/<name>.lua beside this file, run once each with a token that
-- tells them apart from Wireshark's own loading of plugin subfolders (see each module's head).
-- Works the same from a checkout (tshark -X lua_script:dissector/sharedlink.lua) and from the
-- personal plugin folder (make install copies this file and the folder), 4.0 to 4.6.
------------------------------------------------------------------------------
local load_module
do
    local here = (debug.getinfo(1, "S").source or ""):match("^@(.*[/\\])") or ""
    local TOKEN = { sharedlink_module = true }
    local loaded = {}
    function load_module(name)
        local m = loaded[name]
        if m == nil then
            m = assert(loadfile(here .. "sharedlink/" .. name .. ".lua"))(TOKEN)
            loaded[name] = m
        end
        return m
    end
end

-- wsapi: every use of Wireshark's internals, checked against the documented API
-- (dissector/sharedlink/wsapi.lua)
local wsapi = load_module("wsapi")
local PG = wsapi.PG

------------------------------------------------------------------------------
-- Direction state
------------------------------------------------------------------------------
-- vals/from: name -> last good value / its frame; names: named variables in the order first
-- sent in a good frame, npos: name -> its index there, nfirst: name -> that frame;
-- seen: name -> stamp of the last frame that had it; maxslot: highest positional slot that
-- ever held a value; first/lastfull: times of the first frame and of the last good full one.
local function new_dir()
    return { vals = {}, from = {}, names = {}, npos = {}, nfirst = {}, nkey = {}, seen = {}, maxslot = -1,
        first = nil, lastfull = nil, list = nil }
end

-- Direction state for (src address, dst address, src port, dst port, letters).
-- dirs[addresses][ports and letters as one number]; cheap on the per-frame path.
local function get_dir(pinfo, num, dstb, srcb)
    local byaddr
    if dir_cache_num == num then
        byaddr = dir_cache_key
    else
        -- the capture direction keeps the two directions of a serial line apart.  Speed
        -- trick (measured): Address objects compare cheaper than they print, so the key
        -- text is rebuilt only when the addresses differ from the previous packet's.
        local pg = PG
        local sport, dport = pg.src_port(pinfo), pg.dst_port(pinfo)
        -- the capture direction only where no port tells the directions apart (a serial line);
        -- a UDP/TCP flow is one direction whatever direction flags its link layer had
        local asrc, adst = pg.src(pinfo), pg.dst(pinfo)
        local pdir = (sport == 0 and dport == 0) and pg.p2p_dir(pinfo) or -1
        local akey
        if pdir == last_pdir and asrc == last_asrc and adst == last_adst then
            akey = last_akey
        else
            akey = tostring(asrc) .. ">" .. tostring(adst) .. "/" .. pdir
            last_asrc, last_adst, last_pdir, last_akey = asrc, adst, pdir, akey
        end
        byaddr = dirs[akey]
        if not byaddr then
            byaddr = {}
            dirs[akey] = byaddr
        end
        dir_cache_key = byaddr
        dir_cache_num = num
        dir_cache_ports = (sport * 65536 + dport) * 65536
    end
    local key = dir_cache_ports + dstb * 256 + srcb
    local d = byaddr[key]
    if not d then
        d = new_dir()
        if LIM.ndirs >= LIM.max_conversations then d.over = true; return d end   -- kept nowhere
        LIM.ndirs = LIM.ndirs + 1
        byaddr[key] = d
    end
    return d
end

-- The same for the reverse direction (dst -> src) of the current packet.
local function get_rev_dir(pinfo, dstb, srcb)
    local sport, dport = pinfo.src_port, pinfo.dst_port
    local pd = -1
    if sport == 0 and dport == 0 then
        pd = pinfo.p2p_dir
        if pd == 0 or pd == 1 then pd = 1 - pd end
    end
    local akey = tostring(pinfo.dst) .. ">" .. tostring(pinfo.src) .. "/" .. pd
    local byaddr = dirs[akey]
    if not byaddr then
        byaddr = {}
        dirs[akey] = byaddr
    end
    local key = (dport * 65536 + sport) * 65536 + srcb * 256 + dstb
    local d = byaddr[key]
    if not d then
        d = new_dir()
        if LIM.ndirs >= LIM.max_conversations then d.over = true; return d end   -- kept nowhere
        LIM.ndirs = LIM.ndirs + 1
        byaddr[key] = d
    end
    return d
end

-- Per-frame record, kept only for frames that need one.  recs[num] is the record
-- itself (rec.sk identifies the frame within the packet) or, when several frames of
-- one packet have records, a table sk -> record.  A record's array part holds the
-- carried values of its empty D fields: value, frame, value, frame, ...
local CARRY = {}   -- carried values of the current frame: value, frame, value, frame, ...
local MISS = {}    -- named variables missing from the current frame: name, value, frame, ...
local CPARTS = {}

-- Carried-only records (the bulk of a compressed stream) are kept as text lines
-- "num|sk|value|frame|value|frame..." (a D value never holds "|" or a line break;
-- "" = none; a carried named value is stored as "=" .. value, as it may be ""),
-- packed 256 to a string: Wireshark runs full Lua garbage collections
-- during a capture, and their cost grows with the number of live Lua objects.
local FROM_STR, from_str_n = {}, 0   -- frame number -> its text (the carried values' frames)
local function from_text(fr)
    if not fr then return "" end
    local t = FROM_STR[fr]
    if not t then
        if from_str_n >= 4096 then FROM_STR, from_str_n = {}, 0 end
        t = tostring(fr)
        FROM_STR[fr] = t
        from_str_n = from_str_n + 1
    end
    return t
end

-- The text of a frame key (sk), kept for the few a capture has.
local function sk_text(sk)
    local sks = sk_str[sk]
    if not sks then
        sks = tostring(sk)
        if sk_str_n < 4096 then sk_str[sk] = sks; sk_str_n = sk_str_n + 1 end
    end
    return sks
end

-- Record lines wait in cr_pend as pieces, each line ending in "\n" (cr_npend lines, cr_npieces
-- pieces), and are packed 256 to a chunk "\n" .. lines.  Speed tricks (measured, compressed
-- capture): the express lane adds a line as pieces, and no string is made for it until the
-- chunk; the chunks are kept in one ByteArray (cr_store), outside the Lua heap, as the
-- collector's pace follows the heap's live size: kept as Lua strings, they made every
-- collection rarer and each one sweep more garbage, a cost to every allocation of the pass
-- (-2.6 us a frame).  cr_store.off/len: chunk i's place in it; last/last_text: the chunk read last.
local function carried_flush()
    if cr_npend == 0 then return end
    local text = "\n" .. t_concat(cr_pend, "", 1, cr_npieces)
    local st = cr_store
    if not st.bytes then st.bytes = ByteArray.new() end
    st.bytes:append(ByteArray.new(text, true))
    local i = #st.off + 1
    st.off[i], st.len[i], st.size = st.size, #text, st.size + #text
    cr_first[i] = cr_pend_first
    cr_npend, cr_npieces = 0, 0
end

-- The text of chunk i.
local function carried_chunk(i)
    local st = cr_store
    if st.last ~= i then st.last, st.last_text = i, st.bytes:raw(st.off[i], st.len[i]) end
    return st.last_text
end

-- Frame num's record line has been put in cr_pend after the pieces already there, ending with
-- its "\n" at index i (carried_store: the line and "\n"; the express lane: num, "|sk|d|0",
-- a piece a carried variable and "\n").
local function carried_line_end(num, i)
    if cr_npend == 0 then cr_pend_first = num end
    cr_npieces, cr_npend = i, cr_npend + 1
    if cr_npend >= 256 then carried_flush() end
end

-- The named part of a line: name|value|frame|... for the nm/3 triples in MISS.
local function carried_names_text(nm, n)
    for k = 1, nm, 3 do
        -- a named value can be "" (an empty D, rule 3): present values are stored as
        -- "=" .. value so that "" still means none
        local v = MISS[k + 1]
        CPARTS[n + 1], CPARTS[n + 2], CPARTS[n + 3] = MISS[k], v and ("=" .. v) or "", from_text(MISS[k + 2])
        n = n + 3
    end
    return n
end

-- Line: num|sk|kind|ne|value|frame|...(ne/2 pairs)|name|value|frame|...(nm/3 triples)
local function carried_store(num, sk, ne, nm, kind)
    CPARTS[1], CPARTS[2], CPARTS[3], CPARTS[4] = num, sk_text(sk), kind, ne == 0 and "0" or ne
    local n = 4
    for k = 1, ne, 2 do
        CPARTS[n + 1], CPARTS[n + 2] = CARRY[k] or "", from_text(CARRY[k + 1])
        n = n + 2
    end
    n = carried_names_text(nm, n)
    local line = t_concat(CPARTS, "|", 1, n)
    if s_find(line, "\n", 1, true) then return false end   -- a line break in a value: a table record
    local i = cr_npieces
    cr_pend[i + 1], cr_pend[i + 2] = line, "\n"
    carried_line_end(num, i + 2)
    return true
end

local function carried_parse(line)
    local rec = {}
    local parts, n = CPARTS, 0
    local p = 1
    while true do
        local q = s_find(line, "|", p, true)
        n = n + 1
        parts[n] = s_sub(line, p, (q or 0) - 1)
        if not q then break end
        p = q + 1
    end
    rec.sk = tonumber(parts[2])
    rec.kind = parts[3]
    local ne = tonumber(parts[4]) or 0
    for k = 1, ne, 2 do
        local v = parts[k + 4]
        rec[k] = v ~= "" and v or false
        rec[k + 1] = tonumber(parts[k + 5]) or false
    end
    local i = ne + 5
    if i + 2 <= n then
        local miss = {}
        while i + 2 <= n do
            local v = parts[i + 1]
            miss[#miss + 1] = parts[i]
            miss[#miss + 1] = v ~= "" and s_sub(v, 2) or false
            miss[#miss + 1] = tonumber(parts[i + 2]) or false
            i = i + 3
        end
        rec.miss = miss
    end
    return rec
end

local function carried_lookup(num, sk)
    if cr_npend > 0 and num >= cr_pend_first then carried_flush() end
    -- last chunk whose first frame is <= num
    local lo, hi = 1, #cr_first
    local found = nil
    while lo <= hi do
        local mid = floor((lo + hi) / 2)
        if cr_first[mid] <= num then found = mid; lo = mid + 1 else hi = mid - 1 end
    end
    if not found then return nil end
    local chunk = carried_chunk(found)
    local a = s_find(chunk, "\n" .. num .. "|" .. sk .. "|", 1, true)
    if not a then return nil end
    local b = s_find(chunk, "\n", a + 1, true)
    return carried_parse(s_sub(chunk, a + 1, b - 1))
end

local function get_rec(num, sk, create)
    local r = recs[num]
    if r == nil then
        if not create then return carried_lookup(num, sk) end
        r = { sk = sk }
        recs[num] = r
        return r
    end
    if r.sk == sk then return r end
    if r.sk ~= nil then
        if not create then return carried_lookup(num, sk) end
        r = { [r.sk] = r }
        recs[num] = r
    end
    local rec = r[sk]
    if not rec then
        if not create then return carried_lookup(num, sk) end
        rec = { sk = sk }
        r[sk] = rec
    end
    return rec
end

------------------------------------------------------------------------------
-- Info column pieces (reused)
------------------------------------------------------------------------------
local INFO = {}
local ninfo, info_len, info_full = 0, 0, false
local info_clean = true     -- every piece came from the named fast path
local frames_in_info, frames_dropped = 0, 0

local function info_add(str)
    if info_full then return end
    local l = #str
    ninfo = ninfo + 1
    if info_len + l > INFO_MAX then
        INFO[ninfo] = ELLIPSIS
        info_full = true
        return
    end
    INFO[ninfo] = str
    info_len = info_len + l
end

------------------------------------------------------------------------------
-- Frame parsing into reusable arrays (no per-frame table churn)
------------------------------------------------------------------------------
-- fields (only recorded when a tree is built): letter byte (false = empty), start, end in f
local FL, FS, FE = {}, {}, {}
local FV, FC = {}, {}     -- rendering: variable starting at field i / field covered by a variable
local nf = 0
-- variables: type text, name, value (false = no D), index, is reply; field numbers of T, Q/R, D
local VT, VN, VV, VI, VR = {}, {}, {}, {}, {}
local VTf, VQf, VDf = {}, {}, {}
local nv = 0

local LETTER = {}
for b = 0, 255 do
    if b >= 32 and b <= 126 then LETTER[b] = string.char(b) else LETTER[b] = s_format("\\x%02x", b) end
end

-- A T field's text as its type number (0-255), nil when it is not one.  Speed trick
-- (measured, -V): the texts seen are remembered (a few distinct ones a capture, up to 256).
local VALID_TYPE, valid_type_n = {}, 0
local function valid_type(t)
    local v = VALID_TYPE[t]
    if v ~= nil then return v or nil end
    local n = tonumber(t)
    v = (n and n >= 0 and n <= 255 and n == floor(n)) and floor(n) or false
    if valid_type_n < 256 and type(t) == "string" then
        VALID_TYPE[t], valid_type_n = v, valid_type_n + 1
    end
    return v or nil
end

-- The typed field is hidden: the Value line above it shows the same fact.  With no range
-- (a tree nobody sees) the item is added with its value only.
-- TreeItem's methods called through this table (speed trick, measured: -V 16 us a frame
-- less): ti:add(...) looks the method up through wslua's __index, a call into C, each time.
local TI = wsapi.TI   -- see wsapi (2)

local function add_typed_value(vt, range, vtype, text)
    local field, v
    if vtype == 2 then
        field, v = hf.var_double, tonumber(text)
        if not v then TI.add_proto_expert_info(vt, ei.var_badvalue, "Not a double: " .. text) end
    elseif vtype == 0 then
        field, v = hf.var_long, parse_long(text)
        if not v then TI.add_proto_expert_info(vt, ei.var_badvalue, "Not a long (int64): " .. text) end
    elseif vtype == 4 then
        field, v = hf.var_string, text
    end
    if v then
        if range then TI.set_hidden(TI.add(vt, field, range, v)) else TI.add(vt, field, v) end
    end
end

-- A zero-length range at off, kept inside the tvb.
local function zrange(tvb, off)
    local n = tvb:len()
    if off >= n then off = n - 1 end
    if off < 0 then off = 0 end
    return tvb(off, 0)
end

local function pat_escape(text)
    return (s_gsub(text, "[%^%$%(%)%%%.%[%]%*%+%-%?]", "%%%0"))
end


------------------------------------------------------------------------------
-- One frame, in phases: parse (fast paths, else every field), learn the layout for the
-- fast paths, checksum verdict, kind, state (first pass: compute and store; later passes:
-- read the record), Info column, tree (compact when nobody sees it, else full).
------------------------------------------------------------------------------
-- What parsing found in the current frame, beside the field and variable arrays above
-- (pr_*: module-level locals, reset by parse_reset; speed trick, measured: fields of a table
-- cost 3 us a frame more).  n_ord/l_ord: the N/L ordinals (n_text: N's text);
-- has_e..has_r: an E, M, P, G or R field; nq/nd: Q and D fields; n_pos: positional D fields,
-- n_empty_d: empty ones; cpos/ctext: the checksum field's start and text; cmd_start: the
-- first E/M field; ord_text: N? or L? (a list request); fast_sh: the named layout matched,
-- fast_hit: a fast path parsed the frame, fast_sum: the checksum it computed.
local pr_n_ord, pr_l_ord, pr_n_text, pr_ord_text
local pr_has_e, pr_has_m, pr_has_p, pr_has_g, pr_has_r
local pr_nq, pr_nd, pr_n_empty_d, pr_n_pos
local pr_cpos, pr_ctext, pr_cmd_start
local pr_fast_sh, pr_fast_hit, pr_fast_sum
-- pr_odd: parse_general met a field whose tree item carries an expert info (an empty field, an
-- unknown letter, an ordinal or type that is not a number)
local pr_odd
-- pr_limit: why the frame is past a limit its fields alone tell (a "Limit exceeded: ..." text),
-- else false
local pr_limit

-- For tests, marks on the Info of the packets a speed trick took: SHAREDLINK_EXPRESS_MARK=1 the
-- express lane's ("[express] "), SHAREDLINK_FAST_MARK=1 parse_frame's fast paths' ("[fast] ";
-- fast_hit: one of the packet's frames took one).
local MARKS = { express = wsapi.env.express_mark and "[express] ", fast = wsapi.env.fast_mark, fast_hit = false }

-- parse_frame and the helpers only it uses (a block: the main chunk may hold 200 locals);
-- fast_positions serves the express lane too
local parse_frame, fast_positions
do
    -- SHAREDLINK_NO_FAST=1 turns the fast paths off (tests: every frame parsed field by field)
    local FAST = not wsapi.env.no_fast

    -- The layouts' value classes, written as ranges: a value is any byte but '|', ']', the
    -- control characters and DEL (VALUE, the phases' fast paths) and also not '[' (XVALUE, the
    -- express lane: a "[:" there would make the phases split the frame).  Speed trick
    -- (measured): the matcher tries a class's items in order and a digit is in the first range,
    -- where the negated forms ([^|%]\0-\31\127]) tried every item, escapes costing most
    -- (-1.6 and -2.0 thousand instructions a frame, summary pass); XCHECKSUM ends the payload
    -- after the checksum and at most CR LF.
    local VALUE = "([ -\\^-{}-~\128-\255]*)"
    local XVALUE = "([ -Z\\^-{}-~\128-\255]*)"
    local XCHECKSUM = "|C([^][|]*)%]\r?\n?$"
    -- a double-typed value in the express lane: a plain decimal number only, which tonumber always
    -- takes (speed trick, measured: the lane needs no tonumber to know the value has no
    -- var.badvalue; other doubles, "1e5" or " 2", go to the phases)
    local XDOUBLE = "([-+]?%d+%.?%d*)"
    local function parse_reset()
        nf, nv = 0, 0
        pr_n_ord, pr_l_ord, pr_n_text = nil, nil, nil
        pr_has_e, pr_has_m, pr_has_p, pr_has_g, pr_has_r = false, false, false, false, false
        pr_nq, pr_nd, pr_n_empty_d, pr_n_pos = 0, 0, 0, 0
        pr_cpos, pr_ctext, pr_cmd_start, pr_ord_text = nil, nil, nil, false
        pr_fast_sh, pr_fast_hit, pr_fast_sum = nil, false, nil
        pr_odd, pr_limit = false, false
    end

    -- The header: last index of the content, the address bytes (nil when cut short), the index of
    -- the first field (nil: none), and why the frame is malformed (nil: it is not).
    local function parse_header(f, fl, terminated)
        local malformed_msg = nil
        if not terminated then malformed_msg = "Unterminated frame (no closing ])" end
        local bodyend = terminated and fl - 1 or fl
        local dstb, srcb = s_byte(f, 3), s_byte(f, 4)
        if bodyend < 3 then dstb = nil end
        if bodyend < 4 then srcb = nil end
        local p
        if bodyend < 5 then
            p = nil
            if not malformed_msg and not srcb then malformed_msg = "Frame too short for a header" end
        elseif s_byte(f, 5) == B_PIPE then
            p = 6
        else
            local q = s_find(f, "|", 5, true)
            p = q and q + 1 or nil
            if not malformed_msg then malformed_msg = "Expected | after the addresses" end
        end
        return bodyend, dstb, srcb, p, malformed_msg
    end

    -- A fast pattern's captures (the values, then the checksum text) into VV and pr_*; the
    -- checksum as the layout's fixed sum plus the values' sums (speed trick, measured).  Returns
    -- the number of values.
    local function take_fast_values(layout, c1, c2, c3, c4, c5, c6, c7, c8, c9)
        VV[1], VV[2], VV[3], VV[4], VV[5], VV[6], VV[7], VV[8], VV[9] = c1, c2, c3, c4, c5, c6, c7, c8, c9
        local n = layout.n
        pr_ctext = VV[n + 1]
        local sum = layout.fixed
        for k = 1, n do sum = sum + str_sum(VV[k]) end
        pr_fast_sum = sum % 256
        pr_n_ord = layout.ord
        return n
    end

    -- The fields' places in a frame a fast path parsed (N, T/Q/D triplets or D fields, C), for
    -- a shown tree: the layout fixes every field but the values, whose lengths place the rest.
    function fast_positions(ntext, n, named)
        FL[1], FS[1], FE[1] = L_N, 6, 6 + #ntext
        local p, i = 8 + #ntext, 1
        for k = 1, n do
            if named then
                local t, q = VT[k], VN[k]
                FL[i + 1], FS[i + 1], FE[i + 1] = L_T, p, p + #t
                p = p + #t + 2
                FL[i + 2], FS[i + 2], FE[i + 2] = L_Q, p, p + #q
                p = p + #q + 2
                VTf[k], VQf[k] = i + 1, i + 2
                i = i + 2
            else
                VTf[k], VQf[k] = 0, 0
            end
            local v = VV[k]
            FL[i + 1], FS[i + 1], FE[i + 1] = L_D, p, p + #v
            VDf[k] = i + 1
            p = p + #v + 2
            i = i + 1
        end
        FL[i + 1], FS[i + 1], FE[i + 1] = L_C, p, p + #pr_ctext
        nf = i + 1
    end

    -- Fast path: a frame with the layout of one of the node pair's
    -- recent plain named frames is matched by one anchored pattern.  mru: the pair's layouts,
    -- most recently matched first (a compressed stream's deltas cycle through a few subsets of
    -- the variables): a layout that does not fit fails within the first differing name, cheaply.
    -- Returns true when it parsed the frame.
    local function parse_fast_named(f, mru, rec_fields)
        local _, sh, c1, c2, c3, c4, c5, c6, c7, c8, c9
        for k = 1, #mru do
            sh = mru[k]
            _, _, c1, c2, c3, c4, c5, c6, c7, c8, c9 = s_find(f, sh.pat)
            if c1 then
                if k > 1 then table.remove(mru, k); table.insert(mru, 1, sh) end
                break
            end
        end
        if not c1 then return false end
        local n = take_fast_values(sh, c1, c2, c3, c4, c5, c6, c7, c8, c9)
        local st, sn = sh.T, sh.N
        local idx = sh.ord
        for k = 1, n do
            VT[k], VN[k], VI[k], VR[k] = st[k], sn[k], idx, false
            idx = idx + 1
        end
        nv, pr_nq, pr_nd = n, n, n
        pr_fast_sh, pr_fast_hit = sh, sh
        if rec_fields then fast_positions(sh.ntext, n, true) end
        return true
    end

    -- The same for the pair's last plain positional frame (N, D fields, C).
    local function parse_fast_positional(f, ps, rec_fields)
        local _, _, c1, c2, c3, c4, c5, c6, c7, c8, c9 = s_find(f, ps.pat)
        if not c1 then return false end
        local n = take_fast_values(ps, c1, c2, c3, c4, c5, c6, c7, c8, c9)
        local idx = ps.ord
        local n_empty_d = 0
        for k = 1, n do
            VT[k], VN[k], VI[k], VR[k] = false, false, idx, false
            idx = idx + 1
            if VV[k] == "" then n_empty_d = n_empty_d + 1 end
        end
        nv, pr_nd, pr_n_pos, pr_n_empty_d = n, n, n, n_empty_d
        pr_fast_hit = ps
        if rec_fields then fast_positions(ps.ntext, n, false) end
        return true
    end

    -- The plain path: every field from p on, in one pass (fields recorded with their positions
    -- when a tree is built), variables gathered as T/Q/R/D come; results in P.
    -- An N or L field's text as the tree shows it without an expert: a number 0 .. 2^32-1.
    local function ordinal_ok(text)
        local n = tonumber(text)
        return n and n >= 0 and n < 4294967296 and n == floor(n)
    end

    local function parse_general(f, p, bodyend, rec_fields)
        local n_ord, l_ord, n_text = nil, nil, nil
        local has_e, has_m, has_p, has_g, has_r = false, false, false, false, false
        local nq, nd, n_empty_d, n_pos = 0, 0, 0, 0
        local pend_t, pend_q, pend_r = false, false, false   -- pending T text, Q/R name
        local pend_tf, pend_qf = 0, 0
        local idx = 0
        local cpos, ctext = nil, nil  -- checksum field start and text
        local cmd_start = nil         -- first E/M field
        local ord_text = false        -- N or L with a non-numeric ordinal (N?, L?: a list request)
        local odd = false             -- a field with an expert info in the tree (see pr_odd)
        while p and p <= bodyend + 1 do
            local c = s_byte(f, p)
            local _, fe, t1, t2, t3
            if c == L_T and not pend_q then
                _, fe, t1, t2, t3 = s_find(f, "^T([^]|]*)|Q([^]|]*)|D([^]|]*)", p)
            end
            if fe and fe <= bodyend then
                -- fast path: a complete T/Q/D triplet
                nv = nv + 1
                VT[nv], VN[nv], VV[nv], VI[nv], VR[nv] = t1, t2, t3, idx, false
                idx = idx + 1
                nq, nd = nq + 1, nd + 1
                if not valid_type(t1) then odd = true end
                if rec_fields then
                    local q1 = p + #t1 + 2
                    local d1 = q1 + #t2 + 2
                    FL[nf + 1], FS[nf + 1], FE[nf + 1] = L_T, p, q1 - 2
                    FL[nf + 2], FS[nf + 2], FE[nf + 2] = L_Q, q1, d1 - 2
                    FL[nf + 3], FS[nf + 3], FE[nf + 3] = L_D, d1, fe
                    VTf[nv], VQf[nv], VDf[nv] = nf + 1, nf + 2, nf + 3
                end
                nf = nf + 3
                pend_t = false
                p = fe + 2
            else
                _, fe, t1 = s_find(f, "^[^]|]([^]|]*)", p)
                if fe and fe > bodyend then fe = nil end
                if not fe then
                    -- empty field
                    nf = nf + 1
                    if rec_fields then FL[nf], FS[nf], FE[nf] = false, p, p - 1 end
                    odd = true
                    p = p + 1
                else
                    nf = nf + 1
                    if rec_fields then FL[nf], FS[nf], FE[nf] = c, p, fe end
                    if c == L_D then
                        nd = nd + 1
                        if not (has_e or has_m) then
                            nv = nv + 1
                            VT[nv], VN[nv], VV[nv], VI[nv], VR[nv] = pend_t, pend_q, t1, idx, pend_r
                            VTf[nv], VQf[nv], VDf[nv] = pend_tf, pend_qf, nf
                            if not pend_q then
                                n_pos = n_pos + 1
                                if t1 == "" then n_empty_d = n_empty_d + 1 end
                            end
                            idx = idx + 1
                            pend_t, pend_q, pend_r, pend_tf, pend_qf = false, false, false, 0, 0
                        end
                    elseif c == L_Q or c == L_R then
                        if pend_q then
                            nv = nv + 1
                            VT[nv], VN[nv], VV[nv], VI[nv], VR[nv] = pend_t, pend_q, false, idx, pend_r
                            VTf[nv], VQf[nv], VDf[nv] = pend_tf, pend_qf, 0
                            idx = idx + 1
                            pend_t, pend_tf = false, 0
                        end
                        pend_q, pend_qf = t1, nf
                        pend_r = (c == L_R)
                        if pend_r then has_r = true else nq = nq + 1 end
                    elseif c == L_T then
                        if pend_q then
                            nv = nv + 1
                            VT[nv], VN[nv], VV[nv], VI[nv], VR[nv] = pend_t, pend_q, false, idx, pend_r
                            VTf[nv], VQf[nv], VDf[nv] = pend_tf, pend_qf, 0
                            idx = idx + 1
                            pend_q, pend_r, pend_qf = false, false, 0
                        end
                        pend_t, pend_tf = t1, nf
                        if not valid_type(t1) then odd = true end
                    elseif c == L_N then
                        if not ordinal_ok(t1) then odd = true end
                        if #t1 > 9 and not s_find(t1, "[^0-9]") then
                            odd, pr_limit = true, "Limit exceeded: N has more than 9 digits"
                        end
                        if not n_ord then
                            n_ord = to_ordinal(t1); idx = n_ord; n_text = t1
                            if not tonumber(t1) then ord_text = true end
                        end
                    elseif c == L_L then
                        if not ordinal_ok(t1) then odd = true end
                        if #t1 > 9 and not s_find(t1, "[^0-9]") then
                            odd, pr_limit = true, "Limit exceeded: L has more than 9 digits"
                        end
                        if not l_ord then
                            l_ord = to_ordinal(t1); idx = l_ord
                            if not tonumber(t1) then ord_text = true end
                        end
                    elseif c == L_C and fe == bodyend then
                        cpos, ctext = p, t1
                    elseif c == L_E or c == L_M then
                        if c == L_E then has_e = true else has_m = true end
                        if not cmd_start then cmd_start = p end
                    elseif c == L_P then has_p = true
                    elseif c == L_G then has_g = true
                    else odd = true   -- an unknown letter, or C before the last field
                    end
                    p = fe + 2
                end
            end
        end
        if pend_q then
            nv = nv + 1
            VT[nv], VN[nv], VV[nv], VI[nv], VR[nv] = pend_t, pend_q, false, idx, pend_r
            VTf[nv], VQf[nv], VDf[nv] = pend_tf, pend_qf, 0
        end
        pr_n_ord, pr_l_ord, pr_n_text = n_ord, l_ord, n_text
        pr_has_e, pr_has_m, pr_has_p, pr_has_g, pr_has_r = has_e, has_m, has_p, has_g, has_r
        pr_nq, pr_nd, pr_n_empty_d, pr_n_pos = nq, nd, n_empty_d, n_pos
        pr_cpos, pr_ctext, pr_cmd_start, pr_ord_text = cpos, ctext, cmd_start, ord_text
        pr_odd = odd
    end

    -- A named layout's code, made once per pattern (kept for 256 patterns): store(vals, from,
    -- num, v1, ..., vn) stores the values as the direction's last ones (the express lane), and
    -- info(v1, ..., vn) / dinfo(...) make the Info of a full frame / a delta (the express lane
    -- and info_frame).  Speed trick (measured): the names and the Info's pieces are constants in
    -- the code, one concatenation, nothing looked up.
    local LAYOUT_CODE, layout_code_n = {}, 0
    local function layout_code(pat, sn, pieces, dpieces)
        local code = LAYOUT_CODE[pat]
        if not code then
            local args, store, info, dinfo = {}, {}, {}, {}
            for k = 1, #sn do
                local q = string.format("%q", sn[k])
                args[k] = "v" .. k
                store[k] = "vals[" .. q .. "] = v" .. k .. " from[" .. q .. "] = num"
                info[2 * k - 1], info[2 * k] = string.format("%q", pieces[k]), args[k]
                dinfo[2 * k - 1], dinfo[2 * k] = string.format("%q", dpieces[k]), args[k]
            end
            local vs = t_concat(args, ", ")
            code = { assert(load("return function(vals, from, num, " .. vs .. ") " .. t_concat(store, " ") ..
                " end, function(" .. vs .. ") return " .. t_concat(info, " .. ") ..
                " end, function(" .. vs .. ") return " .. t_concat(dinfo, " .. ") .. " end",
                "=layout_code", "t", {}))() }
            if layout_code_n >= 256 then LAYOUT_CODE, layout_code_n = {}, 0 end
            LAYOUT_CODE[pat], layout_code_n = code, layout_code_n + 1
        end
        return code[1], code[2], code[3]
    end

    -- Remember the layout of a plain named frame (N, T/Q/D triplets, C) for parse_fast_named.
    local function learn_named_shape(f, shape_key, dstb, srcb)
        local n_text, cpos, n_pos, ord_text, n_ord = pr_n_text, pr_cpos, pr_n_pos, pr_ord_text, pr_n_ord
        if shape_key and n_text and cpos and nv >= 1 and nv <= 8 and nf == 3 * nv + 2 and n_pos == 0
            and s_byte(f, 6) == L_N and not ord_text then
            local ok = true
            for k = 1, nv do
                if not (VT[k] and VN[k] and VV[k] and valid_type(VT[k])) or VR[k] then ok = false; break end
            end
            if ok then
                local parts = { "^%[:", pat_escape(LETTER[dstb] .. LETTER[srcb]), "|N", pat_escape(n_text) }
                -- the express lane's: the head (up to the first value) as plain text, the rest a
                -- pattern anchored where the head ends
                local xparts = {}
                local st, sn, tv = {}, {}, {}
                local head = LETTER[srcb] .. ARROW .. LETTER[dstb] .. " full"
                local dhead = LETTER[srcb] .. ARROW .. LETTER[dstb] .. " delta"
                local first = " " .. s_gsub(VN[1], CTRL, "?") .. "="
                local pieces, ilen = { head .. first }, #head
                local fixed = byte_sum(f, 2, cpos)
                for k = 1, nv do
                    st[k], sn[k], tv[k] = VT[k], VN[k], valid_type(VT[k])
                    local tq = "|T" .. pat_escape(VT[k]) .. "|Q" .. pat_escape(VN[k])
                    parts[#parts + 1] = tq .. "|D" .. VALUE
                    xparts[#xparts + 1] = (k > 1 and tq .. "|D" or "^") .. (tv[k] == 2 and XDOUBLE or XVALUE)
                    if k > 1 then pieces[k] = " " .. s_gsub(VN[k], CTRL, "?") .. "=" end
                    ilen = ilen + #VN[k] + 2
                    fixed = fixed - str_sum(VV[k])
                end
                parts[#parts + 1] = "|C([^]|]*)%]"
                xparts[#xparts + 1] = XCHECKSUM
                local mru = shapes[shape_key]
                if not mru then mru = {}; shapes[shape_key] = mru end
                local pat = t_concat(parts)
                -- a layout known already comes first again, the same table: everything in it
                -- follows from the pattern, and the direction's names_is compares the table's N
                for k = 1, #mru do
                    if mru[k].pat == pat then
                        if k > 1 then table.insert(mru, 1, table.remove(mru, k)) end
                        return
                    end
                end
                xlen, xlen_n = {}, 0
                if #mru >= MAX_SHAPES then mru[#mru] = nil end
                local dpieces = { dhead .. first }
                for k = 2, nv do dpieces[k] = pieces[k] end
                local xstore, xinfo, xdinfo = layout_code(pat, sn, pieces, dpieces)
                table.insert(mru, 1, { pat = pat, n = nv, T = st, N = sn, TV = tv, ord = n_ord, ntext = n_text,
                    xstore = xstore, xinfo = xinfo, xdinfo = xdinfo,
                    info_len = ilen, dinfo_len = ilen + #dhead - #head,
                    fixed = fixed % 256, letters = LETTER[srcb] .. LETTER[dstb],
                    xhead = "[:" .. LETTER[dstb] .. LETTER[srcb] .. "|N" .. n_text .. "|T" .. VT[1] .. "|Q" .. VN[1]
                        .. "|D",
                    xpat = t_concat(xparts), sums = EXPRESS_SUMS[nv] })
            end
        end
    end

    -- Remember the layout of a plain positional frame (N, D fields, C) for parse_fast_positional.
    local function learn_positional_shape(f, shape_key, dstb, srcb)
        local n_text, cpos, n_pos, nq, has_r = pr_n_text, pr_cpos, pr_n_pos, pr_nq, pr_has_r
        local ord_text, n_ord = pr_ord_text, pr_n_ord
        if shape_key and n_text and cpos and nv >= 1 and nv <= 8 and nf == nv + 2 and n_pos == nv and nq == 0
            and not has_r and s_byte(f, 6) == L_N and not ord_text then
            local ok = true
            for k = 1, nv do
                if VT[k] or VN[k] or not VV[k] then ok = false; break end
            end
            if ok then
                local pat = "^%[:" .. pat_escape(LETTER[dstb] .. LETTER[srcb]) .. "|N" .. pat_escape(n_text) ..
                    s_rep("|D" .. VALUE, nv) .. "|C([^]|]*)%]"
                local ps = pshapes[shape_key]
                if not ps or ps.pat ~= pat then
                    local fixed = byte_sum(f, 2, cpos)
                    for k = 1, nv do fixed = fixed - str_sum(VV[k]) end
                    pshapes[shape_key] = { pat = pat, n = nv, ord = n_ord, ntext = n_text, fixed = fixed % 256 }
                end
            end
        end
    end

    -- Remember the layout of a bare frame (N0 and C only: every variable carried) for the
    -- express lane alone (see express).
    local function bare_sums(ctext) return 0, 0, ctext end
    local function bare_store() end
    local function learn_bare_shape(f, shape_key, dstb, srcb)
        local n_text, cpos = pr_n_text, pr_cpos
        if nv == 0 and nf == 2 and n_text and cpos and pr_n_ord == 0 and not pr_ord_text and s_byte(f, 6) == L_N then
            local xhead = "[:" .. LETTER[dstb] .. LETTER[srcb] .. "|N" .. n_text
            local bs = bshapes[shape_key]
            if not bs or bs.xhead ~= xhead then
                xlen, xlen_n = {}, 0
                local dhead = LETTER[srcb] .. ARROW .. LETTER[dstb] .. " delta"
                bshapes[shape_key] = { xhead = xhead, xpat = "^" .. XCHECKSUM, n = 0, N = {}, ord = 0, ntext = n_text,
                    fixed = byte_sum(f, 2, cpos) % 256,
                    letters = LETTER[srcb] .. LETTER[dstb], info_len = 0, dinfo_len = #dhead,
                    sums = bare_sums, xstore = bare_store, xdinfo = function() return dhead end, bare = true }
            end
        end
    end

    -- Parse a frame: header, then a fast path when one fits, else every field.  Returns the last
    -- index of the content, the address bytes and why it is malformed (nil: it is not).
    function parse_frame(f, fl, terminated, vis, rec_fields)
        parse_reset()
        local bodyend, dstb, srcb, p, malformed_msg = parse_header(f, fl, terminated)
        local shape_key = nil
        if p == 6 and not malformed_msg and dstb >= B_A and dstb <= B_P and srcb >= B_A and srcb <= B_P then
            shape_key = dstb * 256 + srcb
            -- a shown tree (vis) needs the fields' places too
            local mru, ps = FAST and shapes[shape_key], FAST and pshapes[shape_key]
            if (mru and parse_fast_named(f, mru, vis)) or (ps and parse_fast_positional(f, ps, vis)) then
                if MARKS.fast then MARKS.fast_hit = true end
                return bodyend, dstb, srcb, malformed_msg
            end
        end
        if p then parse_general(f, p, bodyend, rec_fields) end
        -- positional slots and declared entries at or past max_slots (their state is dropped)
        if nv > 0 and VI[nv] >= LIM.max_slots and not pr_limit then
            pr_odd, pr_limit = true, "Limit exceeded: a slot or ordinal at or past " .. LIM.max_slots .. " (max_slots)"
        end
        -- layouts are learnt on a miss (a frame the fast paths did not take), from a frame whose
        -- fields carry no expert info
        if shape_key and not pr_odd then
            learn_named_shape(f, shape_key, dstb, srcb)
            learn_positional_shape(f, shape_key, dstb, srcb)
            learn_bare_shape(f, shape_key, dstb, srcb)
        end
        return bodyend, dstb, srcb, malformed_msg
    end
end

-- Checksum verdict, before the state (a frame with a bad checksum changes no state): the
-- value of the checksum text (nil: not hex), the calculated value, the status (1 good, 0 bad,
-- 2 unverified; nil: no C field).
local function checksum_verdict(f, bodyend)
    local ctext = pr_ctext
    if pr_fast_hit then pr_cpos = bodyend - #ctext end   -- the fast patterns end in |C<ctext>]
    local cpos = pr_cpos
    if not cpos then return nil, nil, nil end
    local cs_val = checksum_value(ctext)
    if not pref_validate then return cs_val, nil, 2 end
    local cs_calc = pr_fast_sum or byte_sum(f, 2, cpos) % 256
    return cs_val, cs_calc, (cs_val == cs_calc) and 1 or 0
end

-- The kind the fields alone tell; a data frame (full or delta, told by the state) gives nil, true.
local function kind_of_fields(malformed_msg)
    if malformed_msg then return "malformed", false end
    if pr_has_e or pr_has_m then return "command", false end
    if pr_has_p then return "ping", false end
    if pr_has_g then return "pong", false end
    if pr_has_r then return "reply", false end
    local nd, nq, ord_text = pr_nd, pr_nq, pr_ord_text
    if nd == 0 and nq > 0 and (pr_l_ord or pr_n_ord) and not ord_text then return "declaration", false end
    if nd == 0 and (nq > 0 or ord_text) then return "query", false end
    if nd > 0 or pr_n_ord then return nil, true end
    return "other", false
end

-- The journal: linear state for a direction with many names.  A direction with up to
-- JOURNAL_NAMES names stores, for each frame that leaves some out, their values in the frame's
-- record (cheap, few objects: see carried_store).  Past that, a copy per frame would grow with
-- the names (quadratic), so the direction keeps instead, for each name, the values it took and
-- the frames they came from (d.hist[name] = { key, value, key, value, ... }, a frame's key
-- num * 2^20 + its offset in the packet: frames in capture order) and d.nkey, the key of the
-- frame each name was first sent in (in the order of d.names); a later pass finds what a frame
-- carried from them.  d.jkey: the key of the first frame judged by the journal.
local JOURNAL_NAMES = 32
local journal
do
    local function fkey(num, sk) return num * 1048576 + sk % 1048576 end

    local function start(d, key)
        local hist, vals, from = {}, d.vals, d.from
        for _, name in ipairs(d.names) do
            hist[name] = { (from[name] or 0) * 1048576, vals[name] or false }
        end
        d.hist, d.jkey = hist, key
        LIM.journal = true
        return hist
    end

    local function set(hist, name, key, val)
        local h = hist[name]
        if not h then h = {}; hist[name] = h end
        local n = #h
        if n > 0 and h[n - 1] == key then h[n] = val else h[n + 1], h[n + 2] = key, val end
    end

    -- the value name had before the frame of key (and its frame), false, false when none
    local function get(h, key)
        if not h then return false, false end
        local lo, hi, found = 1, #h / 2, nil
        while lo <= hi do
            local mid = floor((lo + hi) / 2)
            if h[2 * mid - 1] < key then found = mid; lo = mid + 1 else hi = mid - 1 end
        end
        if not found then return false, false end
        return h[2 * found], floor(h[2 * found - 1] / 1048576)
    end

    -- how many names the direction knew at the frame of key (first sent at or before it)
    local function known_at(d, key)
        local nk = d.nkey
        local lo, hi, found = 1, #nk, 0
        while lo <= hi do
            local mid = floor((lo + hi) / 2)
            if nk[mid] <= key then found = mid; lo = mid + 1 else hi = mid - 1 end
        end
        return found
    end

    -- A later pass, a named data frame the journal judged: the number of names it carried, and
    -- with fill, the names in MISS (name, value, frame, ...; nm entries) as the first pass had them.
    local PRESENT, pstamp = {}, 0
    local function missing(d, key, fill)
        pstamp = pstamp + 1
        local npos, nk, present = d.npos, d.nkey, 0
        for v = 1, nv do
            local name = VN[v]
            if name and VV[v] and PRESENT[name] ~= pstamp then
                local i = npos[name]
                if i and nk[i + 1] <= key then present = present + 1 end
                PRESENT[name] = pstamp
            end
        end
        local known = known_at(d, key)
        local nm = 0
        if fill then
            local names, hist = d.names, d.hist
            for k = 1, known do
                local name = names[k]
                if PRESENT[name] ~= pstamp then
                    local cv, cf = get(hist[name], key)
                    MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, cv, cf
                    nm = nm + 3
                end
            end
        end
        return known - present, nm
    end
    journal = { key = fkey, start = start, set = set, missing = missing }
end

-- state_first_pass and its helpers (a block, as parse_frame)
local state_first_pass
do
    -- State, first pass, a data frame: its values go into the direction's state (good checksum),
    -- what it leaves out is gathered in CARRY (empty D fields: value, frame, ...; ne entries) and
    -- MISS (named variables: name, value, frame, ...; nm entries).  Returns whether it is full,
    -- ne, nm, the number of named variables carried, and full_local (the verdict without state).
    local function data_values(d, list, num, sk, good, full_local, has_tree)
        local fast_sh, n_pos, nd, n_ord = pr_fast_sh, pr_n_pos, pr_nd, pr_n_ord
        local ne, nm, miss_n = 0, 0, 0
        local full
        local hist, key = d.hist, nil
        if hist or #d.names > JOURNAL_NAMES then
            key = journal.key(num, sk)
            if not hist and not d.over then hist = journal.start(d, key) end
        end
        if good and fast_sh and d.names_is == fast_sh.N and not hist then
            -- same layout as the known variable set: nothing can be missing
            local vals, from = d.vals, d.from
            for v = 1, nv do
                local name = VN[v]
                vals[name] = VV[v]
                from[name] = num
            end
            full = full_local
        else
            local vals, from, seen = d.vals, d.from, d.seen
            local names = d.names
            stamp_ctr = stamp_ctr + 1
            local stamp = stamp_ctr
            local required_missing = false   -- a slot that held a value is empty here
            local maxslot = -1
            local present = 0                -- known names present (distinct)
            local max_slots = LIM.max_slots
            ne = 0
            for v = 1, nv do
                local val = VV[v]
                if val then
                    local name = VN[v]
                    if name then
                        local st = seen[name]
                        if not st and good then
                            if #names < LIM.max_names then
                                names[#names + 1] = name
                                d.npos[name] = #names - 1
                                d.nfirst[name] = num
                                d.nkey[#names] = key or journal.key(num, sk)
                                d.names_is = nil
                                st = 0
                            else
                                -- a new name past max_names: no state
                                LIM.hit = "Limit exceeded: more than " .. LIM.max_names ..
                                    " names in this direction (max_names)"
                            end
                        end
                        if st then
                            if good then
                                vals[name] = val
                                from[name] = num
                                if hist then journal.set(hist, name, key, val) end
                            end
                            if st ~= stamp then present = present + 1; seen[name] = stamp end
                        end
                    elseif VI[v] < max_slots then
                        local slot = VI[v]
                        name = list[slot + 1] or ("#" .. slot)
                        if slot > maxslot then maxslot = slot end
                        if val == "" then
                            local cv = vals[name]
                            if cv then required_missing = true end
                            CARRY[ne + 1] = cv or false
                            CARRY[ne + 2] = from[name] or false
                            ne = ne + 2
                        elseif good then
                            vals[name] = val
                            from[name] = num
                            if slot > d.maxslot then d.maxslot = slot end
                        end
                    end
                end
            end
            -- positional: required slots past the frame's last D
            if n_pos > 0 then
                for slot = maxslot + 1, d.maxslot do
                    if vals[list[slot + 1] or ("#" .. slot)] then required_missing = true; break end
                end
            end
            -- named: known variables missing from this frame (a journal: counted; listed only
            -- for a tree, kept in no record)
            if n_pos == 0 and #names > 0 and hist then
                miss_n = #names - present
                if has_tree then
                    for k = 1, #names do
                        local name = names[k]
                        if seen[name] ~= stamp then
                            MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, vals[name] or false, from[name] or false
                            nm = nm + 3
                        end
                    end
                end
            elseif n_pos == 0 and #names > 0 then
                for k = 1, #names do
                    local name = names[k]
                    if seen[name] ~= stamp then
                        MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, vals[name] or false, from[name] or false
                        nm = nm + 3
                        miss_n = miss_n + 1
                    end
                end
            end
            if fast_sh and good and miss_n == 0 and #names == fast_sh.n then d.names_is = fast_sh.N end
            full = nd > 0 and (n_ord == nil or n_ord == 0) and not required_missing and miss_n == 0
            if n_pos == 0 then full_local = full_local and miss_n == 0 end
        end
        return full, ne, nm, miss_n, full_local, hist ~= nil
    end

    -- State, first pass, a data frame: the sync clock, and the record later passes read (late
    -- sync, carried values, a kind the fields alone do not tell).  Returns the record and kind.
    local function data_record(pinfo, d, num, sk, full, full_local, good, ne, nm)
        local rec = LIM.hit and get_rec(num, sk, true) or nil   -- a limit's expert: a table record
        local kind
        local now = pinfo.rel_ts
        local first = d.first
        if not first then first = now; d.first = now end
        if full then
            if good then d.lastfull = now end
        else
            local age = now - (d.lastfull or first)
            if age > pref_sync then
                rec = rec or get_rec(num, sk, true)
                rec.late = age
            end
        end
        local kch = full and "f" or "d"
        -- carried values of empty D fields: a packed text record unless the
        -- frame has a table record anyway
        if ne > 0 or nm > 0 then
            if rec or not carried_store(num, sk, ne, nm, kch) then
                rec = rec or get_rec(num, sk, true)
                for k = 1, ne do rec[k] = CARRY[k] end
                if nm > 0 then
                    local miss = {}
                    for k = 1, nm do miss[k] = MISS[k] end
                    rec.miss = miss
                end
            end
        elseif full ~= full_local then
            rec = rec or get_rec(num, sk, true)
        end
        if rec then rec.kind = kch end
        kind = full and "full" or "delta"
        return rec, kind
    end

    -- State, first pass, a declaration with a good checksum: the list it declares.
    local function learn_declaration(pinfo, num, dstb, srcb, dst, src, letters)
        local l_ord, n_ord = pr_l_ord, pr_n_ord
        local dd, rl
        if l_ord then
            -- the sender's inbound list = the list used from dst to src
            dd = get_rev_dir(pinfo, dstb, srcb)
            rl = dst .. src
        else
            dd = get_dir(pinfo, num, dstb, srcb)
            rl = letters
        end
        local base_list = dd.list or pair_lists[rl] or pref_list
        local newlist = {}
        local types = {}
        newlist.t = types
        local start = l_ord or n_ord or 0
        for k = 1, math.min(start, #base_list) do
            newlist[k] = base_list[k]
            types[k] = base_list.t and base_list.t[k]
        end
        local maxi = #newlist
        for v = 1, nv do
            if VN[v] and VI[v] < LIM.max_slots then
                newlist[VI[v] + 1] = VN[v]
                types[VI[v] + 1] = VT[v] and valid_type(VT[v]) or nil
                if VI[v] + 1 > maxi then maxi = VI[v] + 1 end
            end
        end
        for k = 1, maxi do newlist[k] = newlist[k] or ("#" .. (k - 1)) end
        dd.list = newlist
        pair_lists[rl] = newlist
    end

    -- State, first pass: a query or declaration waits for its reply; a reply finds its query.
    local function link_query_reply(pinfo, num, sk, kind, dst, src, rec)
        local pa, pb = pinfo.src_port, pinfo.dst_port
        if pa > pb then pa, pb = pb, pa end
        local ports = ":" .. pa .. "-" .. pb
        for v = 1, nv do
            local name = VN[v]
            if name then
                if VR[v] then
                    rec = rec or get_rec(num, sk, true)
                    local qkey = dst .. ">" .. src .. ":" .. name .. ports
                    local qrec = pending_q[qkey]
                    if qrec then
                        pending_q[qkey] = nil
                        local ck = dst .. ">" .. src .. ports
                        LIM.npend[ck] = (LIM.npend[ck] or 1) - 1
                        qrec.resp_in = qrec.resp_in or {}
                        qrec.resp_in[name] = num
                        rec.resp_to = rec.resp_to or {}
                        rec.resp_to[name] = qrec.num
                        rec.rt = rec.rt or {}
                        rec.rt[name] = pinfo.rel_ts - qrec.t
                    else
                        rec.unmatched = rec.unmatched or {}
                        rec.unmatched[name] = true
                    end
                elseif kind ~= "reply" then
                    rec = rec or get_rec(num, sk, true)
                    rec.num = num
                    rec.t = pinfo.rel_ts
                    local qkey, ck = src .. ">" .. dst .. ":" .. name .. ports, src .. ">" .. dst .. ports
                    if pending_q[qkey] then
                        pending_q[qkey] = rec
                    elseif (LIM.npend[ck] or 0) < LIM.max_pending then
                        pending_q[qkey] = rec
                        LIM.npend[ck] = (LIM.npend[ck] or 0) + 1
                    else
                        LIM.hit = "Limit exceeded: more than " .. LIM.max_pending ..
                            " unanswered queries in this conversation (max_pending)"
                    end
                end
            end
        end
        return rec
    end

    -- State on the first pass.  Returns the kind, the record (nil: none), the list in use, the
    -- direction state (data frames), the named variables carried, and ne/nm (see data_values).
    function state_first_pass(pinfo, num, sk, kind, is_data, good, dstb, srcb, dst, src, addrs_ok, full_local,
                              has_tree)
        local rec, list, d = nil, pref_list, nil
        local miss_n, ne, nm = 0, 0, 0
        LIM.hit = false
        local letters = src .. dst
        if (is_data or kind == "malformed") and addrs_ok then
            d = get_dir(pinfo, num, dstb, srcb)
            if d.over then
                LIM.hit = "Limit exceeded: more than " .. LIM.max_conversations .. " directions with state" ..
                    " (max_conversations); this one keeps none"
            end
            list = d.list or pair_lists[letters] or pref_list
            -- remember when the list in use changes (read back on later passes)
            if list ~= (d.used_list or pref_list) then
                local h = d.uhist
                if not h then h = {}; d.uhist = h end
                h[#h + 1] = num
                h[#h + 1] = sk
                h[#h + 1] = list
                d.used_list = list
            end
            if is_data then
                local full, journaled
                full, ne, nm, miss_n, full_local, journaled = data_values(d, list, num, sk, good, full_local, has_tree)
                -- a journal's carried names go in no record (see journal)
                rec, kind = data_record(pinfo, d, num, sk, full, full_local, good, ne, journaled and 0 or nm)
            end
        elseif kind == "declaration" and addrs_ok and good then
            learn_declaration(pinfo, num, dstb, srcb, dst, src, letters)
        end
        if (kind == "query" or kind == "reply" or kind == "declaration") and addrs_ok and good then
            rec = link_query_reply(pinfo, num, sk, kind, dst, src, rec)
        end
        if LIM.hit then
            rec = rec or get_rec(num, sk, true)
            rec.limit = LIM.hit
        end
        return kind, rec, list, d, miss_n, ne, nm
    end
end

-- The list in use at frame (num, sk) on the first pass, from the direction's history of changes.
-- The entries (num, sk, list) are in capture order: a binary search (linear time over a pass).
local function list_at(d, num, sk)
    local h = d.uhist
    if not h then return pref_list end
    local lo, hi, found = 1, #h / 3, nil
    while lo <= hi do
        local mid = floor((lo + hi) / 2)
        local hn = h[3 * mid - 2]
        if hn < num or (hn == num and h[3 * mid - 1] <= sk) then found = mid; lo = mid + 1 else hi = mid - 1 end
    end
    return found and h[3 * found] or pref_list
end

-- State on a later pass: the record, and the list in use at this frame on the first pass
-- (looked up only where it names something: positional values, or a tree to show indexes).
local function state_later_pass(pinfo, num, sk, kind, is_data, dstb, srcb, addrs_ok, full_local, has_tree)
    local rec = get_rec(num, sk, false)
    local miss_n = (rec and rec.miss) and floor(#rec.miss / 3) or 0
    local nm = 0
    local list, d = pref_list, nil
    if (is_data or kind == "malformed") and addrs_ok and (has_tree or pr_n_pos > 0 or LIM.journal) then
        d = get_dir(pinfo, num, dstb, srcb)
        list = list_at(d, num, sk)
        -- a named frame the journal judged: what it carried, from the journal
        if is_data and d.jkey and pr_n_pos == 0 then
            local key = journal.key(num, sk)
            if key >= d.jkey then miss_n, nm = journal.missing(d, key, has_tree) end
        end
    end
    if is_data then
        if rec and rec.kind then
            kind = rec.kind == "f" and "full" or "delta"
        else
            kind = (full_local and miss_n == 0) and "full" or "delta"
        end
    end
    return kind, rec, list, d, miss_n, nm
end

-- Info column: this frame's piece.
local function info_frame(f, bodyend, kind, is_data, rec, list, src, dst, miss_n)
    local fast_sh, n_empty_d, l_ord, n_ord = pr_fast_sh, pr_n_empty_d, pr_l_ord, pr_n_ord
    local cmd_start, cpos = pr_cmd_start, pr_cpos
    if frames_in_info > 0 then
        if info_full then frames_dropped = frames_dropped + 1 else info_add(" ; ") end
    end
    frames_in_info = frames_in_info + 1
    local info_done = false
    if fast_sh and frames_in_info == 1 and (kind == "full" or kind == "delta") and not (rec and rec.late) then
        -- same text as the pieces below, in one concatenation (speed trick, measured)
        local full = kind == "full"
        local total = full and fast_sh.info_len or fast_sh.dinfo_len
        for k = 1, nv do total = total + #VV[k] end
        local tail = (miss_n > 0) and (" (+" .. miss_n .. " carried)") or nil
        if tail then total = total + #tail end
        if total <= INFO_MAX then
            ninfo, info_len = 1, total
            INFO[1] = (full and fast_sh.xinfo or fast_sh.xdinfo)(VV[1], VV[2], VV[3], VV[4], VV[5], VV[6], VV[7],
                VV[8])
            if tail then INFO[1] = INFO[1] .. tail end
            info_done = true
        end
    end
    if not info_done then info_clean = false end
    if not info_full and not info_done then
        info_add(src .. ARROW .. dst .. " " .. kind)
        if is_data or kind == "reply" or kind == "malformed" then
            for v = 1, nv do
                if info_full then break end
                local val = VV[v]
                if val and (val ~= "" or VN[v]) then
                    local name = VN[v]
                    if not name then name = list[VI[v] + 1] or ("#" .. VI[v]) end
                    info_add(" " .. name .. "=" .. val)
                end
            end
            local nc = n_empty_d + miss_n
            if nc > 0 then info_add(" (+" .. nc .. " carried)") end
        elseif kind == "query" then
            for v = 1, nv do
                if VN[v] then info_add(" " .. VN[v]) end
            end
        elseif kind == "declaration" then
            info_add(l_ord and (" L" .. l_ord) or (" N" .. (n_ord or 0)))
            for v = 1, nv do
                if VN[v] then info_add(" " .. VN[v]) end
            end
        elseif kind == "command" and cmd_start then
            local cmd = s_gsub(s_sub(f, cmd_start, cpos and cpos - 2 or bodyend), "|D?", " ")
            info_add(" " .. cmd)
        end
        if rec and rec.late then info_add(" [sync late]") end
    end
end

local tree_compact_frame
do
-- Fields of a frame parsed by a fast path, for a tree nobody sees (a display filter,
-- coloring rules, a tap): the fields of the full tree with their values, without byte
-- ranges, labels or flags, which only a visible tree shows.  Speed trick (measured: each
-- TvbRange, label or flag is one more Lua-to-C call).  The full tree is built below.
-- vals: the frame's values; carry: carried values of its empty D fields (value, frame, ...);
-- miss: named variables left out (name, value, frame, ...), nmiss entries.
--
-- Only the fields somebody asked for are repeated per variable.  In a tree nobody sees,
-- Wireshark adds a field only when a filter, coloring rule or tap references it; for any
-- other it hands back the parent item (proto.c, TRY_TO_FAKE_THIS_ITEM), whose text is the
-- parent's text.  So the first item of each per-variable field in a frame tells whether the
-- field is referenced (its text differs from its parent's: a real item has its own label;
-- checked on 4.0, 4.4 and 4.6), and an unreferenced field is not added again for the
-- frame's other variables (about 18 fewer Lua-to-C calls in a beacon frame).  Decided
-- again in every frame, as the referenced fields change when the user changes a filter.
--
-- tshark (no GUI) keeps what it learnt for the whole pass, every field included: its filters,
-- taps and field extractors are all set before the first packet and a field Wireshark once
-- saw referenced stays referenced.  (tshark -2 primes the display filter in its first pass
-- too; the cache starts again with each pass all the same.)  The GUI learns again in
-- every frame: its display filter and coloring rules change while it runs, and it dissects
-- packet-list rows (coloring rules only) in the middle of a filter pass.  The environment
-- variable SHAREDLINK_PROBE_EACH_FRAME makes tshark do as the GUI (for the tests).
local REF = {}      -- field -> referenced (nil: not known yet)
local VAR_FIELDS = { hf.var, hf.ftype, hf.var_name, hf.var_index, hf.var_value, hf.var_double,
    hf.var_long, hf.var_string, hf.var_carried, hf.var_carried_from }
local CACHE_REFS = wsapi.cache_refs
local ref_num, ref_visited = -1, nil   -- the frame and pass the cache was last used in
local UNKNOWN = {}  -- "the parent's text is not read yet"

-- Add field = value under parent (whose text is ptext, or UNKNOWN) unless the field is known
-- to be unreferenced; learn that on its first item.  Returns the item or nil.
local function ref_add(parent, ptext, field, value)
    local r = REF[field]
    if r == false then return nil end
    local it
    if value == nil then it = TI.add(parent, field) else it = TI.add(parent, field, value) end
    if r == nil then
        if ptext == UNKNOWN then ptext = parent.text end
        r = wsapi.referenced(it, ptext)
        REF[field] = r
    end
    return r and it or nil
end

-- Start a frame's compact tree: the learnt fields kept (tshark, the same pass) or forgotten.
-- Returns the text ref_add compares ti's children with.
local function ref_start(ti, num, visited)
    if CACHE_REFS then
        if visited ~= ref_visited or (num ~= ref_num and num ~= ref_num + 1) then
            for k in pairs(REF) do REF[k] = nil end
            ref_visited = visited
        end
        ref_num = num
        return UNKNOWN
    end
    for k = 1, #VAR_FIELDS do REF[VAR_FIELDS[k]] = nil end
    return ti.text
end

-- A field of the frame itself in the compact tree: learnt as the per-variable ones when the
-- cache is on, else always added (once a frame, a probe would cost as much as it saves).
local function frame_add(ti, ttext, field, value)
    if CACHE_REFS then return ref_add(ti, ttext, field, value) end
    return TI.add(ti, field, value)
end

-- A variable's item in the compact tree: its subtree, or ti itself when nobody asked for
-- sharedlink.var; and the text its children are compared with (var_text: a real variable
-- item's text, the same for all; reset each frame).
local var_text = nil
local function compact_var(ti, ttext)
    local vt = ref_add(ti, ttext, hf.var)
    if not vt then return ti, ttext end
    var_text = var_text or vt.text
    return vt, var_text
end

-- A carried value's fields: its value and frame when known.
local function compact_carried(vt, ptext, cv, cf)
    if cv then ref_add(vt, ptext, hf.var_value, cv) end
    ref_add(vt, ptext, hf.var_carried, true)
    if cf then ref_add(vt, ptext, hf.var_carried_from, cf) end
end

local function tree_compact(ti, ttext, dstb, srcb, kind, n_ord, nvars, list, d, num, carry, miss, nmiss, fast_tv)
    frame_add(ti, ttext, hf.dst, LETTER[dstb])
    frame_add(ti, ttext, hf.dst_node, dstb - B_A + 1)
    frame_add(ti, ttext, hf.src, LETTER[srcb])
    frame_add(ti, ttext, hf.src_node, srcb - B_A + 1)
    frame_add(ti, ttext, hf.kind, kind)
    frame_add(ti, ttext, hf.ordinal, n_ord)
    var_text = nil
    local ke = 0
    for v = 1, nvars do
        local vt, ptext = compact_var(ti, ttext)
        local name, val = VN[v], VV[v]
        local vtype
        local index = VI[v]
        if name then
            vtype = fast_tv and fast_tv[v] or valid_type(VT[v])
            ref_add(vt, ptext, hf.ftype, vtype)
            if d then
                local first = d.nfirst[name]
                index = (first and first <= num) and d.npos[name] or nil
            end
        else
            name = list[index + 1]
            vtype = list.t and list.t[index + 1]
        end
        if name then
            ref_add(vt, ptext, hf.var_name, name)
        else
            TI.add_proto_expert_info(vt, ei.var_unknown,
                "Positional value " .. VI[v] .. " is past the known list (" .. #list .. " variables)")
        end
        if index then ref_add(vt, ptext, hf.var_index, index) end
        if val ~= "" or VN[v] then
            ref_add(vt, ptext, hf.var_value, val)
            if vtype then
                if vtype == 2 then
                    local x = tonumber(val)
                    if x then ref_add(vt, ptext, hf.var_double, x)
                    else TI.add_proto_expert_info(vt, ei.var_badvalue, "Not a double: " .. val) end
                elseif vtype == 0 then
                    local x = parse_long(val)
                    if x then ref_add(vt, ptext, hf.var_long, x)
                    else TI.add_proto_expert_info(vt, ei.var_badvalue, "Not a long (int64): " .. val) end
                elseif vtype == 4 then
                    ref_add(vt, ptext, hf.var_string, val)
                end
            end
        else
            local cv, cf = false, false
            if carry then cv, cf = carry[ke + 1], carry[ke + 2] end
            ke = ke + 2
            compact_carried(vt, ptext, cv, cf)
        end
    end
    for k = 1, nmiss, 3 do
        local name = miss[k]
        local vt, ptext = compact_var(ti, ttext)
        ref_add(vt, ptext, hf.var_name, name)
        local index = d and d.npos[name]
        if index then ref_add(vt, ptext, hf.var_index, index) end
        compact_carried(vt, ptext, miss[k + 1], miss[k + 2])
    end
end

-- The compact tree of a fast-path frame nobody sees: its fields (tree_compact), the sync and
-- checksum fields and experts, without ranges or labels.
function tree_compact_frame(ti, a, e, fl, s, dstb, srcb, kind, list, d, num, visited, rec, ne, nm,
                                  cs_val, cs_calc, cs_status)
    local ctext = pr_ctext
    local carry = rec or (ne > 0 and CARRY)
    local miss = rec and rec.miss
    local nmiss = miss and #miss or 0
    if not miss and nm > 0 then miss, nmiss = MISS, nm end
    local ttext = ref_start(ti, num, visited)
    -- the last argument: the types of the named fast path's layout, made when it was learnt
    tree_compact(ti, ttext, dstb, srcb, kind, pr_n_ord, nv, list, d, num, carry, miss, nmiss,
        pr_fast_sh and pr_fast_sh.TV)
    if rec and rec.late then
        frame_add(ti, ttext, hf.sync_is_late, true)
        TI.add_proto_expert_info(ti, ei.sync_late)
    end
    if pr_limit then TI.add_proto_expert_info(ti, ei.limit, pr_limit) end
    if rec and rec.limit then TI.add_proto_expert_info(ti, ei.limit, rec.limit) end
    if cs_val then frame_add(ti, ttext, hf.checksum, cs_val) else frame_add(ti, ttext, hf.checksum_text, ctext) end
    if #ctext ~= 2 or s_find(ctext, "[^0-9A-F]") then TI.add_proto_expert_info(ti, ei.checksum_format) end
    if pref_validate then
        frame_add(ti, ttext, hf.checksum_calc, cs_calc)
        frame_add(ti, ttext, hf.checksum_status, cs_status)
        if cs_status == 0 then TI.add_proto_expert_info(ti, ei.checksum_bad) end
    else
        frame_add(ti, ttext, hf.checksum_status, 2)
    end
    local b = a + fl - 1
    if not (e == b + 2 and s_byte(s, b + 1) == B_CR and s_byte(s, b + 2) == B_LF) then
        TI.add_proto_expert_info(ti, ei.crlf_missing)
    end
end

end

-- The full tree (shown: every range and label).
local tree_full
do
    local TC = {}   -- what the parts share, for the frame tree_full was given (reused)

    -- An address: "Destination: A (node 1)", the node number folded into the letter's line,
    -- its field kept for filters but hidden; an expert when it is not a letter A-P.
    -- Speed trick (measured, -V): the labels are made once a letter (ADDR_LABEL[what][b]).
    local ADDR_LABEL = { Destination = {}, Source = {} }
    local function tree_address(ti, tvb, off, b, letter, is_node, field, node_field, what)
        if not b then return end   -- cut short: no byte to point at
        local r = tvb(off, 1)
        if is_node then
            local labels = ADDR_LABEL[what]
            local label = labels[b]
            if not label then
                label = what .. ": " .. letter .. " (node " .. (b - B_A + 1) .. ")"
                labels[b] = label
            end
            TI.add(ti, field, r, letter, label)
            TI.set_hidden(TI.add(ti, node_field, r, b - B_A + 1))
        else
            TI.add_proto_expert_info(TI.add(ti, field, r, letter), ei.address_invalid,
                what .. " " .. letter .. " is not a letter A-P")
        end
    end

    -- The protocol line: "SharedLink Protocol, B→A full" (", bad checksum").  Speed trick
    -- (measured, -V): the item is added with its text, one call, and the texts of node pairs
    -- (both addresses A-P: nodes) are kept (HEAD_TEXT[kind][pair key]).
    local HEAD_TEXT = {}
    local function tree_proto_item(tree, range, kind, dstb, srcb, dst, src, cs_status, nodes)
        local bad = cs_status == 0
        local byk, hk = HEAD_TEXT[kind], nil
        if nodes then
            hk = (dstb * 256 + srcb) * 2 + (bad and 1 or 0)
            if byk then
                local text = byk[hk]
                if text then return TI.add(tree, sl, range, text) end
            end
        end
        local text = "SharedLink Protocol, " .. src .. ARROW .. dst .. " " .. kind .. (bad and ", bad checksum" or "")
        if hk then
            if not byk then byk = {}; HEAD_TEXT[kind] = byk end
            byk[hk] = text
        end
        return TI.add(tree, sl, range, text)
    end

    -- Its first lines: the protocol item, addresses, kind, malformed.
    local function tree_head(tc)
        local tvb, o, src, dst, kind = tc.tvb, tc.o, tc.src, tc.dst, tc.kind
        local dstb, srcb, malformed_msg, cs_status = tc.dstb, tc.srcb, tc.malformed_msg, tc.cs_status
        local dnode = dstb and dstb >= B_A and dstb <= B_P
        local snode = srcb and srcb >= B_A and srcb <= B_P
        local ti = tree_proto_item(tc.tree, tvb(tc.a - 1, tc.e - tc.a + 1), kind, dstb, srcb, dst, src, cs_status,
            dnode and snode)
        tc.ti = ti

        tree_address(ti, tvb, o + 3, dstb, dst, dnode, hf.dst, hf.dst_node, "Destination")
        tree_address(ti, tvb, o + 4, srcb, src, snode, hf.src, hf.src_node, "Source")
        TI.set_generated(TI.add(ti, hf.kind, kind))
        if malformed_msg then
            TI.add_proto_expert_info(ti, ei.malformed, malformed_msg)
        end
    end

    -- A variable's subtree, at its first field fs.
    local function tree_variable(tc, v, fs)
        local ti, tvb, o, list, d, num, rec, ne = tc.ti, tc.tvb, tc.o, tc.list, tc.d, tc.num, tc.rec, tc.ne
        local resp_in, resp_to, rts, unmatched = tc.resp_in, tc.resp_to, tc.rts, tc.unmatched
        local ke = tc.ke
        local tf, qf, df = VTf[v], VQf[v], VDf[v]
        local vend = df ~= 0 and df or (qf ~= 0 and qf or tf)
        local name = VN[v]
        local named = name and true or false
        local index = VI[v]
        local vtype = nil
        if not named then
            name = list[index + 1]
            vtype = list.t and list.t[index + 1]
        elseif d then
            -- a named variable's index: its place among the conversation's names
            local first = d.nfirst[name]
            index = (first and first <= num) and d.npos[name] or nil
        end
        local vt = TI.add(ti, hf.var, tvb(o + fs, FE[vend] - fs + 1))
        local label = name or ("#" .. VI[v])
        if tf ~= 0 then
            vtype = valid_type(VT[v])
            if vtype then
                TI.add(vt, hf.ftype, tvb(o + FS[tf] + 1, FE[tf] - FS[tf]), vtype)
            else
                vt:add(tvb(o + FS[tf], FE[tf] - FS[tf] + 1), "Type (T): " .. tostring(VT[v] or ""))
                    :add_proto_expert_info(ei.var_badvalue, "Type is not a number")
            end
        end
        -- the name is the subtree's label: its field is kept for filters, hidden
        if named then
            local qr = tvb(o + FS[qf] + 1, FE[qf] - FS[qf])
            if VR[v] then TI.add(vt, hf.response, qr, name) end
            TI.set_hidden(TI.add(vt, hf.var_name, qr, name))
        elseif name then
            TI.set_hidden(TI.add(vt, hf.var_name, tvb(o + FS[df], 1), name))
        else
            TI.add_proto_expert_info(vt, ei.var_unknown,
                "Positional value " .. VI[v] .. " is past the known list (" .. #list .. " variables)")
        end
        if not VR[v] and index then TI.set_generated(TI.add(vt, hf.var_index, index)) end
        local val = VV[v]
        if val then
            if val ~= "" or named then
                local vr = tvb(o + FS[df] + 1, FE[df] - FS[df])
                TI.add(vt, hf.var_value, vr, val)
                if vtype then add_typed_value(vt, vr, vtype, val) end
                TI.set_text(vt, label .. " = " .. val)
            else
                local cv, cf = false, false
                local csrc = rec or (ne > 0 and CARRY)
                if csrc then cv, cf = csrc[ke + 1], csrc[ke + 2] end
                ke = ke + 2
                local r0 = tvb(o + FS[df], 1)
                if cv then TI.set_generated(TI.add(vt, hf.var_value, r0, cv)) end
                TI.set_generated(TI.add(vt, hf.var_carried, r0, true))
                if cf then
                    TI.set_generated(TI.add(vt, hf.var_carried_from, r0, cf))
                    TI.set_text(vt, label .. " = " .. tostring(cv) .. " (carried from frame " .. cf .. ")")
                else
                    TI.set_text(vt, label .. " = ? (carried, no earlier value)")
                end
            end
            if VR[v] then
                if resp_to and resp_to[name] then
                    TI.set_generated(TI.add(vt, hf.response_to, resp_to[name]))
                    TI.set_generated(TI.add(vt, hf.response_time, nstime_of(rts[name])))
                elseif unmatched and unmatched[name] then
                    TI.add_proto_expert_info(vt, ei.unanswered)
                end
            end
        else
            TI.set_text(vt, label .. (VR[v] and " (reply without value)" or " (declared)"))
            if resp_in and resp_in[name] then
                TI.set_generated(TI.add(vt, hf.response_in, resp_in[name]))
            end
        end
        tc.ke = ke
    end

    -- A field that is not part of a variable (letter l, f[fs..fe]).
    local function tree_plain_field(tc, l, fs, fe)
        local ti, tvb, o, f, resp_in = tc.ti, tc.tvb, tc.o, tc.f, tc.resp_in
        local cmd_item = tc.cmd_item
        local text = (l ~= false) and s_sub(f, fs + 1, fe) or ""
        local vr = tvb(o + fs + 1, fe - fs)     -- the text after the letter
        if l == false then
            TI.add_proto_expert_info(TI.add(ti, zrange(tvb, o + fs), "Empty field"), ei.field_empty)
        elseif l == L_N or l == L_L then
            local n = tonumber(text)
            if n and n >= 0 and n < 4294967296 and n == floor(n) then
                TI.add(ti, l == L_N and hf.ordinal or hf.inbound_ordinal, vr, floor(n))
            else
                ti:add(tvb(o + fs, fe - fs + 1), (l == L_N and "Ordinal (N): " or "Inbound ordinal (L): ") ..
                    text):add_proto_expert_info(ei.var_badvalue, "Ordinal is not a number")
            end
        elseif l == L_Q then
            local qt = TI.add(ti, hf.query, vr, text)
            if resp_in and resp_in[text] then
                TI.set_generated(TI.add(qt, hf.response_in, resp_in[text]))
            end
        elseif l == L_R then
            TI.add(ti, hf.response, vr, text)
        elseif l == L_T then
            local t = valid_type(text)
            if t then
                TI.add(ti, hf.ftype, vr, t)
            else
                ti:add(tvb(o + fs, fe - fs + 1), "Type (T): " .. text)
                    :add_proto_expert_info(ei.var_badvalue, "Type is not a number")
            end
        elseif l == L_E then
            cmd_item = TI.add(ti, hf.command, vr, text)
        elseif l == L_M then
            TI.add(ti, hf.mode, vr, text)
        elseif l == L_P then
            TI.add(ti, hf.ping, vr, text)
        elseif l == L_G then
            TI.add(ti, hf.pong, vr, text)
        elseif l == L_D then
            (cmd_item or ti):add(hf.command_arg, vr, text)
        else
            local ft = TI.add(ti, hf.field_letter, tvb(o + fs, 1), LETTER[l])
            TI.add(ft, hf.field_text, tvb(o + fs, fe - fs + 1), s_sub(f, fs, fe))
            if l == L_C then
                TI.add_proto_expert_info(ft, ei.field_unknown, "Checksum field C that is not the last field")
            else
                TI.add_proto_expert_info(ft, ei.field_unknown, "Unknown field letter " .. LETTER[l])
            end
        end
        tc.cmd_item = cmd_item
    end

    -- The fields in order; a variable is rendered at its first field.
    local function tree_fields(tc)
        local kind, cpos = tc.kind, pr_cpos
        for i = 1, nf do FV[i] = 0; FC[i] = false end
        for v = 1, nv do
            if VV[v] or kind == "declaration" or VR[v] then
                local first = VTf[v] ~= 0 and VTf[v] or (VQf[v] ~= 0 and VQf[v] or VDf[v])
                FV[first] = v
                if VQf[v] ~= 0 and VQf[v] ~= first then FC[VQf[v]] = true end
                if VDf[v] ~= 0 and VDf[v] ~= first then FC[VDf[v]] = true end
            end
        end
        for i = 1, nf do
            local fs = FS[i]
            local v = FV[i]
            if v ~= 0 then
                tree_variable(tc, v, fs)
            elseif not FC[i] and fs ~= cpos then
                tree_plain_field(tc, FL[i], fs, FE[i])
            end
        end
    end

    -- Named variables this frame left out (carried forward).
    local function tree_carried_names(tc)
        local ti, tvb, o, rec, nm, d, bodyend = tc.ti, tc.tvb, tc.o, tc.rec, tc.nm, tc.d, tc.bodyend
        -- carried named variables (left out of this frame)
        local miss = rec and rec.miss
        local miss_len = miss and #miss or 0
        if not miss and nm > 0 then miss, miss_len = MISS, nm end    -- packed on this pass
        if miss then
            for k = 1, miss_len, 3 do
                local name, cv, cf = miss[k], miss[k + 1], miss[k + 2]
                local vt = TI.add(ti, hf.var, zrange(tvb, o + bodyend))
                TI.set_hidden(TI.add(vt, hf.var_name, name))
                local index = d and d.npos[name]
                if index then TI.set_generated(TI.add(vt, hf.var_index, index)) end
                if cv then TI.set_generated(TI.add(vt, hf.var_value, cv)) end
                TI.set_generated(TI.add(vt, hf.var_carried, true))
                if cf then
                    TI.set_generated(TI.add(vt, hf.var_carried_from, cf))
                    TI.set_text(vt, name .. " = " .. tostring(cv) .. " (carried from frame " .. cf .. ")")
                else
                    TI.set_text(vt, name .. " = ? (carried, no earlier value)")
                end
                TI.set_generated(vt)
            end
        end
    end

    -- Its last lines: sync, checksum, line terminator.
    local CHECKSUM_OK = {}   -- value -> "Checksum: 0x.. [correct]"
    local function tree_trailer(tc)
        local ti, tvb, o, rec, s, a, e, fl = tc.ti, tc.tvb, tc.o, tc.rec, tc.s, tc.a, tc.e, tc.fl
        local cs_val, cs_calc, cs_status = tc.cs_val, tc.cs_calc, tc.cs_status
        local terminated, malformed_msg = tc.terminated, tc.malformed_msg
        local cpos, ctext = pr_cpos, pr_ctext
        if pr_limit then TI.add_proto_expert_info(ti, ei.limit, pr_limit) end
        if rec and rec.limit then TI.add_proto_expert_info(ti, ei.limit, rec.limit) end
        if rec and rec.late then
            TI.set_generated(TI.add(ti, hf.sync_is_late, true))
            TI.add_proto_expert_info(ti, ei.sync_late,
                s_format("No full frame for %.3f s (sync interval %.3f s + %.1f s slack)",
                    rec.late, pref_sync - SYNC_SLACK, SYNC_SLACK))
        end

        -- Checksum
        if cpos then
            local cr = tvb(o + cpos, #ctext + 1)
            local val = cs_val
            local ct
            local correct = pref_validate and cs_status == 1
            if val and val <= 255 and correct then
                -- the label with " [correct]", one call (speed trick, measured: -V)
                local label = CHECKSUM_OK[val]
                if not label then
                    label = s_format("Checksum: 0x%02x [correct]", val)
                    CHECKSUM_OK[val] = label
                end
                ct = TI.add(ti, hf.checksum, cr, val, label)
            elseif val and val <= 255 then
                ct = TI.add(ti, hf.checksum, cr, val)
            else
                ct = TI.add(ti, hf.checksum_text, cr, ctext)
            end
            if #ctext ~= 2 or s_find(ctext, "[^0-9A-F]") then
                TI.add_proto_expert_info(ct, ei.checksum_format, "Checksum \"" .. ctext ..
                    "\" is not two upper-case hex digits")
            end
            if pref_validate then
                local calc = cs_calc
                TI.set_generated(TI.add(ct, hf.checksum_calc, cr, calc))
                if cs_status == 1 then
                    TI.set_generated(TI.add(ct, hf.checksum_status, cr, 1))
                    if not (val and val <= 255) then TI.append_text(ct, " [correct]") end
                else
                    TI.set_generated(TI.add(ct, hf.checksum_status, cr, 0))
                    TI.append_text(ct, s_format(" [incorrect, should be 0x%02x]", calc))
                    TI.add_proto_expert_info(ct, ei.checksum_bad,
                        s_format("Bad checksum: %s, calculated %02X", ctext, calc))
                end
            else
                TI.set_generated(TI.add(ct, hf.checksum_status, cr, 2))
            end
        else
            TI.set_generated(TI.add(ti, hf.checksum_status, 2))
            if terminated and not malformed_msg then
                TI.add_proto_expert_info(ti, ei.checksum_missing)
            end
        end

        -- line terminator
        if terminated then
            local b = a + fl - 1
            if not (e == b + 2 and s_byte(s, b + 1) == B_CR and s_byte(s, b + 2) == B_LF) then
                TI.add_proto_expert_info(ti, ei.crlf_missing)
            end
        end
    end

    -- The whole of it, for a frame at f[1..fl] (bodyend: its content's last index) that starts at
    -- s[a] and ends with its line end at s[e] (as dissect_frame's arguments), as parsed (the
    -- field and variable arrays, pr_cpos, pr_ctext), with its kind, state and checksum verdict.
    -- Called by dissect_frame and by the express lane; what the parts share goes in TC.
    function tree_full(tree, tvb, f, s, a, e, fl, terminated, bodyend, malformed_msg, num, kind, dstb, srcb,
                       list, d, rec, ne, nm, cs_val, cs_calc, cs_status)
        local tc = TC
        -- tvb offset of f[i] is o + i
        tc.tree, tc.tvb, tc.o, tc.f, tc.s, tc.a, tc.e, tc.fl = tree, tvb, a - 2, f, s, a, e, fl
        tc.num, tc.kind, tc.dstb, tc.srcb = num, kind, dstb, srcb
        tc.dst, tc.src = dstb and LETTER[dstb] or "?", srcb and LETTER[srcb] or "?"
        tc.malformed_msg, tc.terminated, tc.bodyend = malformed_msg, terminated, bodyend
        tc.list, tc.d, tc.rec, tc.ne, tc.nm = list, d, rec, ne, nm
        tc.cs_val, tc.cs_calc, tc.cs_status = cs_val, cs_calc, cs_status
        tc.resp_in, tc.resp_to = rec and rec.resp_in, rec and rec.resp_to
        tc.rts, tc.unmatched = rec and rec.rt, rec and rec.unmatched
        tc.ke, tc.cmd_item = 0, nil   -- carried values of empty D fields used so far; the E field's item
        tree_head(tc)
        tree_fields(tc)
        tree_carried_names(tc)
        tree_trailer(tc)
    end
end

-- Whether a variable's value would get var.badvalue or var.unknown (see has_experts).
local function values_have_experts(kind, list)
    local types = list.t
    for v = 1, nv do
        local val = VV[v]
        if val or kind == "declaration" or VR[v] then
            local vtype
            if VN[v] then
                if VT[v] then vtype = valid_type(VT[v]); if not vtype then return true end end
            else
                if not list[VI[v] + 1] then return true end
                vtype = types and types[VI[v] + 1]
            end
            if val and vtype and (val ~= "" or VN[v]) then
                if vtype == 2 then
                    if not tonumber(val) then return true end
                elseif vtype == 0 and not parse_long(val) then
                    return true
                end
            end
        end
    end
    return false
end

-- With no tree, whether the frame's tree would carry an expert info (true when unsure): then
-- the tree is built all the same, on the tree Wireshark gave (which keeps no items but reports
-- the experts to Expert Information and -z expert).  Checks what tree_full adds experts for.
local function has_experts(s, a, e, fl, terminated, malformed_msg, addrs_ok, kind, list, rec, cs_status)
    if malformed_msg or not addrs_ok or pr_odd or cs_status == 0 or not pr_cpos then return true end
    if rec and (rec.limit or rec.late or rec.unmatched) then return true end
    local ctext = pr_ctext
    if #ctext ~= 2 or s_find(ctext, "[^0-9A-F]") then return true end
    local b = a + fl - 1
    if terminated and not (e == b + 2 and s_byte(s, b + 1) == B_CR and s_byte(s, b + 2) == B_LF) then return true end
    return values_have_experts(kind, list)
end

-- f: a string holding the frame at f[1..fl] ('[' .. ']' when terminated, else up to
-- where it stops; bytes after fl may follow when terminated); a: index of f[1] in the
-- payload s; e: index in s of the last byte including the line end.  tree: nil when there is
-- none (see dissect); root: the tree Wireshark gave, for the expert infos of a frame then.
local function dissect_frame(f, fl, a, e, terminated, tvb, pinfo, tree, sk, s, root)
    local num = pinfo.number

    -- a tree that is shown (-V, -T fields/json, the GUI's details) gets every range and
    -- label; one nobody sees (-Y, coloring rules, taps) takes the fast paths too.  The
    -- protocol item is added once the frame is known (the full tree: with its text)
    local vis = tree ~= nil and PG.visible(tree)

    local bodyend, dstb, srcb, malformed_msg = parse_frame(f, fl, terminated, vis, true)
    local cs_val, cs_calc, cs_status = checksum_verdict(f, bodyend)
    local good = cs_status ~= 0
    local kind, is_data = kind_of_fields(malformed_msg)
    local dst, src = dstb and LETTER[dstb] or "?", srcb and LETTER[srcb] or "?"
    local addrs_ok = dstb and srcb and dstb >= B_A and dstb <= B_P and srcb >= B_A and srcb <= B_P
    -- without state: a data frame with N0 (or none), no empty positional D and no named
    -- variable left out is full; the state-based verdict is stored when it differs
    local full_local = pr_nd > 0 and (pr_n_ord == nil or pr_n_ord == 0) and pr_n_empty_d == 0

    local rec, list, d, miss_n
    local ne, nm = 0
    if not pinfo.visited then
        kind, rec, list, d, miss_n, ne, nm = state_first_pass(pinfo, num, sk, kind, is_data, good, dstb, srcb, dst, src,
            addrs_ok, full_local, tree ~= nil)
    else
        kind, rec, list, d, miss_n, nm = state_later_pass(pinfo, num, sk, kind, is_data, dstb, srcb, addrs_ok,
            full_local, tree ~= nil)
    end
    if is_data and not kind then kind = full_local and "full" or "delta" end   -- addresses not A-P

    info_frame(f, bodyend, kind, is_data, rec, list, src, dst, miss_n)

    -- Tree (skipped when there is none, e.g. tshark summary pass, unless it has expert infos:
    -- then built on root, where only the experts stay)
    if not tree then
        if not (root and has_experts(s, a, e, fl, terminated, malformed_msg, addrs_ok, kind, list, rec, cs_status)) then
            return
        end
        tree = root
        if pr_fast_hit then fast_positions(pr_fast_hit.ntext, nv, pr_fast_sh ~= nil) end
        vis = true
    end
    if pr_fast_hit and not vis then
        local ti = TI.add(tree, sl, tvb(a - 1, e - a + 1))
        tree_compact_frame(ti, a, e, fl, s, dstb, srcb, kind, list, d, num, pinfo.visited, rec, ne, nm,
            cs_val, cs_calc, cs_status)
        return
    end
    tree_full(tree, tvb, f, s, a, e, fl, terminated, bodyend, malformed_msg, num, kind, dstb, srcb, list, d, rec,
        ne, nm, cs_val, cs_calc, cs_status)
end
------------------------------------------------------------------------------
-- Payload scanning
------------------------------------------------------------------------------
-- Noise s[i..j] between frames (CR/LF alone is not noise).
local function add_noise(s, i, j, tvb, tree, root)
    local k = s_find(s, "[^\r\n]", i)
    if not k or k > j then return end
    if info_full then
        frames_dropped = frames_dropped + 1
    else
        if frames_in_info > 0 then info_add(" ; ") end
        info_add("noise (" .. (j - i + 1) .. " bytes)")
        frames_in_info = frames_in_info + 1
    end
    if not tree then
        -- no tree: the expert alone, on the tree Wireshark gave
        if root then TI.add_proto_expert_info(root, ei.noise, (j - i + 1) .. " bytes outside any frame") end
        return
    end
    local r = tvb(i - 1, j - i + 1)
    local ti = tree:add(sl, r)
    ti:append_text(", noise")
    ti:add(hf.noise, r):add_proto_expert_info(ei.noise, (j - i + 1) .. " bytes outside any frame")
end

-- Express lane (speed trick, measured: the summary pass 10 us a frame faster, a compressed
-- stream's 20): in any pass (no tree, one nobody sees, a shown one), a packet that is one plain
-- named frame of a layout its node pair sent before, with a good checksum and N0, whose
-- variables the direction knows already -- the bulk of a beacon stream, full or compressed -- is
-- decoded here in one go.  It leaves the same state, records, Info and tree as the phases of
-- dissect_frame (parse_fast_named; data_values' known-set case, or its general case with
-- carried variables; data_record; info_frame's one concatenation; tree_compact_frame or
-- tree_full); anything else returns false before changing any state, and the phases take the
-- packet.  SHAREDLINK_NO_EXPRESS=1 turns it off; the tests compare both ways.
local EXPRESS = not wsapi.env.no_express
local NO_SHAPES = {}
local XSK = {}            -- frame key -> "|sk|d|0" (a line's text after its frame number)
local CARRIED_TAIL = {}   -- n -> " (+n carried)"
for k = 1, 64 do CARRIED_TAIL[k] = " (+" .. k .. " carried)" end

-- The direction's known variables a layout leaves out (nil: it names one the direction does not
-- know yet, or leaves none out), kept per layout until the direction learns another variable.
local function express_missing(d, sh)
    local npos, names, sn = d.npos, d.names, sh.N
    local in_layout = {}
    for k = 1, sh.n do
        if not npos[sn[k]] then return nil end
        in_layout[sn[k]] = true
    end
    local miss = {}
    for k = 1, #names do
        if not in_layout[names[k]] then
            -- a line break in a name: no record line (the phases make a table record)
            if s_find(names[k], "\n", 1, true) then return nil end
            miss[#miss + 1] = names[k]
        end
    end
    if #miss == 0 or not CARRIED_TAIL[#miss] then return nil end
    local xm = { count = #names, names = miss, tail = CARRIED_TAIL[#miss] }
    local cache = d.xmiss
    if not cache then cache = {}; d.xmiss = cache end
    cache[sh] = xm
    return xm
end

-- With no tree, whether the express lane's frame is one whose tree has no expert info: its line
-- ends in CR LF, its checksum is two upper-case hex digits, every value matches its type.  A
-- frame that has one goes to the phases (dissect_frame reports it).
local express_plain
do
    local UHEX = {}
    for t in pairs(HEXV) do
        if not s_find(t, "[a-f]") then UHEX[t] = true end
    end
    -- a double's value matched XDOUBLE already (see learn_named_shape)
    local function value_ok(vtype, v)
        if vtype == 0 then return v == nil or parse_long(v) ~= nil end
        return true
    end
    function express_plain(s, n, sh, ctext, c1, c2, c3, c4, c5, c6, c7, c8)
        if not UHEX[ctext] or s_byte(s, n) ~= B_LF or s_byte(s, n - 1) ~= B_CR or s_byte(s, n - 2) ~= B_RBRACK then
            return false
        end
        local tv = sh.TV
        if not tv then return true end
        return value_ok(tv[1], c1) and value_ok(tv[2], c2) and value_ok(tv[3], c3) and value_ok(tv[4], c4)
            and value_ok(tv[5], c5) and value_ok(tv[6], c6) and value_ok(tv[7], c7) and value_ok(tv[8], c8)
    end
end

local function express(s, n, tvb, pinfo, tree, cols, vis)
    local dstb, srcb = s_byte(s, 3, 4)
    local key = (dstb or 0) * 256 + (srcb or 0)
    -- the layout that matched a payload of this length last (a payload matches one layout at
    -- most), else the node pair's recent layouts, newest first.  Speed trick (measured): a
    -- compressed stream interleaves layouts of one prefix, and a pattern that fails late costs
    -- most of a match
    local lk = key * 65536 + n
    local sh, c1, c2, c3, c4, c5, c6, c7, c8, c9 = xlen[lk]
    -- xhead: the layout's text up to its first value, found as plain text (speed trick,
    -- measured: a pattern matches text one character at a time); xpat: the rest, from there
    if sh and s_find(s, sh.xhead, 1, true) == 1 then
        c1, c2, c3, c4, c5, c6, c7, c8, c9 = s_match(s, sh.xpat, #sh.xhead + 1)
    end
    if not c1 then
        local mru = shapes[key] or NO_SHAPES
        for k = 1, #mru do
            sh = mru[k]
            if s_find(s, sh.xhead, 1, true) == 1 then
                c1, c2, c3, c4, c5, c6, c7, c8, c9 = s_match(s, sh.xpat, #sh.xhead + 1)
            end
            if c1 then
                if k > 1 then table.remove(mru, k); table.insert(mru, 1, sh) end
                break
            end
        end
        if not c1 then
            sh = bshapes[key]
            if not sh then return false end
            if s_find(s, sh.xhead, 1, true) == 1 then c1 = s_match(s, sh.xpat, #sh.xhead + 1) end
            if not c1 then return false end
        end
        if xlen_n >= 4096 then xlen, xlen_n = {}, 0 end
        if n < 65536 then xlen[lk], xlen_n = sh, xlen_n + 1 end
    end
    if sh.ord ~= 0 then return false end
    local total, sum, ctext = sh.sums(c1, c2, c3, c4, c5, c6, c7, c8, c9)
    if not total or total + sh.info_len > INFO_MAX then return false end
    if pref_validate and HEXV[ctext] ~= (sh.fixed + sum) % 256 then return false end
    if not tree and not express_plain(s, n, sh, ctext, c1, c2, c3, c4, c5, c6, c7, c8) then return false end
    local pg = PG
    local num = pg.number(pinfo)
    local visited = pg.visited(pinfo)
    local sk = n * 1048576 + 1   -- the frame's key in its packet, as dissect makes it (sk_base + 1)
    local tail = nil    -- a delta's " (+n carried)"
    local d, list, rec, nm = nil, pref_list, nil, 0   -- for the tree: see state_first_pass
    if visited then
        -- a later pass: no record means the first pass found it full; a carried-only record, a delta
        rec = get_rec(num, sk, false)
        if not rec and sh.bare then return false end   -- a bare frame with no record: the phases say why
        if LIM.journal then
            -- a frame the journal judged: the phases
            d = get_dir(pinfo, num, dstb, srcb)
            if d.jkey and journal.key(num, sk) >= d.jkey then return false end
        end
        if rec then
            if rec.late or rec[1] or rec.kind ~= "d" or not rec.miss then return false end
            tail = CARRIED_TAIL[floor(#rec.miss / 3)]
            if not tail or total + sh.dinfo_len + #tail > INFO_MAX then return false end
        end
        if tree then
            -- as state_later_pass: the list in use here on the first pass
            d = get_dir(pinfo, num, dstb, srcb)
            list = list_at(d, num, sk)
        end
    else
        d = get_dir(pinfo, num, dstb, srcb)
        if d.hist or d.over or #d.names >= JOURNAL_NAMES then return false end   -- a journal, a limit: the phases
        list = d.list or pair_lists[sh.letters] or pref_list
        if list ~= (d.used_list or pref_list) then return false end
        local names, vals, from = sh.N, d.vals, d.from
        local now = pg.rel_ts(pinfo)
        local first = d.first
        if not first then first = now; d.first = now end
        if d.names_is == names then
            d.lastfull = now
        else
            -- a delta: the direction's other variables are carried forward
            local xm = d.xmiss and d.xmiss[sh]
            if not xm or xm.count ~= #d.names then
                xm = express_missing(d, sh)
                if not xm then return false end
            end
            tail = xm.tail
            local miss_names = xm.names
            -- no full frame for too long: the phases record the late sync
            if now - (d.lastfull or first) > pref_sync then return false end
            if total + sh.dinfo_len + #tail > INFO_MAX then return false end
            -- the record line carried_store would write (num|sk|d|0|name|=value|frame|...), as
            -- pieces: no string is made for it until its chunk, and each carried variable's
            -- "|name|=value|frame" is kept in the direction (ctext) while its value and frame
            -- stay the same.  A value with a line break cannot go in a line (the phases make a
            -- table record).
            local ct, cfrom, cval = d.ctext, d.cfrom, d.cval
            if not ct then ct, cfrom, cval = {}, {}, {}; d.ctext, d.cfrom, d.cval = ct, cfrom, cval end
            local xsk = XSK[sk]
            if not xsk then xsk = "|" .. sk_text(sk) .. "|d|0"; XSK[sk] = xsk end
            local pend, i = cr_pend, cr_npieces
            pend[i + 1], pend[i + 2] = num, xsk
            i = i + 2
            for k = 1, #miss_names do
                local name = miss_names[k]
                local f, v = from[name] or false, vals[name] or false
                local t = ct[name]
                if cfrom[name] ~= f or cval[name] ~= v or not t then
                    if v and s_find(v, "\n", 1, true) then return false end
                    t = "|" .. name .. (v and ("|=" .. v) or "|") .. "|" .. from_text(f)
                    ct[name], cfrom[name], cval[name] = t, f, v
                end
                pend[i + k] = t
                -- MISS, as data_values gathers it, for the tree (carried variables)
                if tree then MISS[nm + 1], MISS[nm + 2], MISS[nm + 3] = name, v, f; nm = nm + 3 end
            end
            i = i + #miss_names + 1
            pend[i] = "\n"
            carried_line_end(num, i)
        end
        sh.xstore(vals, from, num, c1, c2, c3, c4, c5, c6, c7, c8)
    end
    local info
    if tail then
        info = sh.xdinfo(c1, c2, c3, c4, c5, c6, c7, c8) .. tail
    else
        info = sh.xinfo(c1, c2, c3, c4, c5, c6, c7, c8)
    end
    if MARKS.express then info = MARKS.express .. info end
    cols.info = info
    if tree then
        -- the tree dissect_frame makes, from what parse_fast_named would have left: the compact
        -- one for a tree nobody sees (-Y, coloring rules, taps), else the full one
        VV[1], VV[2], VV[3], VV[4], VV[5], VV[6], VV[7], VV[8] = c1, c2, c3, c4, c5, c6, c7, c8
        local st, sn = sh.T, sh.N
        local nvals = sh.n
        for k = 1, nvals do VT[k], VN[k], VI[k], VR[k] = st[k], sn[k], k - 1, false end
        nv, pr_ctext, pr_n_ord, pr_fast_sh = nvals, ctext, 0, sh
        local fl = n   -- the index of its ']': the pattern lets CR LF, CR or LF follow
        while s_byte(s, fl) ~= B_RBRACK do fl = fl - 1 end
        local cs_val, cs_calc, cs_status = checksum_value(ctext), nil, 2
        if pref_validate then cs_calc, cs_status = (sh.fixed + sum) % 256, 1 end
        local kind = tail and "delta" or "full"
        if not vis then
            tree_compact_frame(TI.add(tree, sl, tvb(0, n)), 1, n, fl, s, dstb, srcb, kind, list, d, num, visited,
                rec, 0, nm, cs_val, cs_calc, cs_status)
            return true
        end
        -- a shown tree (-V, the GUI's details; speed trick, measured: -V 5 %, a compressed
        -- stream's 8 %): the fields' places, then as dissect_frame (its frame is s[1..fl])
        pr_cpos = fl - 1 - #ctext
        fast_positions(sh.ntext, nvals, true)
        tree_full(tree, tvb, s, s, 1, n, fl, true, fl - 1, nil, num, kind, dstb, srcb, list, d, rec, 0, nm,
            cs_val, cs_calc, cs_status)
    end
    return true
end

local function dissect(tvb, pinfo, tree)
    if not wsapi.ready then wsapi.init(pinfo, tree, tvb) end
    local s = wsapi.tvb_raw(tvb)
    local n = #s
    if n <= 0 then return 0 end
    local cols = PG.cols(pinfo)

    cols.protocol = "SharedLink"

    -- With no tree at all (tshark's summary pass) skip all tree work (wsapi.no_tree); frames with
    -- expert infos still get them (see dissect_frame)
    local t = tree
    if t ~= nil and wsapi.no_tree(t) then t = nil end
    -- the express lane (the tree's visibility is the whole tree's)
    if EXPRESS and express(s, n, tvb, pinfo, t, cols, t ~= nil and PG.visible(t)) then return n end
    -- the phases: the frames' keys, and the Info they build
    local sk_base = n * 1048576
    ninfo, info_len, info_full, frames_in_info, frames_dropped = 0, 0, false, 0, 0
    info_clean = true
    local pos = 1
    local open_at, close_at = 0, 0 -- cached search results (false = none left)
    while pos <= n do
        if open_at ~= false and open_at < pos then open_at = s_find(s, "[:", pos, true) or false end
        local a = open_at
        if not a then
            if s_byte(s, n) == B_LBRACK and pinfo.can_desegment > 0 then
                -- a frame may start with this '[' in the next segment
                if n > pos then add_noise(s, pos, n - 1, tvb, t, tree) end
                pinfo.desegment_offset = n - 1
                pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
            else
                add_noise(s, pos, n, tvb, t, tree)
            end
            break
        end
        if a > pos then add_noise(s, pos, a - 1, tvb, t, tree) end
        if close_at ~= false and close_at < a + 2 then close_at = s_find(s, "]", a + 2, true) or false end
        local b = close_at
        open_at = s_find(s, "[:", a + 2, true) or false
        local na = open_at
        local sk = sk_base + a
        if b and (not na or b < na) then
            local e = b
            local c1, c2 = s_byte(s, b + 1, b + 2)
            if c1 == B_CR then
                if c2 == B_LF then e = b + 2 else e = b + 1 end
            elseif c1 == B_LF then
                e = b + 1
            end
            if a == 1 then
                dissect_frame(s, b, a, e, true, tvb, pinfo, t, sk, s, tree)
            else
                dissect_frame(s_sub(s, a, b), b - a + 1, a, e, true, tvb, pinfo, t, sk, s, tree)
            end
            pos = e + 1
        elseif na then
            dissect_frame(s_sub(s, a, na - 1), na - a, a, na - 1, false, tvb, pinfo, t, sk, s, tree)
            pos = na
        else
            if pinfo.can_desegment > 0 then
                if (n - a) < LIM.max_held_bytes then
                    pinfo.desegment_offset = a - 1
                    pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
                    break
                end
                TI.add_proto_expert_info(tree, ei.limit, "Limit exceeded: an unterminated frame of over " ..
                    LIM.max_held_bytes .. " bytes (max_held_bytes), decoded as it is")
            end
            dissect_frame(s_sub(s, a, n), n - a + 1, a, n, false, tvb, pinfo, t, sk, s, tree)
            pos = n + 1
        end
    end

    if frames_dropped > 0 then
        ninfo = ninfo + 1
        INFO[ninfo] = " (+" .. frames_dropped .. " more)"
    end
    if ninfo > 0 then
        local info = (ninfo == 1) and INFO[1] or t_concat(INFO, "", 1, ninfo)
        if MARKS.fast_hit then info = "[fast] " .. info; MARKS.fast_hit = false end
        -- control characters from a damaged frame must not break the column (the
        -- fast path's text cannot hold any: its patterns exclude them)
        if not info_clean and s_find(info, CTRL) then info = s_gsub(info, CTRL, "?") end
        cols.info = info
    end
    return n
end

sl.dissector = dissect

------------------------------------------------------------------------------
-- Heuristics
------------------------------------------------------------------------------
do
local function looks_like_sharedlink(tvb, is_tcp)
    local n = tvb:len()
    if n < 5 then return false end
    local head = tvb:raw(0, n < 8 and n or 8)
    local o = 1
    -- allow leading CR/LF
    while o <= #head and (s_byte(head, o) == B_CR or s_byte(head, o) == B_LF) do o = o + 1 end
    if o > 3 then return false end
    local b1, b2, b3, b4, b5 = s_byte(head, o, o + 4)
    if b1 ~= B_LBRACK or b2 ~= B_COLON then return false end
    if not b3 or b3 < B_A or b3 > B_P or not b4 or b4 < B_A or b4 > B_P then return false end
    if b5 ~= B_PIPE and b5 ~= B_RBRACK then return false end
    local s = tvb:raw(0, n)
    local close = s_find(s, "]", o + 4, true)
    -- CR, LF and TAB may occur inside a value (a status text); other control bytes refuse
    local bad = s_find(s, "[^\9\10\13\32-\126]", o)
    if close then
        if bad and bad < close then return false end
        local c = s_byte(s, close + 1)
        if not (c == nil or c == B_LBRACK or c == B_LF or (c == B_CR and
            (s_byte(s, close + 2) == B_LF or close + 1 == n))) then
            return false
        end
        return true
    end
    -- no ']' yet: only TCP may wait for the rest of the frame
    if is_tcp and not bad and n >= 8 then return true end
    return false
end

local function make_heuristic(is_tcp)
    return function(tvb, pinfo, tree)
        if not pref_heuristic then return false end
        if not looks_like_sharedlink(tvb, is_tcp) then return false end
        pinfo.conversation = sl
        dissect(tvb, pinfo, tree)
        return true
    end
end

sl:register_heuristic("udp", make_heuristic(false))
sl:register_heuristic("tcp", make_heuristic(true))
end

------------------------------------------------------------------------------
-- Ports
------------------------------------------------------------------------------
local apply_ports
do
local udp_table = DissectorTable.get("udp.port")
local tcp_table = DissectorTable.get("tcp.port")
local current_ports = ""

function apply_ports()
    local ports = sl.prefs.ports
    if type(ports) ~= "string" then ports = tostring(ports or "") end
    if ports == current_ports then return end
    if current_ports ~= "" then
        udp_table:remove(current_ports, sl)
        tcp_table:remove(current_ports, sl)
    end
    if ports ~= "" then
        udp_table:add(ports, sl)
        tcp_table:add(ports, sl)
    end
    current_ports = ports
end
end

function sl.prefs_changed()
    apply_ports()
    pref_list = parse_list(sl.prefs.variables)
    pref_validate = sl.prefs.validate_checksum
    pref_heuristic = sl.prefs.heuristic
    pref_sync = (tonumber(sl.prefs.sync_interval) or 1000) / 1000 + SYNC_SLACK
    read_limits()
end

apply_ports()
pref_list = parse_list(DEFAULT_VARS)
read_limits()
