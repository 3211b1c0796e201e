-- SharedLink protocol dissector for Wireshark (Lua).
--
-- SharedLink (Kairos Autonomi BUL-009 / BUL-049) is a line protocol:
--   [:<dst><src>|<field>|<field>|...|C<xx>]<CR><LF>
-- dst/src are letters A..P (nodes 1..16).  Every field starts with a type letter
-- (N ordinal, T type, Q name/query, R reply, D data, C checksum, L inbound
-- declaration, E command, M mode, P ping, G pong).  The checksum is the sum of the
-- bytes from ':' through the 'C' of the checksum field, modulo 256, in hex.
--
-- Install: copy this file and its module folder sharedlink/ into your personal Lua plugins folder
-- (Help > About Wireshark > Folders > Personal Lua Plugins; make install does), or run
--   tshark -X lua_script:/path/to/sharedlink.lua ...
-- This file is the entry (Proto, registration, the dissect loop, heuristics); the modules beside it
-- in sharedlink/ hold the rest by role (docs/architecture.md has the map).
--
-- Works with Wireshark 4.0 (Lua 5.2) and later (Lua 5.4).
--
-- Preferences (tshark -o name:value):
--   sharedlink.ports              UDP/TCP port range always decoded (default 7013)
--   sharedlink.heuristic          try the heuristic on other ports (default TRUE)
--   sharedlink.validate_checksum  compute and check the checksum (default TRUE)
--   sharedlink.variables          a-priori list naming positional values, NAME or NAME:TYPE
--                                 (0 long, 2 double, 4 string; default AutoGpsLat:2,AutoGpsLon:2,
--                                 AutoGpsHead:2,AutoGpsVel:2), and per-pair lists SRC>DST: ...
--   sharedlink.sync_interval_ms   expected full-frame interval in ms (default 1000; the old name
--                                 sharedlink.sync_interval still works, deprecated)
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
-- between frames), sharedlink.checksum.text (a checksum that is not a hex byte, or not written
-- as two upper-case hex digits), sharedlink.sync.is_late (generated boolean: the sync.late
-- condition, for taps/filters), sharedlink.sync.gap (a late frame's time since the last full one).
-- Each expert's summary names its problem, never a value (the values are in those fields:
-- tshark -z expert lists one row per problem).
-- Expert infos beyond the core set: sharedlink.checksum.missing (warning),
-- sharedlink.var.badvalue (warning: value/type/ordinal not matching its type),
-- sharedlink.crlf.missing (note), sharedlink.noise.skipped (note),
-- sharedlink.reply.unmatched (note: a reply with no query seen before it).
--
-- Query/reply links: a reply links back to its query in any pass; the query's
-- "Response in" needs the reply to have been seen, i.e. a second pass (GUI, tshark -2).
--
-- Performance: every frame goes one route (docs/architecture.md): parse, checksum, state, Info,
-- tree.  In front of the parser, a layout cache: a frame with the layout of one of the node
-- pair's recent plain frames (up to 8: a compressed stream's deltas) is matched by one anchored
-- pattern, its checksum the layout's fixed sum plus the values' sum, in a shown tree too (the
-- fields' places follow from the layout and the values' lengths).  With no tree (tshark summary
-- pass) no tree items are built, unless the frame has expert infos; with a tree nobody sees
-- (-Y, coloring rules, taps) a frame gets its fields' values without byte ranges, labels or
-- flags, and a field no filter references is left out (tree.lua: one builder for every tree);
-- the shown tree's labels are made once; every use of Wireshark's internals is in wsapi,
-- checked against the documented API.  Per-frame state is stored only for frames that need it
-- (carried values, late sync, queries/replies); carried-only records are packed as text lines,
-- 256 a chunk in one ByteArray, and the list in use is kept as a per-direction history of
-- changes, so that long compressed captures add few Lua objects (Wireshark runs full Lua
-- garbage collections during a capture).
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

------------------------------------------------------------------------------
-- Modules: dissector/sharedlink/<name>.lua beside this file, run once each, in this order, with a
-- token that tells them apart from Wireshark's own loading of plugin subfolders (see each
-- module's head) and M, the modules loaded before (M.proto: the Proto).  Works the same from a
-- checkout (tshark -X lua_script:dissector/sharedlink.lua) and from the personal plugin folder
-- (make install copies this file and the folder), 4.0 to 4.6.
------------------------------------------------------------------------------
local M = { proto = sl }
local load_tree   -- run tree.lua: the tree builder (below)
do
    local here = (debug.getinfo(1, "S").source or ""):match("^@(.*[/\\])") or ""
    local TOKEN = { sharedlink_module = true }
    local function compile(name) return assert(loadfile(here .. "sharedlink/" .. name .. ".lua")) end
    local function run(name)
        M[name] = compile(name)(TOKEN, M)
        return M[name]
    end
    for _, name in ipairs({ "util", "wsapi", "fields", "prefs", "records", "parse", "state", "info", "experts",
        "health" }) do
        run(name)
    end
    -- The tree builder runs the first time a frame's tree is built: a pass that builds none (tshark's
    -- summary pass of frames with no expert info) keeps its code out of the live Lua heap, which the
    -- collector's work grows with (docs/perf-log.md, 7 December).  Compiled here and dropped, so a
    -- missing or broken tree.lua still says so when Wireshark starts.
    compile("tree")
    function load_tree() return run("tree") end
end
local U, cfg, wsapi, hf = M.util, M.prefs, M.wsapi, M.fields.hf
local ei, s_byte, s_sub, s_find = M.fields.ei, string.byte, string.sub, string.find
local tostring, type, B_LBRACK, B_RBRACK = tostring, type, U.B_LBRACK, U.B_RBRACK
local B_PIPE, B_COLON, B_CR, B_LF = U.B_PIPE, U.B_COLON, U.B_CR, U.B_LF
local B_A, B_P = U.B_A, U.B_P
local Pm, S, I, X, R = M.parse, M.state, M.info, M.experts, M.records
local health_frame, health_marked, health_mark = M.health.frame, M.health.marked, M.health.mark
local F = Pm.F   -- the frame record (parse.lua): what is known of the frame being dissected
local PG, TI = M.wsapi.PG, M.wsapi.TI
local parse_frame, kind_of_fields, bylen = Pm.parse_frame, Pm.kind_of_fields, Pm.bylen
local checksum_facts = Pm.checksum_facts
local state_data, state_other, state_later_pass = S.state_data, S.state_other, S.state_later_pass
local info_frame, info_layout, info_finish, first_piece = I.info_frame, I.info_layout, I.finish, I.first_piece
local has_experts, T_SHOWN, T_HIDDEN, T_NONE = X.has_experts, X.SHOWN, X.HIDDEN, X.NONE
local set_crlf_frames = X.set_crlf_frames
-- the tree builder (tree.lua), run on the first call (load_tree)
local tree_frame
tree_frame = function(mode, tree, tvb, fr)
    tree_frame = load_tree().tree_frame
    return tree_frame(mode, tree, tvb, fr)
end

sl.fields = M.fields.register(hf)
sl.experts = M.fields.register(ei)

-- per-capture state, and the preferences in use
function sl.init()
    I.begin()
    R.reset()
    S.reset()
    Pm.reset()
    cfg.reset()
    cfg.read()
    M.health.reset()
end

-- A frame the parser took (not a layout's): into the frame record, the kind its fields tell
-- (F.fkind; nil: a data frame, full or delta as the state tells), whether it is a data frame
-- (F.is_data), whether both address bytes are nodes A-P (F.addrs_ok; false when cut short), the
-- address bytes (F.dstb, F.srcb: nil when cut short).
-- Returns whether it is full without state (a data frame with N0 or none, no empty positional D
-- and no named variable left out; the state-based verdict is stored when it differs), and the
-- first pass's state writer for it: state_data (a data frame between nodes), else state_other.
local function fields_facts(malformed_msg, dstb, srcb)
    local kind, is_data = kind_of_fields(malformed_msg)
    local nodes = (dstb and srcb and dstb >= B_A and dstb <= B_P and srcb >= B_A and srcb <= B_P) or false
    F.fkind, F.is_data, F.addrs_ok, F.dstb, F.srcb = kind, is_data, nodes, dstb, srcb
    local n_ord = F.n_ord
    local full_local = F.nd > 0 and (n_ord == nil or n_ord == 0) and F.n_empty_d == 0
    return full_local, (is_data and nodes) and state_data or state_other
end

-- The index of the last byte of a frame closed at b, its line end included (CR LF, CR or LF).
local function line_end(s, b)
    local c1, c2 = s_byte(s, b + 1, b + 2)
    if c1 == B_CR then return c2 == B_LF and b + 2 or b + 1 end
    if c1 == B_LF then return b + 1 end
    return b
end

-- A terminated frame with no CR LF after it tells the tree module whether CR LF frames the
-- packet's bytes (not on UDP: wsapi.is_udp).
local function tell_crlf(pinfo, terminated)
    if terminated then set_crlf_frames(not wsapi.is_udp(pinfo)) end
end

-- The packet being dissected (set by dissect, read by dissect_frame; upvalues, not arguments:
-- the same for every frame of the packet): its Tvb, Pinfo, the tree to build in (nil: none, see
-- dissect), the tree Wireshark gave (for the expert infos of a frame with no tree), its payload.
local pk_tvb, pk_pinfo, pk_tree, pk_root, pk_s

-- wslua attributes the entry reads each frame, through wsapi's getters (PG), as upvalues once
-- wsapi.init has chosen them on the first packet (set by dissect)
local pg_number, pg_visited, pg_visible
local MODE = { [true] = T_SHOWN, [false] = T_HIDDEN }   -- a tree's mode by whether it is shown

-- The rest of a frame once its state is known (the frame record filled: dissect_frame): the Info
-- (info.lua) unless in_info (the layout's piece is in it), the tree (tree.lua).  vis: the tree is
-- shown; calm: a frame with no possible expert (F.calm).  Returns e, piece (dissect_frame's).
local function frame_output(piece, in_info, calm, vis)
    if not in_info then info_frame(F) end
    -- Tree: shown, hidden (nobody sees it) or none (tshark's summary pass: built only for a frame
    -- with expert infos, on root, where only the experts stay); one builder (tree.lua)
    local tree, mode = pk_tree, T_NONE
    if tree then
        mode = MODE[vis]
    else
        if not pk_root then return F.e, piece end
        -- a layout's frame with no possible expert (speed trick, measured: F.calm, see
        -- dissect_frame); otherwise has_experts tells
        if calm then return F.e, piece end
        if not has_experts(F) then return F.e, piece end
        tree = pk_root
    end
    tree_frame(mode, tree, pk_tvb, F)
    return F.e, piece
end

-- f: a string holding the frame at f[1..fl] ('[' .. ']' when terminated, else up to
-- where it stops; bytes after fl may follow when terminated); a: index of f[1] in the
-- payload (pk_s); e: index in it of the last byte including the line end; sk: the frame's key.
-- payload: f is the payload, fl its length, and the frame it starts with is taken only when the
-- layout cache has it (parse_frame); then fl and e are found here, and nil returned when it does
-- not.  Returns e, and the Info piece of a payload's first frame (first_piece).
local function dissect_frame(f, fl, a, e, terminated, sk, payload)
    local pinfo, tree = pk_pinfo, pk_tree
    -- a tree that is shown (-V, -T fields/json, the GUI's details) gets every range and
    -- label; one nobody sees (-Y, coloring rules, taps) takes the fast paths too.  The
    -- protocol item is added once the frame is known (the full tree: with its text)
    local vis = tree and pg_visible(tree)   -- (nil: no tree)

    -- the take function of the layout that matched a frame of this length last (bylen), else
    -- parse_frame (speed trick, measured: the layout's called here, not through parse_frame)
    local bodyend, dstb, srcb, malformed_msg, cs_status, quiet, full_local, le =
        (terminated and bylen[fl] or parse_frame)(f, fl, terminated, vis, payload)
    if payload then
        if not bodyend then return nil end
        fl = bodyend + 1
        e = fl + #le   -- (the layout's pattern took the line end: as line_end's)
    end
    local num = pg_number(pinfo)
    -- a layout's frame: a data frame between nodes A-P (fill_layout's F.fkind, is_data,
    -- addrs_ok); full_local from the layout (nil from the parser); any other frame's facts from
    -- fields_facts, with the state writer's function for it on the first pass (a later pass:
    -- state_later_pass).  One argument list for the three: the answers go straight into the
    -- locals (speed trick, measured)
    local state = state_data
    if full_local == nil then full_local, state = fields_facts(malformed_msg, dstb, srcb) end
    local visited = pg_visited(pinfo)
    if visited then state = state_later_pass end
    local kind, rec, list, d, miss_n, ne, nm, t = state(pinfo, num, sk, cs_status, dstb, srcb, full_local, tree)
    -- link health (health.lua): the link moves on (first pass: t, the packet's time if the state
    -- read it); the outage this frame ends, if any, marked on every pass
    local gone
    if visited then
        gone = health_marked(num, sk)
    else
        gone = health_frame(pinfo, num, sk, d, t, cs_status, rec, kind)
    end
    if gone then health_mark(tree, pk_root, gone) end

    -- Info: the piece of the payload's first frame from its layout (I.first_piece), which the
    -- packet's Info is when no other frame follows (dissect writes it: speed trick, measured);
    -- else a named layout's (info_layout), else info.lua's pieces (frame_output)
    local piece = payload and first_piece(kind, rec, miss_n)
    local in_info = piece or info_layout(kind, rec, miss_n)

    -- CR LF after its ']' (line_end, or the layout's pattern)?  Whether CR LF frames the packet's
    -- bytes (sharedlink.crlf.missing is noted only then) is told the tree module before each
    -- frame that lacks one.  Speed trick (measured): pinfo.port_type is a call into wslua's
    -- __index, read only then
    local crlf = e == a + fl + 1
    if not crlf then tell_crlf(pinfo, terminated) end
    -- calm: a layout's frame with no possible expert (speed trick, measured): quiet (values its
    -- layout proves, a good upper-case checksum), CR LF after it, no record (late sync, limit).
    -- The commonest frame, done: its Info made, no tree, no possible expert
    local calm = quiet and crlf and not rec
    if in_info and not tree and (not pk_root or calm) then return e, piece end
    F.kind, F.rec, F.list, F.d, F.miss_n, F.ne, F.nm, F.calm = kind, rec, list, d, miss_n, ne, nm, calm
    F.f, F.fl, F.a, F.e, F.terminated, F.crlf, F.s = f, fl, a, e, terminated, crlf, pk_s
    F.bodyend, F.malformed, F.cs_status, F.num, F.visited = bodyend, malformed_msg, cs_status, num, visited
    checksum_facts()
    return frame_output(piece, in_info, calm, vis)
end
------------------------------------------------------------------------------
-- Payload scanning
------------------------------------------------------------------------------
-- Noise s[i..j] between frames (CR/LF alone is not noise).
local function add_noise(s, i, j, tvb, tree, root)
    local k = s_find(s, "[^\r\n]", i)
    if not k or k > j then return end
    I.noise(j - i + 1)
    if not tree then
        -- no tree: the expert alone, on the tree Wireshark gave
        if root then TI.add_proto_expert_info(root, ei.noise) end   -- (the bytes: sharedlink.noise)
        return
    end
    local r = tvb(i - 1, j - i + 1)
    local ti = tree:add(sl, r)
    ti:append_text(", noise")
    ti:add(hf.noise, r):add_proto_expert_info(ei.noise)
end

-- A frame at s[a..] that no ']' closes: held for the next TCP segment while within
-- max_held_bytes (returns nil), else decoded as it is (returns the next position).
local function unclosed_frame(s, n, a, pinfo, sk, tree)
    if pinfo.can_desegment > 0 then
        if (n - a) < cfg.LIM.max_held_bytes then
            pinfo.desegment_offset = a - 1
            pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
            return nil
        end
        TI.add_proto_expert_info(tree, ei.limit, "Limit exceeded: an unterminated frame of over " ..
            cfg.LIM.max_held_bytes .. " bytes (max_held_bytes), decoded as it is")
    end
    dissect_frame(s_sub(s, a, n), n - a + 1, a, n, false, sk)
    return n + 1
end

-- The payload's tail from pos on holds no "[:": noise, or a '[' a frame may start with in the
-- next TCP segment.
local function tail_noise(s, n, pos, tvb, pinfo, t, tree)
    if s_byte(s, n) == B_LBRACK and pinfo.can_desegment > 0 then
        if n > pos then add_noise(s, pos, n - 1, tvb, t, tree) end
        pinfo.desegment_offset = n - 1
        pinfo.desegment_len = DESEGMENT_ONE_MORE_SEGMENT
    else
        add_noise(s, pos, n, tvb, t, tree)
    end
end

-- The frames of the payload s (n bytes) from pos on, each through dissect_frame; the next "[:"
-- and "]" are searched once each (open_at, close_at: false = none left).
local function scan(s, n, tvb, pinfo, t, tree, pos)
    local sk_base = n * 1048576   -- a frame's key: the payload's length and the frame's start
    local open_at, close_at = 0, 0
    while pos and pos <= n do
        if open_at ~= false and open_at < pos then open_at = s_find(s, "[:", pos, true) or false end
        local a = open_at
        if not a then tail_noise(s, n, pos, tvb, pinfo, t, tree); return end
        if a > pos then add_noise(s, pos, a - 1, tvb, t, tree) end
        if close_at ~= false and close_at < a + 2 then close_at = s_find(s, "]", a + 2, true) or false end
        local b = close_at
        open_at = s_find(s, "[:", a + 2, true) or false
        local na = open_at
        if b and (not na or b < na) then
            local e = line_end(s, b)
            -- a payload that starts with the frame is the frame's text itself (no copy)
            local f = a == 1 and s or s_sub(s, a, b)
            dissect_frame(f, b - a + 1, a, e, true, sk_base + a)
            pos = e + 1
        elseif na then
            dissect_frame(s_sub(s, a, na - 1), na - a, a, na - 1, false, sk_base + a)
            pos = na
        else
            pos = unclosed_frame(s, n, a, pinfo, sk_base + a, tree)
        end
    end
end

-- wsapi's functions the entry calls each packet, as upvalues once wsapi.init has chosen them on
-- the first packet (a table's field is a hash lookup: speed trick, measured)
local tvb_raw, has_tree, pg_cols
local in_packet = false   -- between a packet's first frame and its Info (I.finish)

local function dissect(tvb, pinfo, tree)
    if not tvb_raw then
        wsapi.init(pinfo, tree, tvb)
        tvb_raw, has_tree, pg_cols = wsapi.tvb_raw, wsapi.has_tree, PG.cols
        pg_number, pg_visited, pg_visible = PG.number, PG.visited, PG.visible
        S.take_getters()
    end
    local s = tvb_raw(tvb)
    local n = #s
    if n <= 0 then return 0 end
    local cols = pg_cols(pinfo)
    cols.protocol = "SharedLink"
    -- With no tree at all (tshark's summary pass) skip all tree work (wsapi.has_tree); frames with
    -- expert infos still get them (see dissect_frame)
    local t = tree
    if t ~= nil and not has_tree(t) then t = nil end
    -- the Info starts empty (I.finish leaves it so) unless the last packet stopped short of it
    if in_packet then I.begin() end
    in_packet = true
    -- the layout cache first, for the frame the payload starts with (dissect_frame's payload); its
    -- Info piece (piece: from its layout's Info code) is the packet's Info when it is the only frame
    pk_tvb, pk_pinfo, pk_tree, pk_root, pk_s = tvb, pinfo, t, tree, s
    local e, piece = dissect_frame(s, n, 1, nil, true, n * 1048576 + 1, true)
    if piece then
        if e == n then
            cols.info = piece
            in_packet = false
            return n
        end
        I.first(piece)
    end
    if not e then
        scan(s, n, tvb, pinfo, t, tree, 1)
    elseif e < n then
        scan(s, n, tvb, pinfo, t, tree, e + 1)
    end
    info_finish(cols)
    in_packet = false
    return n
end

sl.dissector = dissect

------------------------------------------------------------------------------
-- Heuristics
------------------------------------------------------------------------------
do
-- The head: up to two CR/LF, then "[:", two letters A-P and "|" or "]".  Returns where "[:" is.
local function heuristic_head(head)
    local o = 1
    -- allow leading CR/LF
    while o <= #head and (s_byte(head, o) == B_CR or s_byte(head, o) == B_LF) do o = o + 1 end
    if o > 3 then return nil end
    local b1, b2, b3, b4, b5 = s_byte(head, o, o + 4)
    if b1 ~= B_LBRACK or b2 ~= B_COLON then return nil end
    if not b3 or b3 < B_A or b3 > B_P or not b4 or b4 < B_A or b4 > B_P then return nil end
    if b5 ~= B_PIPE and b5 ~= B_RBRACK then return nil end
    return o
end

-- What may follow a frame's "]" at close: the end, "[", LF, or CR LF (CR alone at the end).
local function heuristic_close(s, n, close)
    local c = s_byte(s, close + 1)
    return c == nil or c == B_LBRACK or c == B_LF or (c == B_CR and (s_byte(s, close + 2) == B_LF or close + 1 == n))
end

local function looks_like_sharedlink(tvb, is_tcp)
    local n = tvb:len()
    if n < 5 then return false end
    local o = heuristic_head(tvb:raw(0, n < 8 and n or 8))
    if not o then return false end
    local s = tvb:raw(0, n)
    local close = s_find(s, "]", o + 4, true)
    -- CR, LF and TAB may occur inside a value (a status text); other control bytes refuse
    local bad = s_find(s, "[^\9\10\13\32-\126]", o)
    if close then return not (bad and bad < close) and heuristic_close(s, n, close) end
    -- no ']' yet: only TCP may wait for the rest of the frame
    return is_tcp and not bad and n >= 8
end

local function make_heuristic(is_tcp)
    return function(tvb, pinfo, tree)
        if not cfg.heuristic then return false end
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
    cfg.read()
    S.lists_changed()
    Pm.reset()   -- (a layout's code holds validate_checksum's value)
end

apply_ports()
